//! Initial guesses for pose graphs, computed from the edges alone.
//!
//! Entry points:
//! - [`initialize_odometry`] — compose measurements along an odometry-first spanning tree (any
//!   dimension; what the GTSAM peer script does for files without vertices);
//! - [`initialize_lago`] — LAGO for planar graphs (Carlone et al., IJRR 2014);
//! - [`initialize_chordal`] — chordal relaxation for 3D graphs (Carlone et al., ICRA 2015).
//!
//! Each connected component is anchored at its lowest-id fixed vertex (else its lowest id),
//! which keeps its current pose, as do all fixed vertices. On error the graph is unchanged.
//!
//! ```
//! use mapmerge_geometry::{LieGroup, Se2};
//! use mapmerge_init::{initialize_lago, LagoParams};
//! use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph2, Vertex};
//! use nalgebra::Matrix3;
//!
//! // A square driven counter-clockwise, closed by a loop edge; vertices start at the origin.
//! let mut graph = PoseGraph2::new();
//! for k in 0..4 {
//!     graph.add_vertex(NodeId(k), Vertex::new(Se2::identity())).unwrap();
//! }
//! let step = Se2::new(1.0, 0.0, std::f64::consts::FRAC_PI_2);
//! for (from, to) in [(0, 1), (1, 2), (2, 3), (3, 0)] {
//!     let kind = if to == from + 1 { EdgeKind::Odometry } else { EdgeKind::Loop };
//!     graph.add_edge(Edge { from: NodeId(from), to: NodeId(to), measurement: step,
//!         information: Matrix3::identity(), kind }).unwrap();
//! }
//! let info = initialize_lago(&mut graph, &LagoParams::default()).unwrap();
//! assert_eq!(info.vertices_set, 3);
//! let p2 = graph.vertex(NodeId(2)).unwrap().pose;
//! assert!((p2.x_m - 1.0).abs() < 1e-9 && (p2.y_m - 1.0).abs() < 1e-9);
//! assert!(graph.chi2() < 1e-18);
//! ```

mod chordal;
mod error;
mod info;
mod lago;
mod odometry;
mod sparse;
mod topology;

pub use chordal::{initialize_chordal, ChordalParams, RotationWeighting};
pub use error::InitError;
pub use info::InitInfo;
pub use lago::{initialize_lago, LagoParams};
pub use odometry::initialize_odometry;
