//! The crate's error type.

/// Why a scan-matching input was refused.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
#[non_exhaustive]
pub enum ScanMatchError {
    /// The target has no finite point, so there is nothing to match against.
    #[error("the target has no finite point")]
    EmptyTarget,
    /// The target's bounding box would need more cells than `max_cells` at this resolution.
    #[error("the target spans {cells} cells at {resolution_m} m, more than the limit {max_cells}")]
    TargetTooLarge {
        /// Cells the grid would need.
        cells: u64,
        /// The grid resolution (m).
        resolution_m: f64,
        /// The limit (`ScanMatchParams::max_grid_cells`).
        max_cells: u64,
    },
    /// A parameter is out of its range.
    #[error(transparent)]
    InvalidParams(#[from] mapmerge_params::ParamError),
}
