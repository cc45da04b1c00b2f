//! The crate's error type.

use mapmerge_grid::GridError;
use mapmerge_params::ParamError;
use mapmerge_scanmatch::ScanMatchError;

/// Which of the two input maps an error is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Which {
    /// The receiving map `A`.
    A,
    /// The map `B` that is matched onto `A`.
    B,
}

impl std::fmt::Display for Which {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Which::A => "A",
            Which::B => "B",
        })
    }
}

/// Why two grids could not be matched or compared.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum GridMatchError {
    /// A grid has no cells at all.
    #[error("map {0} has no cells")]
    EmptyMap(Which),
    /// A grid has no known (free or occupied) cell.
    #[error("map {0} has no known cell")]
    NoKnownCells(Which),
    /// A grid has no occupied cell: there is no structure to match.
    #[error("map {0} has no occupied cell")]
    NoOccupiedCells(Which),
    /// A grid's resolution is not a positive finite number of metres.
    #[error("map {which} has an invalid resolution {resolution_m} m")]
    BadResolution {
        /// The map.
        which: Which,
        /// Its resolution (m).
        resolution_m: f64,
    },
    /// The transform between the maps is not finite.
    #[error("the transform a_from_b is not finite")]
    NonFiniteTransform,
    /// A grid is larger than the matcher handles.
    #[error("map {which} has {cells} cells, more than the limit {max_cells}")]
    TooLarge {
        /// The map.
        which: Which,
        /// Its cell count.
        cells: usize,
        /// `GridMatchParams::max_cells`.
        max_cells: usize,
    },
    /// A parameter is out of its range.
    #[error(transparent)]
    Params(#[from] ParamError),
    /// Resampling a grid failed.
    #[error("resampling failed: {0}")]
    Grid(#[from] GridError),
    /// The refinement's scan matcher refused its input.
    #[error("refinement failed: {0}")]
    ScanMatch(#[from] ScanMatchError),
}
