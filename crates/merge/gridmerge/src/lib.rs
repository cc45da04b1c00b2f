//! Reversible merging of occupancy grids after Andersone, "Distributed Framework for Reversible
//! Merging of Heterogeneous Robot Maps": decide whether and how to merge (Sec. 2.1), fuse with
//! regard to each region's quality (Sec. 2.2, 4.1), keep mapping with periodic verification and
//! undo with multiple maps (2M, Sec. 3.1) or a single map plus a local-update map (1M,
//! Sec. 3.2).
//!
//! Entry points: [`DecisionTable::decide`] (which procedures, or why not), [`fuse`] (map B into
//! map A's frame and resolution), and [`ReversibleMapper`] (merge, keep inserting scans, check,
//! undo), checked by [`MetricsCheck`] (SM/DM from `mapmerge-gridmatch`, where matching
//! lives) or any other [`MergeCheck`].
//!
//! ```
//! use mapmerge_geometry::Se2;
//! use mapmerge_grid::{Cell, GridGeometry, OccupancyGrid, Point2};
//! use mapmerge_gridmerge::{fuse, FusionParams};
//!
//! let geometry = GridGeometry { resolution_m: 0.05, origin_m: Point2::zeros(), width: 40, height: 40 };
//! let a = OccupancyGrid::from_log_odds(geometry, vec![-0.5; 1600])?;
//! let b = OccupancyGrid::from_log_odds(GridGeometry { resolution_m: 0.1, width: 20, height: 20, ..geometry }, vec![-0.5; 400])?;
//! // B's frame is 1 m to the right of A's and turned by 90°.
//! let fused = fuse(&a, &b, &Se2::new(1.0, 0.0, core::f64::consts::FRAC_PI_2), &FusionParams::default())?;
//! assert_eq!(fused.merged.resolution_m(), 0.05);
//! assert_eq!(fused.merged.log_odds_at(&Point2::new(0.9, 0.5)), -1.0);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod check;
mod decision;
mod error;
mod fusion;
mod quality;
mod reversible;
mod warp;

pub use check::MetricsCheck;
pub use decision::{
    DecisionRecord, DecisionTable, FusionProcedure, GridMergeChoice, GridMergeDecision,
    GridMergeRejection, GridMergeRequest, GridRejectReason, MapKind, MapMetadata,
    MatchingProcedure, PoseCondition, PoseKnowledge, SensorKind, WhichMap,
};
pub use error::MergeError;
pub use fusion::{fuse, Fused, FusionInfo, FusionParams, FusionWeighting};
pub use quality::{QualityMap, QualityParams};
pub use reversible::{
    CheckInput, GridMergeEvent, GridMergeEventKind, GridMergeId, KeepMerge, LocalUpdateMap,
    MapperState, MergeCheck, Metric, ReversibleMapper, ReversibleMode, ReversibleParams,
    ScanUpdate, UndoReason, UpdateTiming, Verdict,
};
pub use warp::resample_into;
