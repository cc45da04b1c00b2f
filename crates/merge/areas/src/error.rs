//! Errors of the map manager.

use mapmerge_params::ParamError;
use thiserror::Error;

/// What can go wrong in the map manager.
#[derive(Debug, Error)]
pub enum AreasError {
    /// A parameter is out of its range.
    #[error(transparent)]
    Params(#[from] ParamError),
    /// A preset's file could not be read.
    #[error("preset {name}: {reason}")]
    Preset {
        /// The preset.
        name: String,
        /// Why.
        reason: String,
    },
    /// An area could not be mapped, or its map does not fit its scans.
    #[error("mapping: {0}")]
    Mapping(String),
    /// A hybrid map (read from a file) breaks its own rules.
    #[error("hybrid map: {0}")]
    Hybrid(String),
}
