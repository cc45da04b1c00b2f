//! The one error type of this crate.

/// What can go wrong while assembling segments. Variants name the segment or the parameter.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AssembleError {
    /// A segment's inputs are inconsistent (lengths differ, a pose is missing or not finite).
    #[error("segment {segment}: {reason}")]
    InvalidSegment {
        /// The segment's name.
        segment: String,
        /// What is wrong.
        reason: String,
    },
    /// A parameter is out of its range (its path, value and allowed range).
    #[error(transparent)]
    InvalidParams(#[from] mapmerge_params::ParamError),
    /// The association of a pair (or the grouping, or a group's graph) failed.
    #[error("{pair}: {reason}")]
    Association {
        /// The pair (`a × b`) or the stage.
        pair: String,
        /// What went wrong.
        reason: String,
    },
}
