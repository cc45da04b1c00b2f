//! The lifelong mapping loop: the only place that knows the order of the stages.
//!
//! Two owners, in the manner of Cartographer's local/global split (Hess et al. 2016): the
//! local tracker (`mapmerge-slam`) matches scans against its submaps and hands over
//! keyframes; the atlas (`mapmerge-atlas`) owns every pose graph, every keyframe, the place
//! index and the constraint builder. [`Engine::add_scan`] runs, per scan:
//! 1. track (scan-to-submap matching; most scans stop here);
//! 2. insert the keyframe into the atlas's active graph;
//! 3. search constraints (loops in the epoch, loops into merged data, matches in the
//!    inactive graphs);
//! 4. update the merge hypotheses and merge when one is accepted;
//! 5. optimise when loops wait;
//! 6. verify the merges so far with an invalid-merge detector (`mapmerge-verify`;
//!    Holoch et al., Sec. IV);
//! 7. undo every merge when it fires.
//!
//! A kidnap, restart or tracking failure ends the epoch ([`Engine::end_epoch`]). Single-log
//! SLAM is the same loop with one epoch ([`run_slam`]).

use std::sync::Arc;

use mapmerge_atlas::{
    default_verifier, Atlas, AtlasError, AtlasEvent, AtlasParams, ConstraintInfo, ConstraintSearch,
    EpochEndReason, LoopRecord, MapId, MergeProposal, MergeRequest, UnmergeReason,
};
use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_place::ScanMatchVerifier;
use mapmerge_posegraph::{EdgeKind, NodeId, PoseGraph2};
use mapmerge_scan::{LaserLog, LaserScan, Point2};
use mapmerge_slam::{LocalTracker, ScanAnchors, TrackerError, TrackerInfo, TrackerParams};
use mapmerge_verify::{DetectorScan, InvalidMergeDetector, MergedMap};
use serde::{Deserialize, Serialize};

/// What can go wrong.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum EngineError {
    /// The tracker failed.
    #[error(transparent)]
    Tracker(#[from] TrackerError),
    /// The atlas refused an operation.
    #[error(transparent)]
    Atlas(#[from] AtlasError),
    /// The verifier could not be built.
    #[error("place verification: {0}")]
    Verifier(String),
    /// A graph could not be imported.
    #[error("import: {0}")]
    Import(String),
    /// No detector of that name.
    #[error("unknown invalid-merge detector `{0}` (known: {1})")]
    UnknownDetector(String, String),
}

/// [`EngineParams::detector`] for no verification.
pub const NO_DETECTOR: &str = "none";

/// Parameters of the loop.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EngineParams {
    /// The local tracker.
    pub tracker: TrackerParams,
    /// The atlas (loop closing, recognition, merging, optimisation).
    pub atlas: AtlasParams,
    /// The invalid-merge detector (a name of `mapmerge_verify::DETECTOR_NAMES`, or `none`
    /// for no verification, as in an evaluation that runs its own detectors; default
    /// `combined`).
    pub detector: String,
    /// Undo all merges when its invalidity exceeds this (default: 0.5).
    pub unmerge_threshold: f64,
    /// A merge that was undone is not made again: proposals for the same inactive graph
    /// within this of its transform (m, rad) are refused for the rest of the epoch
    /// (default: 1 m, 10°).
    pub refused_within: (f64, f64),
}

impl Default for EngineParams {
    fn default() -> Self {
        Self {
            tracker: TrackerParams::default(),
            atlas: AtlasParams::default(),
            detector: "combined".into(),
            unmerge_threshold: 0.5,
            refused_within: (1.0, 10f64.to_radians()),
        }
    }
}

/// An atlas event with where and when it happened.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EngineEvent {
    /// Scans fed to the engine so far (the event happened after scan `scan - 1`).
    pub scan: usize,
    /// Robot travel so far (m, tracker estimate, summed over epochs).
    pub travel_m: f64,
    /// The event.
    #[serde(flatten)]
    pub event: AtlasEvent,
}

/// What one scan did.
#[derive(Debug)]
pub struct ScanReport<'a> {
    /// The keyframe the scan hangs on and its pose in that keyframe's frame.
    pub anchor: (NodeId, Se2),
    /// The keyframe the scan became.
    pub keyframe: Option<NodeId>,
    /// The events it caused.
    pub events: &'a [EngineEvent],
}

/// The loop's state.
pub struct Engine {
    params: EngineParams,
    atlas: Atlas,
    tracker: LocalTracker,
    verifier: ScanMatchVerifier,
    /// `None`: merges are never checked (detector `none`).
    detector: Option<Box<dyn InvalidMergeDetector>>,
    /// Merges undone in this epoch: (inactive map, its transform), not to be made again.
    refused: Vec<(MapId, Se2)>,
    scans: usize,
    /// Travel of the previous epochs (m).
    travel_before_epoch_m: f64,
    events: Vec<EngineEvent>,
    atlas_events_seen: usize,
    /// Largest invalidity seen since the last merge.
    max_invalidity: f64,
    /// The active graph just before the last merge or unmerge (for pictures).
    before_last_change: Option<PoseGraph2>,
    /// Every merge's merge edges `(from, to, measurement)` as made, in merge order (an undo
    /// removes them from the graph).
    merge_edges: Vec<Vec<(NodeId, NodeId, Se2)>>,
    /// Counters of the tracker of the previous epochs.
    tracker_info_before_epoch: TrackerInfo,
}

impl Engine {
    /// A new engine: epoch 0 starts.
    pub fn new(params: EngineParams) -> Result<Self, EngineError> {
        let detector = match params.detector.as_str() {
            NO_DETECTOR => None,
            name => Some(mapmerge_verify::detector(name).ok_or_else(|| {
                EngineError::UnknownDetector(
                    params.detector.clone(),
                    format!(
                        "{}, {NO_DETECTOR}",
                        mapmerge_verify::DETECTOR_NAMES.join(", ")
                    ),
                )
            })?),
        };
        let verifier = default_verifier().map_err(|e| EngineError::Verifier(e.to_string()))?;
        let mut engine = Self {
            tracker: LocalTracker::new(params.tracker.clone())?,
            atlas: Atlas::new(params.atlas.clone())?,
            params,
            verifier,
            detector,
            refused: Vec::new(),
            scans: 0,
            travel_before_epoch_m: 0.0,
            events: Vec::new(),
            atlas_events_seen: 0,
            max_invalidity: 0.0,
            before_last_change: None,
            merge_edges: Vec::new(),
            tracker_info_before_epoch: TrackerInfo::default(),
        };
        engine.collect_events();
        Ok(engine)
    }

    /// The parameters.
    pub fn params(&self) -> &EngineParams {
        &self.params
    }

    /// The atlas.
    pub fn atlas(&self) -> &Atlas {
        &self.atlas
    }

    /// Every event so far.
    pub fn events(&self) -> &[EngineEvent] {
        &self.events
    }

    /// Robot travel so far (m).
    pub fn travel_m(&self) -> f64 {
        self.travel_before_epoch_m + self.tracker.travel_m()
    }

    /// Scans fed so far.
    pub fn scans(&self) -> usize {
        self.scans
    }

    /// The tracker's counters over every epoch so far.
    pub fn tracker_info(&self) -> TrackerInfo {
        let (a, b) = (self.tracker_info_before_epoch, self.tracker.info());
        TrackerInfo {
            scans: a.scans + b.scans,
            matched: a.matched + b.matched,
            odometry_only: a.odometry_only + b.odometry_only,
            refined: a.refined + b.refined,
            keyframes: a.keyframes + b.keyframes,
            submaps: a.submaps + b.submaps,
            matching_seconds: a.matching_seconds + b.matching_seconds,
            submaps_seconds: a.submaps_seconds + b.submaps_seconds,
        }
    }

    /// The largest invalidity the detector reported since the last merge.
    pub fn max_invalidity(&self) -> f64 {
        self.max_invalidity
    }

    /// The active graph as it was just before the last merge or unmerge.
    pub fn before_last_change(&self) -> Option<&PoseGraph2> {
        self.before_last_change.as_ref()
    }

    /// Every merge's merge edges `(from, to, measurement)` as made, in merge order.
    pub fn merge_edges(&self) -> &[Vec<(NodeId, NodeId, Se2)>] {
        &self.merge_edges
    }

    /// The atlas node of the robot's newest keyframe.
    pub fn robot_node(&self) -> Option<NodeId> {
        self.atlas.robot_node()
    }

    /// Ends the epoch (kidnap, restart, tracking failure): the active graph becomes inactive,
    /// the tracker starts afresh. Returns the new events.
    pub fn end_epoch(&mut self, reason: EpochEndReason) -> Result<&[EngineEvent], EngineError> {
        let before = self.events.len();
        self.atlas.optimize_if_due(true)?;
        self.atlas.end_epoch(reason);
        self.tracker_info_before_epoch = self.tracker_info();
        self.travel_before_epoch_m += self.tracker.travel_m();
        self.tracker = LocalTracker::new(self.params.tracker.clone())?;
        self.refused.clear();
        self.collect_events();
        Ok(self.events.get(before..).unwrap_or_default())
    }

    /// Optimises once more if loops wait (call after a log's last scan).
    pub fn finish(&mut self) -> Result<(), EngineError> {
        self.atlas.optimize_if_due(true)?;
        Ok(())
    }

    /// Feeds one scan with its wheel-odometry pose; see the crate docs for the steps.
    pub fn add_scan(
        &mut self,
        odom_from_robot: &Se2,
        scan: &LaserScan,
        stamp_secs: Option<f64>,
    ) -> Result<ScanReport<'_>, EngineError> {
        let before = self.events.len();
        self.scans += 1;
        // 1. Track.
        let tracked = self
            .tracker
            .add_scan(odom_from_robot, scan, self.atlas.next_node_id())?;
        let anchor = tracked.anchor;
        let Some(insertion) = tracked.keyframe else {
            return Ok(ScanReport {
                anchor,
                keyframe: None,
                events: self.events.get(before..).unwrap_or_default(),
            });
        };
        // 2. Insert the keyframe.
        let node = self.atlas.insert_keyframe(insertion, stamp_secs)?;
        // 3. Search constraints.
        let found = self.atlas.search_constraints(node, &self.verifier)?;
        // 4. Update the merge hypotheses.
        let merged = self.update_hypotheses(found)?;
        // 5. Optimise.
        self.atlas.optimize_if_due(false)?;
        // 6. Verify and 7. undo (a merge made now is checked from the next keyframe on).
        if !merged && self.atlas.is_undoable() {
            self.verify_and_undo()?;
        }
        self.collect_events();
        Ok(ScanReport {
            anchor,
            keyframe: Some(node),
            events: self.events.get(before..).unwrap_or_default(),
        })
    }

    /// Step 4: the best match in an inactive graph not refused before is merged. Returns
    /// whether a merge happened.
    fn update_hypotheses(&mut self, found: ConstraintSearch) -> Result<bool, EngineError> {
        let (m, rad) = self.params.refused_within;
        let refused = |p: &MergeProposal| {
            self.refused.iter().any(|(map, t)| {
                *map == p.map
                    && (t.translation() - p.active_from_inactive.translation()).norm() <= m
                    && wrap_angle_rad(t.theta_rad - p.active_from_inactive.theta_rad).abs() <= rad
            })
        };
        let Some(proposal) = found.merge_candidates.into_iter().find(|p| !refused(p)) else {
            return Ok(false);
        };
        self.apply_merge(proposal.into_request())?;
        Ok(true)
    }

    /// The merged map as the detectors see it: the active graph's current-epoch and
    /// other-epoch keyframes at their poses, with their points.
    pub fn merged_map_scans(&self) -> (Vec<DetectorScan>, Vec<DetectorScan>) {
        merged_map_scans(&self.atlas)
    }

    /// Steps 6 and 7: runs the detector after a new keyframe; undoes every merge when it
    /// fires, and refuses those merges for the rest of the epoch.
    fn verify_and_undo(&mut self) -> Result<(), EngineError> {
        let Some(detector) = self.detector.as_mut() else {
            return Ok(());
        };
        let (current, other) = merged_map_scans(&self.atlas);
        let map = MergedMap {
            current: &current,
            other: &other,
        };
        let invalidity = detector.on_vertex(&map);
        self.max_invalidity = self.max_invalidity.max(invalidity);
        if invalidity > self.params.unmerge_threshold {
            self.before_last_change = Some(self.atlas.active().clone());
            let undone = self.atlas.unmerge_all(UnmergeReason::InvalidMerge {
                detector: detector.name().to_owned(),
                invalidity,
            })?;
            if let Some(undone) = undone {
                self.refused.extend(
                    undone
                        .restored_maps
                        .iter()
                        .zip(&undone.undone_transforms)
                        .map(|(map, t)| (*map, Se2::new(t[0], t[1], t[2]))),
                );
            }
        }
        Ok(())
    }

    /// Merges inactive graph `map` into the active graph with a given transform (a forced
    /// merge, as in Holoch et al.'s evaluation), then searches the overlap for loops and
    /// re-optimises like a merge by recognition; the detector starts over on the merged map.
    pub fn force_merge(
        &mut self,
        map: MapId,
        active_from_inactive: Se2,
        note: impl Into<String>,
    ) -> Result<(), EngineError> {
        self.apply_merge(MergeRequest::forced(map, active_from_inactive, note))?;
        self.collect_events();
        Ok(())
    }

    /// Adds `graph` (e.g. an earlier session's graph, with `points(node)` as each vertex's
    /// keyframe points) to the atlas as an inactive graph of its own epoch: it is imported
    /// into the (empty) current epoch, which then ends. Returns its map id.
    pub fn import_inactive(
        &mut self,
        graph: &PoseGraph2,
        points: impl FnMut(NodeId) -> Option<Arc<[Point2]>>,
    ) -> Result<MapId, EngineError> {
        if self.atlas.active().num_vertices() > 0 {
            return Err(EngineError::Import(
                "the current epoch already has keyframes; end it first".into(),
            ));
        }
        self.atlas.import_graph(graph, points)?;
        let before = self.events.len();
        self.end_epoch(EpochEndReason::Restart)?;
        self.events
            .get(before..)
            .unwrap_or_default()
            .iter()
            .find_map(|e| match &e.event {
                AtlasEvent::EpochEnded { map, .. } => *map,
                _ => None,
            })
            .ok_or_else(|| EngineError::Import("the imported graph is empty".into()))
    }

    fn apply_merge(&mut self, request: MergeRequest) -> Result<(), EngineError> {
        let before = self.atlas.active().clone();
        let first_edge = self.atlas.active().next_edge_id();
        self.atlas.merge(request, Some(&self.verifier))?;
        self.before_last_change = Some(before);
        self.merge_edges.push(
            self.atlas
                .active()
                .edges()
                .filter(|(id, e)| id.0 >= first_edge.0 && e.kind == EdgeKind::Merge)
                .map(|(_, e)| (e.from, e.to, e.measurement))
                .collect(),
        );
        if let Some(detector) = self.detector.as_mut() {
            let (current, other) = merged_map_scans(&self.atlas);
            detector.on_merge(&MergedMap {
                current: &current,
                other: &other,
            });
        }
        self.max_invalidity = 0.0;
        Ok(())
    }

    fn collect_events(&mut self) {
        let travel_m = self.travel_m();
        let fresh = self
            .atlas
            .events()
            .get(self.atlas_events_seen..)
            .unwrap_or_default();
        for event in fresh {
            self.events.push(EngineEvent {
                scan: self.scans,
                travel_m,
                event: event.clone(),
            });
        }
        self.atlas_events_seen = self.atlas.events().len();
    }
}

/// The merged map as the detectors see it (see [`Engine::merged_map_scans`]).
fn merged_map_scans(atlas: &Atlas) -> (Vec<DetectorScan>, Vec<DetectorScan>) {
    let (mut current, mut other) = (Vec::new(), Vec::new());
    for (node, vertex) in atlas.active().vertices() {
        let Some(points) = atlas.keyframes().get(node) else {
            continue;
        };
        let scan = DetectorScan {
            node,
            epoch: vertex.meta.session.0,
            map_from_robot: vertex.pose,
            points_in_robot: Arc::clone(points),
        };
        if atlas.is_current_epoch(node) {
            current.push(scan);
        } else {
            other.push(scan);
        }
    }
    (current, other)
}

/// Counters of a SLAM run: the tracker's and the constraint builder's.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct SlamInfo {
    /// The tracker.
    #[serde(flatten)]
    pub tracker: TrackerInfo,
    /// Loop closing and optimisation.
    #[serde(flatten)]
    pub constraints: ConstraintInfo,
}

/// The result of [`run_slam`]: every scan's pose and the counters.
#[derive(Clone, Debug)]
pub struct SlamRun {
    /// `map_from_robot` of every scan of the log, in log order (from the final graph).
    pub trajectory: Vec<Se2>,
    /// The final pose graph (node `k` is keyframe `k`).
    pub graph: PoseGraph2,
    /// Scan index (log order) of every keyframe node, by node id.
    pub keyframe_scans: Vec<usize>,
    /// Every loop edge added, in order.
    pub loops: Vec<LoopRecord>,
    /// Counters.
    pub info: SlamInfo,
    /// Wall time of the loop alone (s).
    pub seconds: f64,
}

/// 2D graph SLAM on one log: the engine with one epoch (no inactive graphs, so nothing to
/// merge or verify), each scan's `odom_from_robot` as the wheel odometry (scans without one
/// reuse the previous one), calling `progress(scans_done)` after every scan.
pub fn run_slam(
    log: &LaserLog,
    params: EngineParams,
    mut progress: impl FnMut(usize),
) -> Result<SlamRun, EngineError> {
    let mut engine = Engine::new(EngineParams {
        detector: NO_DETECTOR.into(),
        ..params
    })?;
    let started = std::time::Instant::now();
    let mut odometry = Se2::identity();
    let mut keyframe_scans = Vec::new();
    let mut anchors = ScanAnchors::new();
    for (index, record) in log.scans.iter().enumerate() {
        odometry = record.odom_from_robot.unwrap_or(odometry);
        let report = engine.add_scan(&odometry, &record.scan, None)?;
        anchors.push(report.anchor.0, report.anchor.1);
        if report.keyframe.is_some() {
            keyframe_scans.push(index);
        }
        progress(index + 1);
    }
    engine.finish()?;
    let seconds = started.elapsed().as_secs_f64();
    let graph = engine.atlas.active().clone();
    let trajectory = anchors
        .trajectory(&graph)
        .into_iter()
        .map(|pose| pose.unwrap_or_else(Se2::identity))
        .collect();
    Ok(SlamRun {
        trajectory,
        info: SlamInfo {
            tracker: engine.tracker_info(),
            constraints: engine.atlas.constraint_info(),
        },
        loops: engine.atlas.loops().to_vec(),
        graph,
        keyframe_scans,
        seconds,
    })
}
