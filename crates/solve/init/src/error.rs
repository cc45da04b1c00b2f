//! The error type of the crate.

use mapmerge_posegraph::{EdgeId, NodeId};

/// Why an initial guess could not be computed. The graph is left unchanged whenever one of
/// these is returned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum InitError {
    /// An edge measurement contains NaN or infinity.
    #[error("edge {edge} ({from} -> {to}): measurement is not finite")]
    NonFiniteMeasurement {
        /// The edge.
        edge: EdgeId,
        /// Its start vertex.
        from: NodeId,
        /// Its end vertex.
        to: NodeId,
    },
    /// An edge information matrix is unusable (not finite, or negative where a weight must
    /// be non-negative).
    #[error("edge {edge} ({from} -> {to}): invalid information matrix: {reason}")]
    InvalidInformation {
        /// The edge.
        edge: EdgeId,
        /// Its start vertex.
        from: NodeId,
        /// Its end vertex.
        to: NodeId,
        /// What is wrong.
        reason: &'static str,
    },
    /// The pose of an anchor (a fixed vertex, or the lowest id of a component without one),
    /// which every other pose is computed from, contains NaN or infinity.
    #[error("anchor vertex {node}: pose is not finite")]
    NonFiniteAnchor {
        /// The anchor vertex.
        node: NodeId,
    },
    /// A sparse linear system could not be built or factorised (for instance a bridge edge
    /// with zero information makes it singular).
    #[error("{stage}: sparse Cholesky failed: {reason}")]
    LinearSolve {
        /// Which system (e.g. "LAGO orientations").
        stage: &'static str,
        /// faer's error, as text.
        reason: String,
    },
    /// A computed pose is not finite (overflow or an ill-conditioned system).
    #[error("{stage}: the estimate of vertex {node} is not finite")]
    NonFiniteEstimate {
        /// Which step produced it.
        stage: &'static str,
        /// The vertex.
        node: NodeId,
    },
}
