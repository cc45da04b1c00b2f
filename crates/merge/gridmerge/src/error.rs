//! The error type of this crate.

use mapmerge_grid::GridError;

use crate::GridMergeId;

/// Why a merge operation was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MergeError {
    /// A grid operation failed (bad resolution, non-finite pose, grid too large).
    #[error(transparent)]
    Grid(#[from] GridError),
    /// The transform `a_from_b` has a NaN or infinite component.
    #[error("transform a_from_b is not finite: x = {x_m} m, y = {y_m} m, yaw = {yaw_rad} rad")]
    NotFiniteTransform {
        /// x (m).
        x_m: f64,
        /// y (m).
        y_m: f64,
        /// yaw (rad).
        yaw_rad: f64,
    },
    /// A parameter is out of its range.
    #[error("bad parameter `{name}`: {reason}")]
    BadParams {
        /// The parameter's field name.
        name: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// A merge is active; the mapper keeps one merge at a time.
    #[error("merge {0} is active; undo it before merging again")]
    AlreadyMerged(GridMergeId),
    /// Undo was asked for but no merge is active.
    #[error("no merge is active")]
    NotMerged,
}
