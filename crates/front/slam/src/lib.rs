//! The front of 2D graph SLAM: the local tracker (scan-to-submap matching, keyframes,
//! submaps; Hess et al. 2016's local trajectory builder) and the bookkeeping that gives every
//! scan a pose from the current graph. It holds no pose graph: keyframes, their edges and the
//! finished submaps go to the graph's one owner (`mapmerge-atlas`), which closes loops and
//! optimises.
//!
//! ```
//! use mapmerge_geometry::Se2;
//! use mapmerge_slam::KeyframePolicy;
//! let policy = KeyframePolicy::default();
//! assert!(!policy.is_keyframe(&Se2::new(0.05, 0.0, 0.01), 1));
//! assert!(policy.is_keyframe(&Se2::new(0.5, 0.0, 0.0), 1));
//! ```

mod anchors;
mod keyframe;
mod lost;
mod submap;
mod tracker;

pub use anchors::{NodesBefore, ScanAnchors};
pub use keyframe::KeyframePolicy;
pub use lost::{
    LostCause, LostDetector, LostParams, LostReport, OffReading, ReadScan, TrackingState, Verdict,
};
pub use submap::Submap;
pub use tracker::{
    edge_information, odometry_covariance, KeyframeInsertion, LocalTracker, RefineFirst,
    TrackedScan, TrackerError, TrackerInfo, TrackerParams, TrackingReading,
    LOOP_BRANCH_AND_BOUND_DEPTH,
};
