//! The error type of this crate.

/// Why a grid operation was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum GridError {
    /// The resolution must be a positive finite number of metres.
    #[error("grid resolution must be positive and finite, got {0} m")]
    BadResolution(f64),
    /// A coordinate or pose was NaN or infinite.
    #[error("non-finite coordinate")]
    NotFinite,
    /// A log-odds value was NaN.
    #[error("log-odds of cell {index} is NaN")]
    NotANumber {
        /// Row-major index of the cell.
        index: usize,
    },
    /// The data does not fill the grid.
    #[error("expected {expected} cells, found {found}")]
    SizeMismatch {
        /// `width × height`.
        expected: usize,
        /// Values given.
        found: usize,
    },
    /// The grid would exceed [`crate::MAX_CELLS`] cells.
    #[error("grid would exceed {} cells", crate::MAX_CELLS)]
    TooLarge,
}
