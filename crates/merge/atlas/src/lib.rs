//! The lifelong atlas (Holoch et al., "Detecting Invalid Map Merges in Lifelong SLAM",
//! Sec. III): epochs stamped on every vertex, one active pose graph and any number of
//! inactive ones, merging by place recognition (or forced), backups, and undoing every merge
//! into the active graph without losing what the robot mapped since.
//!
//! Entry points:
//! - [`Atlas`]: [`Atlas::add_vertex`] / [`Atlas::import_graph`] feed the current epoch,
//!   [`Atlas::end_epoch`] starts a new one (kidnap, restart, tracking failure).
//! - [`Atlas::merge_by_recognition`] (or [`Atlas::find_merges`] + [`Atlas::merge`]); forced
//!   merges with a given transform via [`MergeRequest::forced`].
//! - [`Atlas::unmerge_all`] on an invalid-merge detection; [`Atlas::can_prune`] /
//!   [`Atlas::prune_vertex`] guard pruning while merges are undoable.
//!
//! Every mutation returns (and records) an [`AtlasEvent`]; [`EventLogWriter`] writes them as
//! `events.jsonl`.
//!
//! ```
//! use std::sync::Arc;
//! use mapmerge_atlas::{Atlas, EpochEndReason, MapId, MergeRequest, UnmergeReason};
//! use mapmerge_geometry::{LieGroup, Se2};
//! use mapmerge_posegraph::{Edge, EdgeKind, Vertex};
//! use nalgebra::Matrix3;
//!
//! let mut atlas = Atlas::new(Default::default()).unwrap();
//! let mut path = |atlas: &mut Atlas| {
//!     let a = atlas.add_vertex(Vertex::new(Se2::identity()), Arc::from(Vec::new()));
//!     let b = atlas.add_vertex(Vertex::new(Se2::new(1.0, 0.0, 0.0)), Arc::from(Vec::new()));
//!     atlas.add_edge(Edge { from: a, to: b, measurement: Se2::new(1.0, 0.0, 0.0),
//!         information: Matrix3::identity(), kind: EdgeKind::Odometry }).unwrap();
//! };
//! path(&mut atlas);
//! atlas.end_epoch(EpochEndReason::Kidnap); // epoch 0 becomes inactive map 0
//! path(&mut atlas);
//! let before = atlas.inactive(MapId(0)).unwrap().clone();
//! let robot = atlas.active().vertex(atlas.robot_node().unwrap()).unwrap().pose;
//! let merged = atlas
//!     .merge(MergeRequest::forced(MapId(0), Se2::new(0.0, 2.0, 0.5), "example"), None)
//!     .unwrap();
//! assert_eq!(merged.merged_vertices, 2);
//! assert_eq!(atlas.active().vertex(atlas.robot_node().unwrap()).unwrap().pose, robot);
//! atlas.unmerge_all(UnmergeReason::Requested { note: "example".into() }).unwrap();
//! assert_eq!(atlas.inactive(MapId(0)), Some(&before)); // restored exactly
//! assert_eq!(atlas.active().num_vertices(), 2);
//! ```

mod atlas;
mod backup;
mod constraints;
mod error;
mod events;
mod ids;
mod keyframes;
mod local_maps;
mod maintenance;
mod merge;
mod protrusion;
mod recognition;
mod rejoin;
mod snapshot;

pub use atlas::{epochs_of, AppliedMerge, Atlas, AtlasParams};
pub use backup::{BackupStore, DiskBackups, MemoryBackups};
pub use constraints::{
    revisits_among, ConstraintInfo, ConstraintSearch, LoopClosureParams, LoopRecord, LoopSource,
};
pub use error::AtlasError;
pub use events::{
    pose_array, read_events, AtlasEvent, EpochEndReason, EventLogWriter, MergeEvent, MergeReason,
    UnmergeEvent, UnmergeReason,
};
pub use ids::{map_name, EpochId, MapId, MergeId};
pub use keyframes::{KeyframeRecord, KeyframeStore};
pub use local_maps::{LocalMapGrid, RenderedMap, LOG_ODDS_STEP};
pub use maintenance::{MaintenanceParams, MaintenanceReport, ViewUse};
pub use merge::{EpochAgreement, LoopEdge, MergeParams, MergePreview, MergeRequest, OverlapParams};
pub use protrusion::{
    align_graphs, new_regions, remove_regions, FeatureSet, LabelledRegion, ProtrusionClassifier,
    ProtrusionParams, Region, RegionFeatures, DEFAULT_DEPTH, DEFAULT_MIN_LEAF,
};
pub use recognition::{
    default_verifier, KeyframeParams, MergeProposal, MergeQueryTrace, RecognitionParams,
};
pub use rejoin::{RejoinEvent, RejoinParams};
pub use snapshot::{points_from_le_bytes, points_to_le_bytes, AtlasCounters, AtlasSnapshot};
