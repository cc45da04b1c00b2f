//! The 2D graph-SLAM front-end (issue 4, being built): keyframe selection and the bookkeeping
//! that gives every scan of a log a pose from the current graph. Scan-to-map odometry and loop
//! closing come with the scan matcher (`mapmerge-scanmatch`) and place recognition
//! (`mapmerge-place`).
//!
//! ```
//! use mapmerge_geometry::Se2;
//! use mapmerge_slam::KeyframePolicy;
//! let policy = KeyframePolicy::default();
//! assert!(!policy.is_keyframe(&Se2::new(0.05, 0.0, 0.01), 1));
//! assert!(policy.is_keyframe(&Se2::new(0.5, 0.0, 0.0), 1));
//! ```

mod anchors;
mod front_end;
mod keyframe;
mod loop_closing;
mod submap;

pub use anchors::ScanAnchors;
pub use front_end::{
    run_front_end, run_front_end_with_progress, FrontEnd, FrontEndError, FrontEndInfo,
    FrontEndParams, FrontEndRun, LoopRecord, LoopSource, RefineFirst, ScanStep, StageSeconds,
};
pub use keyframe::KeyframePolicy;
pub use loop_closing::LoopClosureParams;
pub use submap::Submap;
