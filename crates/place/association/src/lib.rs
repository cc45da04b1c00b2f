//! Data association between trajectory segments without initial guesses (Yin et al., AutoMerge,
//! T-RO 2023, Sec. V–VI): descriptors of every submap of two segments → cosine difference matrix
//! → sequence matches (SeqSLAM) and single-frame matches → k-means zones + RANSAC with the
//! edge-length consistency test (Eq. 7) → candidate loop edges; confidences between segments
//! (Eq. 9) → spectral grouping (Algorithm 1).
//!
//! Everything here is geometry-free numerics on descriptor rows and submap positions, so the
//! 2D and the 3D paths share it.

pub mod difference;
pub mod grouping;
pub mod kmeans;
pub mod sequence;
pub mod zones;

pub use grouping::{
    confidence, spectral_groups, GroupingError, GroupingParams, IncrementalGrouping,
};
pub use kmeans::{kmeans, KMeansError, KMeansParams, KMeansResult};
pub use zones::{
    edge_lengths_consistent, verify_zones, ZoneClustering, ZoneError, ZoneInfo, ZoneOutcome,
    ZoneParams, ZoneVerification,
};

pub use difference::{
    difference_matrix, difference_matrix_into, AssociationError, DescriptorMatrix, DifferenceMatrix,
};
pub use sequence::{
    contrast_enhanced, sequence_matches, single_frame_matches, SequenceParams, SingleFrameParams,
};

/// One candidate association: submap `query` of the first segment with submap `reference` of
/// the second, and their descriptor distance (cosine difference, 0 = identical).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SubmapMatch {
    pub query: usize,
    pub reference: usize,
    pub distance: f32,
}
