//! The lifelong mapping loop: the only place that knows the order of the stages.
//!
//! Per scan: the 2D front-end (`mapmerge-slam`) matches it and makes keyframes; each new
//! keyframe joins the atlas's active graph (`mapmerge-atlas`) with the front-end's edges;
//! every few keyframes place recognition looks for the active graph in the inactive ones and
//! merges; after a merge every new keyframe is checked by an invalid-merge detector
//! (`mapmerge-verify`) and all merges are undone when it fires (Holoch et al., Sec. III–IV).
//! A kidnap, restart or tracking failure ends the epoch ([`Engine::end_epoch`]).
//!
//! Poses: the front-end's graph and the atlas's active graph share the epoch's frame (the
//! first keyframe at the origin; a merge moves the *inactive* graph, never the active one).
//! While nothing is merged the front-end's estimate is copied; once other epochs are in the
//! active graph, new keyframes are placed by the front-end's relative motion and the atlas
//! re-optimises the merged graph whenever the front-end would have.

use std::collections::BTreeMap;
use std::sync::Arc;

use mapmerge_atlas::{
    default_verifier, Atlas, AtlasError, AtlasEvent, AtlasParams, EpochEndReason, MapId,
    MergeRequest, UnmergeReason,
};
use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_place::ScanMatchVerifier;
use mapmerge_posegraph::{Edge, EdgeId, EdgeKind, NodeId, PoseGraph2, Vertex};
use mapmerge_scan::{LaserScan, Point2};
use mapmerge_slam::{FrontEnd, FrontEndError, FrontEndParams};
use mapmerge_verify::{DetectorScan, InvalidMergeDetector, MergedMap};
use serde::{Deserialize, Serialize};

/// What can go wrong.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum EngineError {
    /// The front-end failed.
    #[error(transparent)]
    FrontEnd(#[from] FrontEndError),
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
    /// The front-end.
    pub front_end: FrontEndParams,
    /// The atlas (recognition, merging, optimisation).
    pub atlas: AtlasParams,
    /// Place recognition runs every this many new keyframes while inactive graphs exist
    /// (default: 5), with the newest `atlas.recognition.recent_queries` keyframes (default
    /// here: 1, with 3 candidates from score 0.7 and confidence 0.05: verification dominates
    /// the cost, and a wrong merge is undone).
    pub merge_every_keyframes: usize,
    /// … once the current epoch has at least this many keyframes (default: 10): a local map
    /// needs some travel before it is distinctive.
    pub min_keyframes_before_merge: usize,
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
        let mut atlas = AtlasParams::default();
        // A live robot queries with its newest keyframes only, and merges readily: a wrong
        // merge is undone by the detector (Holoch et al. run "careless" place recognition).
        let recognition = &mut atlas.recognition;
        recognition.recent_queries = 1;
        recognition.min_confidence = 0.05;
        recognition.place.candidates_per_query = 3;
        recognition.place.min_score = 0.7;
        Self {
            front_end: FrontEndParams::default(),
            atlas,
            merge_every_keyframes: 5,
            min_keyframes_before_merge: 10,
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
    /// Robot travel so far (m, front-end estimate, summed over epochs).
    pub travel_m: f64,
    /// The event.
    #[serde(flatten)]
    pub event: AtlasEvent,
}

/// The loop's state.
pub struct Engine {
    params: EngineParams,
    atlas: Atlas,
    front_end: FrontEnd,
    verifier: ScanMatchVerifier,
    /// `None`: merges are never checked (detector `none`).
    detector: Option<Box<dyn InvalidMergeDetector>>,
    /// Atlas id of every front-end node of the current epoch.
    atlas_from_front_end: BTreeMap<NodeId, NodeId>,
    /// Front-end edges already copied (ids below this).
    edges_copied: u64,
    front_end_optimizations: usize,
    keyframes_in_epoch: usize,
    keyframes_since_query: usize,
    /// Merges undone in this epoch: (inactive map, its transform), not to be made again.
    refused: Vec<(MapId, Se2)>,
    scans: usize,
    travel_m: f64,
    last_pose: Option<Se2>,
    events: Vec<EngineEvent>,
    atlas_events_seen: usize,
    /// Largest invalidity seen since the last merge.
    max_invalidity: f64,
    /// The active graph just before the last merge or unmerge (for pictures).
    before_last_change: Option<PoseGraph2>,
    /// Every merge's merge edges `(from, to, measurement)` as made, in merge order (an undo
    /// removes them from the graph).
    merge_edges: Vec<Vec<(NodeId, NodeId, Se2)>>,
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
            front_end: FrontEnd::new(params.front_end.clone())?,
            atlas: Atlas::new(params.atlas.clone()),
            params,
            verifier,
            detector,
            atlas_from_front_end: BTreeMap::new(),
            edges_copied: 0,
            front_end_optimizations: 0,
            keyframes_in_epoch: 0,
            keyframes_since_query: 0,
            refused: Vec::new(),
            scans: 0,
            travel_m: 0.0,
            last_pose: None,
            events: Vec::new(),
            atlas_events_seen: 0,
            max_invalidity: 0.0,
            before_last_change: None,
            merge_edges: Vec::new(),
        };
        engine.collect_events();
        Ok(engine)
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
        self.travel_m
    }

    /// Scans fed so far.
    pub fn scans(&self) -> usize {
        self.scans
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
    /// the front-end starts afresh. Returns the new events.
    pub fn end_epoch(&mut self, reason: EpochEndReason) -> Result<&[EngineEvent], EngineError> {
        let before = self.events.len();
        self.atlas.end_epoch(reason);
        self.front_end = FrontEnd::new(self.params.front_end.clone())?;
        self.atlas_from_front_end.clear();
        self.edges_copied = 0;
        self.front_end_optimizations = 0;
        self.keyframes_in_epoch = 0;
        self.keyframes_since_query = 0;
        self.refused.clear();
        self.last_pose = None;
        self.collect_events();
        Ok(self.events.get(before..).unwrap_or_default())
    }

    /// Feeds one scan with its wheel-odometry pose. Returns the events it caused.
    pub fn add_scan(
        &mut self,
        odom_from_robot: &Se2,
        scan: &LaserScan,
        stamp_secs: Option<f64>,
    ) -> Result<&[EngineEvent], EngineError> {
        let before = self.events.len();
        let step = self.front_end.add_scan(odom_from_robot, scan)?;
        self.scans += 1;
        if let Some(last) = self.last_pose {
            self.travel_m += last.between(&step.local_from_robot).translation().norm();
        }
        self.last_pose = Some(step.local_from_robot);
        let Some(keyframe) = step.keyframe else {
            return Ok(self.events.get(before..).unwrap_or_default());
        };
        self.add_keyframe(keyframe, stamp_secs)?;
        self.keyframes_in_epoch += 1;
        self.keyframes_since_query += 1;
        // Loops into the merged data (drift), verification of the merges so far (Sec. IV),
        // then new merges (Sec. III-A).
        if self.atlas.is_undoable() {
            if self.keyframes_in_epoch % self.params.merge_every_keyframes.max(1) == 0 {
                self.atlas.close_loops_into_merged(
                    self.params.merge_every_keyframes.max(1),
                    &self.verifier,
                )?;
            }
            self.verify()?;
        }
        if self.atlas.inactive_maps().len() > 0
            && self.keyframes_in_epoch >= self.params.min_keyframes_before_merge
            && self.keyframes_since_query >= self.params.merge_every_keyframes.max(1)
        {
            self.keyframes_since_query = 0;
            self.try_merge()?;
        }
        self.collect_events();
        Ok(self.events.get(before..).unwrap_or_default())
    }

    /// Copies a new front-end keyframe, its edges and (after a front-end optimisation) the
    /// poses into the atlas.
    fn add_keyframe(
        &mut self,
        keyframe: NodeId,
        stamp_secs: Option<f64>,
    ) -> Result<(), EngineError> {
        let graph = self.front_end.graph();
        let Some(vertex) = graph.vertex(keyframe) else {
            return Ok(());
        };
        let merged = self.atlas.is_undoable();
        // Place the new keyframe by the front-end's motion from the robot's last keyframe.
        let previous = self
            .atlas_from_front_end
            .last_key_value()
            .map(|(f, a)| (*f, *a));
        let pose = match previous {
            Some((fe_prev, atlas_prev)) if merged => {
                match (
                    graph.vertex(fe_prev),
                    self.atlas.active().vertex(atlas_prev),
                ) {
                    (Some(f), Some(a)) => a.pose.compose(&f.pose.between(&vertex.pose)),
                    _ => vertex.pose,
                }
            }
            _ => vertex.pose,
        };
        let points: Arc<[Point2]> = Arc::from(
            self.front_end
                .keyframe_points(keyframe)
                .unwrap_or_default()
                .to_vec(),
        );
        let mut atlas_vertex = Vertex::new(pose);
        atlas_vertex.meta.stamp_secs = stamp_secs;
        let id = self.atlas.add_vertex(atlas_vertex, points);
        self.atlas_from_front_end.insert(keyframe, id);
        // The front-end's new edges (odometry, submap, loops), in id order.
        let graph = self.front_end.graph();
        let new_edges: Vec<(EdgeId, Edge<Se2, 3>)> = graph
            .edges()
            .filter(|(e, _)| e.0 >= self.edges_copied)
            .map(|(e, edge)| (e, *edge))
            .collect();
        for (e, edge) in new_edges {
            self.edges_copied = self.edges_copied.max(e.0 + 1);
            let (Some(from), Some(to)) = (
                self.atlas_from_front_end.get(&edge.from).copied(),
                self.atlas_from_front_end.get(&edge.to).copied(),
            ) else {
                continue;
            };
            self.atlas.add_edge(Edge { from, to, ..edge })?;
        }
        // Poses after a front-end optimisation (loop closure).
        let optimizations = self.front_end.info().optimizations;
        if optimizations != self.front_end_optimizations {
            self.front_end_optimizations = optimizations;
            if merged {
                self.atlas.optimize_active()?;
            } else {
                let graph = self.front_end.graph();
                for (fe, atlas) in &self.atlas_from_front_end {
                    if let Some(v) = graph.vertex(*fe) {
                        self.atlas.set_pose(*atlas, v.pose)?;
                    }
                }
            }
        }
        Ok(())
    }

    /// The merged map as the detectors see it: the active graph's current-epoch and
    /// other-epoch keyframes at their poses, with their points.
    pub fn merged_map_scans(&self) -> (Vec<DetectorScan>, Vec<DetectorScan>) {
        merged_map_scans(&self.atlas)
    }

    /// Runs the detector after a new keyframe; undoes every merge when it fires.
    fn verify(&mut self) -> Result<(), EngineError> {
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
            let undone: Vec<(MapId, Se2)> = self
                .events
                .iter()
                .rev()
                .filter_map(|e| match &e.event {
                    AtlasEvent::Merged(m) => Some((
                        m.map,
                        Se2::new(
                            m.active_from_inactive[0],
                            m.active_from_inactive[1],
                            m.active_from_inactive[2],
                        ),
                    )),
                    _ => None,
                })
                .take(self.atlas.undoable_merges().len())
                .collect();
            self.before_last_change = Some(self.atlas.active().clone());
            self.atlas.unmerge_all(UnmergeReason::InvalidMerge {
                detector: detector.name().to_owned(),
                invalidity,
            })?;
            self.refused.extend(undone);
        }
        Ok(())
    }

    /// Place recognition against the inactive graphs; the best proposal not refused before
    /// is merged, and the detector starts over on the new merged map.
    fn try_merge(&mut self) -> Result<(), EngineError> {
        let (m, rad) = self.params.refused_within;
        let proposals = self.atlas.find_merges(&self.verifier);
        let Some(proposal) = proposals.into_iter().find(|p| {
            !self.refused.iter().any(|(map, t)| {
                *map == p.map
                    && (t.translation() - p.active_from_inactive.translation()).norm() <= m
                    && wrap_angle_rad(t.theta_rad - p.active_from_inactive.theta_rad).abs() <= rad
            })
        }) else {
            return Ok(());
        };
        self.apply_merge(proposal.into_request())
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
        self.apply_merge(MergeRequest::forced(map, active_from_inactive, note))
    }

    /// Adds `graph` (e.g. an earlier session's front-end graph, with `points(node)` as each
    /// vertex's keyframe points) to the atlas as an inactive graph of its own epoch: it is
    /// imported into the (empty) current epoch, which then ends. Returns its map id.
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
        self.before_last_change = Some(self.atlas.active().clone());
        let first_edge = self.atlas.active().next_edge_id();
        self.atlas.merge(request, Some(&self.verifier))?;
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
        let fresh = self
            .atlas
            .events()
            .get(self.atlas_events_seen..)
            .unwrap_or_default();
        for event in fresh {
            self.events.push(EngineEvent {
                scan: self.scans,
                travel_m: self.travel_m,
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
        let Some(points) = atlas.scans().get(node) else {
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
