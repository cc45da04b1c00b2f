//! Sparse nonlinear least squares on pose graphs.
//!
//! Entry points: [`optimize`] (Gauss–Newton / Levenberg–Marquardt with optional robust
//! kernels), [`optimize_gnc`] (Graduated Non-Convexity with truncated least squares, which
//! reports the edges it rejected) and [`marginal_covariances`].
//!
//! ```
//! use mapmerge_geometry::{LieGroup, Se2};
//! use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph2, Vertex};
//! use mapmerge_solve::{optimize, OptimizerParams};
//! use nalgebra::Matrix3;
//! let mut g = PoseGraph2::new();
//! g.add_vertex(NodeId(0), Vertex::new(Se2::identity())).unwrap();
//! g.add_vertex(NodeId(1), Vertex::new(Se2::new(0.7, 0.3, 0.2))).unwrap();
//! g.add_edge(Edge { from: NodeId(0), to: NodeId(1), measurement: Se2::new(1.0, 0.0, 0.0),
//!     information: Matrix3::identity(), kind: EdgeKind::Odometry }).unwrap();
//! let info = optimize(&mut g, &OptimizerParams::default()).unwrap();
//! assert!(info.final_chi2 < 1e-12);
//! ```

mod error;
mod gnc;
mod linear;
mod marginals;
mod optimizer;
mod problem;
mod robust;

pub use error::SolveError;
pub use gnc::{chi2_quantile_99, optimize_gnc, GncInfo, GncParams, GncStart};
pub use marginals::marginal_covariances;
pub use optimizer::{
    optimize, optimize_with_progress, Algorithm, IterationStats, OptimizerInfo, OptimizerParams,
    Termination,
};
pub use robust::RobustKernel;
