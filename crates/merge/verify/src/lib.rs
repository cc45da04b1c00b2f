//! Invalid-merge detectors (Holoch et al., "Detecting Invalid Map Merges in Lifelong SLAM",
//! Sec. IV): after a merge, every new vertex of the current epoch is checked against the data
//! of the other epochs, and each detector says how likely the merge is wrong as an
//! *invalidity ratio* in [0, 1] (higher = more likely wrong; an unmerge happens above a
//! threshold `t_unmerge`).
//!
//! Entry points: [`MergedMap`] (what a detector sees: the current epoch's scans and the other
//! epochs' scans, each with its pose in the active map frame), the [`InvalidMergeDetector`]
//! trait, and the detectors by name ([`detector`], [`DETECTOR_NAMES`], [`all_detectors`]).
//!
//! ```
//! use mapmerge_verify::{detector, RatioSupport, MergedMap, DETECTOR_NAMES};
//! // After a merge: prepare once, then ask after every new current-epoch vertex.
//! let map = MergedMap { current: &[], other: &[] };
//! for name in DETECTOR_NAMES {
//!     let mut d = detector(name).unwrap();
//!     d.on_merge(&map);
//!     let ratio = d.on_vertex(&map);
//!     // No other-epoch data: no evidence (0, or a calibrated score flagged unsupported).
//!     assert!(ratio == 0.0 || d.evidence() == RatioSupport::Unsupported);
//! }
//! ```

mod better_hypothesis;
mod change_detection;
mod combined;
mod common;
mod entropy;
mod forest;
mod gridmap;
mod histogram;
mod learned;
mod map;
mod realign;
mod registry;
mod similarity;
#[cfg(test)]
mod testworld;

pub use better_hypothesis::{
    BetterHypothesisDetector, BetterHypothesisInfo, BetterHypothesisParams,
};
pub use change_detection::{
    ChangeDetectionDetector, ChangeDetectionInfo, ChangeDetectionParams, PointClass,
};
pub use combined::{CombinedDetector, CombinedInfo, CombinedParams};
pub use entropy::{EntropyDetector, EntropyParams};
pub use forest::{ForestParams, RandomForest, Tree};
pub use gridmap::{GridmapDetector, GridmapInfo, GridmapParams};
pub use histogram::{HistogramDetector, HistogramParams};
pub use learned::{FitError, LearnedDetector, LearnedModel, LearnedSample, RatioTransform};
pub use map::{DetectorScan, InvalidMergeDetector, MergedMap, RatioSupport};
pub use realign::{RealignDetector, RealignInfo, RealignParams};
pub use registry::{all_detectors, detector, DetectorParams, DETECTOR_NAMES};
pub use similarity::{DmDetector, SimilarityParams, SmDetector};
