//! The crate's error type.

/// Why an input or a parameter set was refused. Nothing in this crate panics on bad input.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum HypothesisError {
    /// A pose, travel or time that should be finite is not.
    #[error("{what} is not finite")]
    NonFinite {
        /// The offending input.
        what: &'static str,
    },
    /// A covariance that must be symmetric positive definite is not.
    #[error("{what} is not symmetric positive definite")]
    NotPositiveDefinite {
        /// The offending input.
        what: &'static str,
    },
    /// A covariance that must be symmetric positive semidefinite is not.
    #[error("{what} is not symmetric positive semidefinite")]
    NotPositiveSemidefinite {
        /// The offending input.
        what: &'static str,
    },
    /// A parameter is out of range.
    #[error(transparent)]
    InvalidParams(#[from] mapmerge_params::ParamError),
    /// The EKF produced a non-finite or indefinite state (inputs of absurd magnitude).
    #[error("numerical failure in {what}")]
    Numerical {
        /// The step that failed.
        what: &'static str,
    },
}
