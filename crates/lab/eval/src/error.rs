//! The one error type of this crate.

use mapmerge_posegraph::GraphError;

/// What can go wrong in an evaluation helper. Nothing in this crate panics on input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum EvalError {
    /// The outlier fraction must be finite and in `[0, 1)`.
    #[error("outlier fraction {0} is not in [0, 1)")]
    InvalidFraction(f64),
    /// False loop closures copy the information matrix of an existing loop closure (or, failing
    /// that, of any relative edge); the graph has neither.
    #[error(
        "the graph has no relative edge whose information matrix a false loop closure could copy"
    )]
    NoTemplateEdge,
    /// No pair of distinct, non-consecutive vertices exists (fewer than three vertices).
    #[error("no pair of distinct, non-consecutive vertices among {vertices} vertices")]
    NoVertexPair {
        /// Number of vertices in the graph.
        vertices: usize,
    },
    /// The two graphs share no vertex id, so no trajectory error can be computed.
    #[error("the reference and the estimate share no vertex id")]
    NoCommonVertices,
    /// A parameter is out of its valid range.
    #[error("invalid parameter {field}: {reason}")]
    InvalidParams {
        /// The parameter's name.
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// Two trajectories keyed by scan index differ in length.
    #[error("{what}: {estimate} estimated poses vs {reference} reference poses (poses pair by scan index)")]
    LengthMismatch {
        /// Which comparison.
        what: &'static str,
        /// Number of reference poses.
        reference: usize,
        /// Number of estimated poses.
        estimate: usize,
    },
    /// A relation names a scan index beyond the trajectory.
    #[error(
        "relation {relation} ({from} → {to}) names a scan beyond the trajectory's {poses} poses"
    )]
    RelationOutOfRange {
        /// Position of the relation in its list.
        relation: usize,
        /// Its first scan index.
        from: usize,
        /// Its second scan index.
        to: usize,
        /// Number of poses of the trajectory.
        poses: usize,
    },
    /// There is nothing to measure (no relations, or fewer than two poses).
    #[error("nothing to measure: {0}")]
    Empty(&'static str),
    /// A graph edit failed (should not happen for graphs built by this crate).
    #[error(transparent)]
    Graph(#[from] GraphError),
}
