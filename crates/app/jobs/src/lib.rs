//! The jobs the `mapmerge` CLI and the Python module (`mapmerge-python`) share: each job's
//! options, its steps in order, its report (the object `--json` prints) and its errors,
//! whose text is what the CLI prints after `mapmerge: error: ` and whose variant is the exit
//! code ([`JobError`]). The binary and the Python module are thin: they parse arguments,
//! print or convert, and call these.
//!
//! Entry points:
//! - [`optimize_file`] / [`optimize_loaded`]: read, initialise, optimise, write a pose graph
//!   ([`OptimizeReport`]);
//! - [`grid_merge`]: merge two map_server maps without a guess ([`GridMergeReport`]);
//! - [`read_session_log`], [`slam_log`], [`build_grid`]: a CARMEN log or ROS 2 bag, SLAM on
//!   it, its map;
//! - [`load_segments`] + [`assemble`]: AutoMerge over segments;
//! - [`AtlasJob`]: sessions through the lifelong engine, with a store ([`AtlasReport`]).
//!
//! ```
//! use mapmerge_jobs::{optimize_file, OptimizeOptions};
//! let dir = std::env::temp_dir().join(format!("mapmerge-jobs-doc-{}", std::process::id()));
//! std::fs::create_dir_all(&dir).unwrap();
//! let input = dir.join("in.g2o");
//! std::fs::write(&input, "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0.9 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n").unwrap();
//! let done = optimize_file(&input, None, &OptimizeOptions::default(), |_| {}).unwrap();
//! assert!(done.report.final_chi2 < 1e-12);
//!
//! let err = optimize_file(&dir.join("missing.g2o"), None, &OptimizeOptions::default(), |_| {}).unwrap_err();
//! assert_eq!(err.exit_code(), 2);
//! assert!(err.to_string().starts_with(&format!("{}: cannot read", dir.join("missing.g2o").display())));
//! ```

mod areas;
mod assemble;
mod atlas;
#[cfg(feature = "cli")]
pub mod cli;
mod convert;
mod error;
mod grid_merge;
mod lifelong;
mod optimize;
mod session;
mod store;

pub use areas::{
    load_hybrid_map, manage_areas, parse_area_position, route_between, AreasOptions, AreasProgress,
    AreasReport,
};
pub use assemble::{
    arrival_order, assemble, default_params, load_segments, segment_name, Assembled, LoadedSegment,
    LoopLine, Order, ScanRef, TrajectorySource,
};
pub use atlas::{draw_graph, write_atlas};
pub use convert::{convert, is_kitti_folder, ConvertReport};
pub use error::{error_chain, JobError};
pub use grid_merge::{
    grid_merge, load_map, map_from_grid, merge_loaded, GridMergeReport, GridMerged,
    HypothesisReport, TransformReport, DEFAULT_HYPOTHESES,
};
pub use lifelong::{
    kidnaps_per_log, log_sessions, AtlasJob, AtlasOptions, AtlasProgress, AtlasReport, AtlasRun,
    AtlasSession, CommittedSession, MapEpoch, MapReport, MergeReport, RejoinReport,
    SelfSimilarityReport, SessionStart, SiteMap, StoreRunReport, UnmergeReport,
};
pub use mapmerge_store::DEFAULT_KEEP_VERSIONS;
pub use optimize::{
    load_graph, numerical_failure_message, optimize_file, optimize_loaded, AlgorithmChoice,
    BadInformationChoice, Choice, InitChoice, Initialised, OptimizeOptions, OptimizeProgress,
    OptimizeReport, Optimized, RejectedEdge, RobustChoice,
};
pub use session::{
    build_grid, check_output_dir, check_output_file, check_resolution, log_file_stem,
    read_log_or_bag, read_session_log, read_session_log_with, slam_log, write_slam_outputs,
    SlamSummary, DEFAULT_RESOLUTION_M, TUM_CLOCK_PERIOD_S,
};
pub use store::{
    export_version, open_or_create_store, open_store, open_store_read_only, store_protrusions,
    ExportReport, ExportedMap, ProtrusionAction, ProtrusionReport, RegionReport,
};
