//! Errors of the solver crate.

use mapmerge_posegraph::{EdgeId, NodeId};

/// Why an optimisation could not start. Numerical trouble during the run is not an error: the
/// optimizer returns the last good state and says so in its info.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SolveError {
    /// The graph has no vertices.
    #[error("the graph has no vertices")]
    EmptyGraph,
    /// A vertex pose holds NaN or infinity.
    #[error("vertex {0} has a non-finite pose")]
    NonFinitePose(NodeId),
    /// An edge measurement or information holds NaN or infinity.
    #[error("edge {0} has a non-finite measurement or information matrix")]
    NonFiniteEdge(EdgeId),
    /// An edge names a vertex that does not exist.
    #[error("edge {0} names a vertex that does not exist")]
    DanglingEdge(EdgeId),
    /// A parameter is out of range.
    #[error("invalid parameter: {0}")]
    InvalidParameter(String),
    /// A parameter struct's field is out of its range.
    #[error(transparent)]
    Params(#[from] mapmerge_params::ParamError),
    /// The sparse symbolic analysis failed (out of memory or index overflow).
    #[error("sparse symbolic analysis failed: {0}")]
    Symbolic(String),
    /// A requested vertex does not exist or is not free.
    #[error("vertex {0}: {1}")]
    BadVertex(NodeId, &'static str),
    /// The information matrix is singular at the requested vertex (unconstrained direction).
    #[error("the system is not positive definite: {0}")]
    NotPositiveDefinite(String),
}
