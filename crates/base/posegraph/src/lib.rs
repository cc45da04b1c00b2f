//! The pose-graph model of mapmerge.
//!
//! A [`PoseGraph`] holds vertices (poses with a fixed flag and [`VertexMeta`]) and edges
//! (relative measurements with an information matrix and an [`EdgeKind`]). Every structural
//! edit returns a record from which it can be undone exactly: [`PoseGraph::union`] /
//! [`PoseGraph::undo_union`], [`PoseGraph::remove_vertex`] / [`PoseGraph::restore_vertex`],
//! [`PoseGraph::reanchor`] / [`PoseGraph::undo_reanchor`].
//!
//! ```
//! use mapmerge_geometry::{LieGroup, Se2};
//! use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph2, Vertex};
//! use nalgebra::Matrix3;
//! let mut g = PoseGraph2::new();
//! g.add_vertex(NodeId(0), Vertex::new(Se2::identity())).unwrap();
//! g.add_vertex(NodeId(1), Vertex::new(Se2::new(1.0, 0.0, 0.0))).unwrap();
//! let z = Se2::new(1.0, 0.0, 0.0);
//! g.add_edge(Edge { from: NodeId(0), to: NodeId(1), measurement: z,
//!     information: Matrix3::identity(), kind: EdgeKind::Odometry }).unwrap();
//! assert!(g.chi2() < 1e-20);
//! ```

mod graph;
mod ids;
mod marginalize;
mod simplify;

pub use graph::{
    Edge, EdgeKind, GraphError, PoseGraph, PoseGraph2, PoseGraph3, ReanchorRecord, RemovedVertex,
    UnionRecord, Vertex,
};
pub use ids::{EdgeId, NodeId, RobotId, SessionId, VertexMeta};
pub use marginalize::Marginalized;
pub use simplify::edge_information_ln_det;
