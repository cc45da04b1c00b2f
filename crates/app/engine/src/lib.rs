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
//!
//! The engine keeps the state it decides with; reports are read from its events
//! ([`Engine::events`]): [`epoch_outcomes`], [`hypothesis_summary`], [`ambiguous_views`],
//! [`view_self_similarity`].

mod decisions;
mod epochs;
mod reports;
mod trajectories;

use std::collections::{BTreeSet, HashSet};
use std::sync::Arc;

use mapmerge_atlas::{
    revisits_among, Atlas, AtlasError, AtlasEvent, AtlasParams, AtlasSnapshot, ConstraintInfo,
    ConstraintSearch, LoopEdge, LoopRecord, MaintenanceReport, MapId, MemoryBackups, MergeReason,
    MergeRequest, UnmergeReason,
};
use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_hypothesis::{
    AmbiguityTracker, FilterEvent, Hypothesis, HypothesisError, HypothesisFilter, HypothesisId,
    HypothesisState, Observation, RejectReason, Target,
};
use mapmerge_params::{Checker, ParamError, Real, Validate};
use mapmerge_place::{ScanMatchVerifier, SelfSimilarity};
use mapmerge_posegraph::{EdgeKind, NodeId, PoseGraph2};
use mapmerge_scan::{LaserLog, LaserScan, Point2};
use mapmerge_slam::{
    LocalTracker, ScanAnchors, TrackerError, TrackerInfo, TrackerParams, TrackingState,
};
use mapmerge_verify::{
    DetectorParams, DetectorScan, InvalidMergeDetector, LearnedDetector, LearnedModel, MergedMap,
    RatioSupport,
};
use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

use decisions::Conditional;
pub use decisions::{
    Decision, DecisionParams, DetectorReading, EventKind, MergeRecord, MergeState, ObservedEdge,
};
pub use epochs::{epoch_outcomes, EpochEnd, EpochOutcome};
pub use mapmerge_atlas::EpochEndReason;
/// Counters of the merge and recovery hypotheses (`created`, `merge`, `recovery`,
/// `conditional`, `full`, `rejected_conditional`, `expired`).
pub use mapmerge_hypothesis::FilterStats as HypothesisSummary;
pub use reports::{ambiguous_views, hypothesis_summary, view_self_similarity};
pub use trajectories::{MapScan, MapTrajectory};

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
    /// The hypothesis filter refused an input (non-finite or not positive definite).
    #[error("hypothesis filter: {0}")]
    Hypothesis(#[from] HypothesisError),
    /// A graph could not be imported.
    #[error("import: {0}")]
    Import(String),
    /// No detector of that name.
    #[error("unknown invalid-merge detector `{0}` (known: {1})")]
    UnknownDetector(String, String),
    /// A `learned_model` was given for another detector.
    #[error("learned_model is for detector `learned`, but the detector is `{0}`")]
    ModelWithoutLearned(String),
    /// A parameter out of its range (its path in the engine's parameters).
    #[error(transparent)]
    Params(#[from] ParamError),
}

/// [`EngineParams::detector`] for no verification.
pub const NO_DETECTOR: &str = "none";

/// Parameters of the loop.
///
/// Absent fields keep their defaults; unknown fields are refused, at every level. A config
/// that names a removed option, such as the decision options measured, rejected and deleted in
/// issue 63 (`decisions.confirm_tentative`, `query_self_similarity`, `confirm_at_epoch_end`,
/// `epoch_agreement`, `epoch_agreement_every_m`), fails with serde's "unknown field" error
/// naming it, rather than running without it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EngineParams {
    /// The local tracker.
    pub tracker: TrackerParams,
    /// The atlas (loop closing, recognition, merging, optimisation).
    pub atlas: AtlasParams,
    /// Merge decisions on accumulated evidence (hypotheses, conditional merges, ambiguous
    /// views).
    pub decisions: DecisionParams,
    /// The invalid-merge detector (a name of `mapmerge_verify::DETECTOR_NAMES`, or `none`
    /// for no verification, as in an evaluation that runs its own detectors; default
    /// `learned`, the calibrated decision of `mapmerge_verify::LearnedModel::calibrated`: a
    /// logistic regression on change detection and gridmap fitted on forced merges of the
    /// public logs and of the simulator's fitting seeds, joined with better hypothesis by a
    /// noisy-or; the probability that the merge is invalid at equal priors, threshold 0.5; its
    /// components keep the parameters it was fitted with, so `detector_params` does not reach
    /// them). On the fitting seeds it makes every decision `combined` (the hand-calibrated
    /// decision) makes, on the held-out seeds every count is the same, and on the public
    /// logs it takes the same time (docs/benchmarks.md, "Invalid-merge detection").
    /// A model fitted on the engine's own merges (`learned_model`,
    /// `scripts/fit_engine_decision.sh`) caught more wrong merges than `combined` on its
    /// fitting seeds but also undid more correct ones (17 against 10), so it is not the
    /// default.
    pub detector: String,
    /// The model of detector `learned` (default: none, `LearnedModel::calibrated`); e.g. one
    /// fitted by `mapmerge eval calibrate` on the engine's own merges. An error with any
    /// other detector.
    pub learned_model: Option<LearnedModel>,
    /// The detectors' parameters by name, the defaults where absent (e.g. `{"combined":
    /// {"change_detection_threshold": 0.3, "change_detection": {"range_tolerance_m":
    /// 0.15}}}`); only the chosen `detector`'s are used.
    pub detector_params: DetectorParams,
    /// Undo all merges when its invalidity exceeds this (default: 0.5; for `learned`, a
    /// merge more likely invalid than valid; above 1: never).
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
            decisions: DecisionParams::default(),
            detector: "learned".into(),
            learned_model: None,
            detector_params: DetectorParams::default(),
            unmerge_threshold: 0.5,
            refused_within: (1.0, 10f64.to_radians()),
        }
    }
}

impl Validate for EngineParams {
    fn check(&self, check: &mut Checker) {
        let known = self.detector == NO_DETECTOR
            || mapmerge_verify::DETECTOR_NAMES.contains(&self.detector.as_str());
        check
            .nested("tracker", &self.tracker)
            .nested("atlas", &self.atlas)
            .nested("decisions", &self.decisions)
            .rule(
                "detector",
                &self.detector,
                known,
                &format!(
                    "must be one of {}, {NO_DETECTOR}",
                    mapmerge_verify::DETECTOR_NAMES.join(", ")
                ),
            )
            .rule(
                "learned_model",
                format_args!("a model with detector `{}`", self.detector),
                self.learned_model.is_none() || self.detector == "learned",
                "is for detector `learned` only",
            )
            .nested_opt("learned_model", self.learned_model.as_ref())
            .nested("detector_params", &self.detector_params)
            .real(
                "unmerge_threshold",
                self.unmerge_threshold,
                Real::fraction(),
            )
            .reals(
                "refused_within",
                &[
                    (self.refused_within.0, Real::non_negative()),
                    (
                        self.refused_within.1,
                        Real::within(0.0, std::f64::consts::PI),
                    ),
                ],
            );
    }
}

/// An event with where and when it happened: an atlas mutation, a hypothesis change or a
/// decision, one JSON object each (`events.jsonl`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EngineEvent {
    /// Scans fed to the engine so far (the event happened after scan `scan - 1`).
    pub scan: usize,
    /// Robot travel so far (m, tracker estimate, summed over epochs).
    pub travel_m: f64,
    /// The event.
    #[serde(flatten)]
    pub event: EventKind,
}

impl EngineEvent {
    /// The atlas event, if it is one.
    pub fn atlas(&self) -> Option<&AtlasEvent> {
        match &self.event {
            EventKind::Atlas(event) => Some(event),
            _ => None,
        }
    }
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
    /// The merged epochs' keyframes the detector does not judge, fixed at each merge: the
    /// revisits among them (`atlas.loops.revisit_spacing_m`), so what the detectors hold
    /// follows the mapped area, not the time spent in it.
    detector_revisits: HashSet<NodeId>,
    /// Merges undone in this epoch: (inactive map, its transform), not to be made again.
    refused: Vec<(MapId, Se2)>,
    scans: usize,
    /// Travel of the previous epochs (m).
    travel_before_epoch_m: f64,
    events: Vec<EngineEvent>,
    atlas_events_seen: usize,
    /// The active graph just before the last merge or unmerge (for pictures).
    before_last_change: Option<PoseGraph2>,
    /// Every merge decision as it went, in order.
    merge_log: Vec<MergeRecord>,
    /// Counters of the tracker of the previous epochs.
    tracker_info_before_epoch: TrackerInfo,
    /// Merge and recovery hypotheses (Banerjee et al., Sec. 3.2.1).
    filter: HypothesisFilter<ObservedEdge>,
    /// Ambiguous views (Sec. 5.3).
    ambiguity: AmbiguityTracker,
    /// The search for views whose own map fits itself elsewhere (`decisions.self_similarity`).
    self_similarity: Option<SelfSimilarity>,
    /// Views of inactive graphs searched so far, by node, with their best other placement's
    /// score (each view is searched once).
    self_similarity_of_view: std::collections::BTreeMap<NodeId, f64>,
    /// Joint local maps of a hypothesis's self-similar views searched so far, by their
    /// sorted views, with their best other placement's score (`decisions.joint_views`).
    joint_self_similarity: std::collections::BTreeMap<Vec<u64>, f64>,
    /// Time spent in those searches (s).
    self_similarity_seconds: f64,
    /// The conditional merge and its graph copy G' (Sec. 5.2).
    conditional: Option<Conditional>,
    /// Place-recognition matches in the merged data while merged in this epoch: agreeing
    /// with the merged map's estimate, and contradicting it (issue 64, part 4).
    merged_matches: (usize, usize),
    /// The epoch whose agreement was judged (once, by `finish` or at its end).
    agreement_judged: Option<mapmerge_atlas::EpochId>,
    /// The tracker's pose of the previous keyframe (the EKF's motion update).
    previous_keyframe_local: Option<Se2>,
    /// Every scan of the run on its keyframe, and its stamp as fed.
    anchors: ScanAnchors,
    stamps: Vec<Option<f64>>,
    /// The scans the tracker holds in doubt (relocalizing), as fed: should it lose track,
    /// they are fed again to the new epoch.
    in_doubt: Vec<(Se2, LaserScan, Option<f64>)>,
}

/// At most this many views of a hypothesis are joined for `decisions.joint_views`.
const JOINT_VIEWS_MAX: usize = 8;

/// The surroundings a predicted match's rival is searched in (`decisions.track_unique`): at
/// most this many views …
const RIVAL_VIEWS: usize = 8;
/// … at least this far apart (m).
const RIVAL_SPACING_M: f64 = 2.0;

impl Engine {
    /// A new engine: epoch 0 starts.
    pub fn new(params: EngineParams) -> Result<Self, EngineError> {
        params.validate()?;
        let detector: Option<Box<dyn InvalidMergeDetector>> =
            match (params.detector.as_str(), &params.learned_model) {
                ("learned", Some(model)) => Some(Box::new(LearnedDetector::new(model.clone()))),
                (name, Some(_)) => return Err(EngineError::ModelWithoutLearned(name.to_owned())),
                (NO_DETECTOR, None) => None,
                (name, None) => Some(params.detector_params.detector(name).ok_or_else(|| {
                    EngineError::UnknownDetector(
                        params.detector.clone(),
                        format!(
                            "{}, {NO_DETECTOR}",
                            mapmerge_verify::DETECTOR_NAMES.join(", ")
                        ),
                    )
                })?),
            };
        let verifier = params
            .atlas
            .recognition
            .verifier
            .verifier()
            .map_err(|e| EngineError::Verifier(e.to_string()))?;
        let filter = HypothesisFilter::new(params.decisions.filter.clone())?;
        let ambiguity = AmbiguityTracker::new(params.decisions.ambiguity.clone())?;
        let self_similarity = params
            .decisions
            .self_similarity
            .map(|p| SelfSimilarity::new(p, params.atlas.recognition.verifier.evidence))
            .transpose()
            .map_err(|e| EngineError::Verifier(e.to_string()))?;
        let mut engine = Self {
            filter,
            ambiguity,
            self_similarity,
            self_similarity_of_view: std::collections::BTreeMap::new(),
            joint_self_similarity: std::collections::BTreeMap::new(),
            self_similarity_seconds: 0.0,
            conditional: None,
            merged_matches: (0, 0),
            agreement_judged: None,
            previous_keyframe_local: None,
            anchors: ScanAnchors::new(),
            stamps: Vec::new(),
            in_doubt: Vec::new(),
            tracker: LocalTracker::new(params.tracker.clone())?,
            atlas: Atlas::new(params.atlas.clone())?,
            params,
            verifier,
            detector,
            detector_revisits: HashSet::new(),
            refused: Vec::new(),
            scans: 0,
            travel_before_epoch_m: 0.0,
            events: Vec::new(),
            atlas_events_seen: 0,
            before_last_change: None,
            merge_log: Vec::new(),
            tracker_info_before_epoch: TrackerInfo::default(),
        };
        engine.collect_events();
        Ok(engine)
    }

    /// An engine continuing a stored atlas (the lifelong store, iRobot Sec. 4): the atlas is
    /// restored from `atlas` ([`Atlas::restore`], the place index rebuilt) and everything
    /// else starts afresh, as after a restart. The robot's epoch is the snapshot's until the
    /// caller ends it (a restarted robot does not know where it is: `end_epoch(Restart)`).
    pub fn resume(params: EngineParams, atlas: AtlasSnapshot) -> Result<Self, EngineError> {
        let mut engine = Self::new(params)?;
        engine.atlas =
            Atlas::restore(engine.params.atlas.clone(), MemoryBackups::default(), atlas)?;
        engine.events.clear();
        engine.atlas_events_seen = 0;
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
        self.tracker_info_before_epoch + self.tracker.info()
    }

    /// The active graph as it was just before the last merge or unmerge.
    pub fn before_last_change(&self) -> Option<&PoseGraph2> {
        self.before_last_change.as_ref()
    }

    /// Every merge decision as it went, in order (conditional, full, rejected, undone).
    pub fn merge_log(&self) -> &[MergeRecord] {
        &self.merge_log
    }

    /// Joint local maps of a merge hypothesis's self-similar views searched so far
    /// (`decisions.joint_views`), by their sorted views, with their best other placement's
    /// score; below `decisions.self_similar_from_score` the views counted in full.
    pub fn joint_self_similarity(&self) -> &std::collections::BTreeMap<Vec<u64>, f64> {
        &self.joint_self_similarity
    }

    /// Time spent searching views (and joint sets of views) for another placement of their
    /// own map (s).
    pub fn self_similarity_seconds(&self) -> f64 {
        self.self_similarity_seconds
    }

    /// The graph read-only queries use (Sec. 5.2): G' while a merge is conditional, else the
    /// atlas's active graph.
    pub fn map_graph(&self) -> &PoseGraph2 {
        self.conditional
            .as_ref()
            .map_or(self.atlas.active(), |c| &c.graph)
    }

    /// The conditional merge's edges `(from, to)`, if one is conditional.
    pub fn conditional_edges(&self) -> Vec<(NodeId, NodeId)> {
        self.conditional.as_ref().map_or_else(Vec::new, |c| {
            c.edges.iter().map(|e| (e.inactive, e.active)).collect()
        })
    }

    /// The robot's pose as read-only queries see it (in G' while a merge is conditional).
    pub fn robot_pose(&self) -> Option<Se2> {
        let robot = self.atlas.robot_node()?;
        Some(self.map_graph().vertex(robot)?.pose)
    }

    /// The atlas node of the robot's newest keyframe.
    pub fn robot_node(&self) -> Option<NodeId> {
        self.atlas.robot_node()
    }

    /// Ends the epoch (kidnap, restart, tracking failure): hypotheses are dropped (a
    /// conditional merge with them), the active graph becomes inactive, the tracker starts
    /// afresh. Returns the new events.
    pub fn end_epoch(&mut self, reason: EpochEndReason) -> Result<&[EngineEvent], EngineError> {
        let before = self.events.len();
        self.collect_events();
        let cleared = self.filter.clear();
        self.log_filter_events(cleared);
        if let Some(conditional) = self.conditional.take() {
            // Neither confirmed nor refuted: it stays "conditional" in the log.
            self.log_decision(Decision::ConditionalDropped {
                hypothesis: conditional.hypothesis.0,
                map: conditional.map,
                reason: "epoch ended".into(),
            });
        }
        self.atlas.optimize_if_due(true)?;
        self.judge_epoch_agreement()?;
        self.atlas.end_epoch(reason);
        self.merged_matches = (0, 0);
        self.tracker_info_before_epoch = self.tracker_info();
        self.travel_before_epoch_m += self.tracker.travel_m();
        self.tracker = LocalTracker::new(self.params.tracker.clone())?;
        self.previous_keyframe_local = None;
        self.refused.clear();
        self.in_doubt.clear();
        self.collect_events();
        Ok(self.events.get(before..).unwrap_or_default())
    }

    /// Before an epoch's merges become final (issue 64, part 4): how well the epoch agrees
    /// with the epochs merged into it ([`Atlas::epoch_agreement`] and the matches in the
    /// merged data), logged as an `epoch_agreement` decision; with
    /// `decisions.undo_disagreeing_edges` of them unsatisfied, every merge is undone.
    fn judge_epoch_agreement(&mut self) -> Result<(), EngineError> {
        let epoch = self.atlas.current_epoch();
        if !self.atlas.is_undoable() || self.agreement_judged == Some(epoch) {
            return Ok(());
        }
        self.agreement_judged = Some(epoch);
        let agreement = self.atlas.epoch_agreement();
        let (confirmations, contradictions) = self.merged_matches;
        let undo = self
            .params
            .decisions
            .undo_disagreeing_edges
            .is_some_and(|n| agreement.disagreeing_edges >= n);
        self.log_decision(Decision::EpochAgreement {
            agreeing_edges: agreement.agreeing_edges,
            disagreeing_edges: agreement.disagreeing_edges,
            disagreeing_merge_edges: agreement.disagreeing_merge_edges,
            worst_off_m: agreement.worst_off_m,
            confirmations,
            contradictions,
            undone: undo,
        });
        if undo {
            self.undo_all(UnmergeReason::InconsistentEpochs {
                agreeing_edges: agreement.agreeing_edges,
                disagreeing_edges: agreement.disagreeing_edges,
                disagreeing_merge_edges: agreement.disagreeing_merge_edges,
                worst_off_m: agreement.worst_off_m,
            })?;
        }
        Ok(())
    }

    /// Ends a session of a lifelong robot (iRobot Sec. 4): its epoch ends (a restart), every
    /// merge becomes final, fragments rejoin the site map where found in it
    /// ([`Atlas::rejoin_fragments`]), and the atlas is maintained with `atlas.maintenance`
    /// ([`Atlas::maintain`]); the session's vertices are those from `first_node` on. The next
    /// scan starts a new epoch.
    pub fn end_session(&mut self, first_node: NodeId) -> Result<MaintenanceReport, EngineError> {
        self.end_epoch(EpochEndReason::Restart)?;
        let params = self.params.atlas.maintenance.clone();
        self.atlas
            .rejoin_fragments(&params.rejoin, &self.verifier)?;
        self.collect_events();
        let before = self.nodes_before();
        let report = self.atlas.maintain(&params, first_node)?;
        let atlas = &self.atlas;
        self.anchors
            .reanchor(&before, |node| atlas.pose_of(node).is_some());
        Ok(report)
    }

    /// Optimises once more if loops wait, and judges the epoch's agreement with the epochs
    /// merged into it (see `end_epoch`), undoing its merges if they disagree (call after a
    /// log's last scan).
    pub fn finish(&mut self) -> Result<(), EngineError> {
        self.atlas.optimize_if_due(true)?;
        self.judge_epoch_agreement()
    }

    /// Feeds one scan with its wheel-odometry pose; see the crate docs for the steps.
    pub fn add_scan(
        &mut self,
        odom_from_robot: &Se2,
        scan: &LaserScan,
        stamp_secs: Option<f64>,
    ) -> Result<ScanReport<'_>, EngineError> {
        let before = self.events.len();
        let (anchor, keyframe) = self.feed_scan(odom_from_robot, scan, stamp_secs)?;
        Ok(ScanReport {
            anchor,
            keyframe,
            events: self.events.get(before..).unwrap_or_default(),
        })
    }

    /// [`Engine::add_scan`]'s steps; the anchor and keyframe of the scan.
    fn feed_scan(
        &mut self,
        odom_from_robot: &Se2,
        scan: &LaserScan,
        stamp_secs: Option<f64>,
    ) -> Result<((NodeId, Se2), Option<NodeId>), EngineError> {
        // 1. Track (a scan the tracker refuses is not counted).
        let tracked =
            self.tracker
                .add_scan(odom_from_robot, scan, stamp_secs, self.atlas.next_node_id())?;
        self.scans += 1;
        let anchor = tracked.anchor;
        self.anchors.push(anchor.0, anchor.1);
        self.stamps.push(stamp_secs);
        if tracked.state == TrackingState::Tracking {
            self.in_doubt.clear();
        } else {
            self.in_doubt
                .push((*odom_from_robot, scan.clone(), stamp_secs));
        }
        if let Some(lost) = tracked.lost {
            return self.lose_track(lost, anchor);
        }
        let Some(insertion) = tracked.keyframe else {
            return Ok((anchor, None));
        };
        let local_from_robot = insertion.local_from_robot;
        // 2. Insert the keyframe.
        let loops_before = self.atlas.loops().len();
        let node = self.atlas.insert_keyframe(insertion, stamp_secs)?;
        // 3. Search constraints.
        let found = self.atlas.search_constraints(node, &self.verifier)?;
        self.collect_events();
        // 4. Update the hypotheses; merge conditionally or fully.
        let decided = self.update_hypotheses(local_from_robot, loops_before, found)?;
        // 5. Optimise.
        self.atlas.optimize_if_due(false)?;
        // 6. Verify and 7. undo (a merge decided now is checked from the next keyframe on).
        if !decided {
            self.verify_and_undo()?;
        }
        self.collect_events();
        Ok((anchor, Some(node)))
    }

    /// The tracker lost track (issue 65): the scans in doubt, which made no keyframe, are
    /// taken back; the epoch ends with `tracking_lost`; they are fed to the new epoch. The
    /// anchor and keyframe of the last of them (`anchor`, the scan's in the old epoch, when
    /// none was held).
    fn lose_track(
        &mut self,
        lost: mapmerge_slam::LostReport,
        anchor: (NodeId, Se2),
    ) -> Result<((NodeId, Se2), Option<NodeId>), EngineError> {
        let in_doubt = std::mem::take(&mut self.in_doubt);
        let kept = self.scans - in_doubt.len();
        self.scans = kept;
        self.anchors.truncate(kept);
        self.stamps.truncate(kept);
        self.log_decision(Decision::TrackingLost {
            cause: lost.cause,
            in_doubt: lost.in_doubt,
        });
        self.end_epoch(EpochEndReason::TrackingLost)?;
        let mut last = None;
        for (odom_from_robot, scan, stamp_secs) in &in_doubt {
            last = Some(self.feed_scan(odom_from_robot, scan, *stamp_secs)?);
        }
        Ok(last.unwrap_or((anchor, None)))
    }

    /// Step 4: the motion update, every observation into the hypothesis filter (merge
    /// candidates of inactive graphs, contradictions of the own graph), the ambiguity
    /// tracker, then conditional and full merges. Returns whether a merge was decided on.
    fn update_hypotheses(
        &mut self,
        local_from_robot: Se2,
        loops_before: usize,
        found: ConstraintSearch,
    ) -> Result<bool, EngineError> {
        let travel_m = self.travel_m();
        let decisions = self.params.decisions.clone();
        self.refresh_conditional_graph();
        if let Some(previous) = self.previous_keyframe_local {
            let increment = previous.between(&local_from_robot);
            // A motion the filter refuses (non-finite) leaves the hypotheses as they were.
            if let Ok(events) = self.filter.predict(
                &increment,
                &decisions.motion_covariance(&increment),
                travel_m,
                None,
            ) {
                self.log_filter_events(events);
            }
        }
        self.previous_keyframe_local = Some(local_from_robot);
        // Accepted observations of views (Sec. 5.3's accepted tracker).
        let accepted: Vec<NodeId> = self
            .atlas
            .loops()
            .get(loops_before..)
            .unwrap_or_default()
            .iter()
            .map(|l| l.from)
            .chain(found.merged_loops.iter().map(|l| l.inactive))
            .chain(found.confirmations.iter().map(|l| l.from))
            .collect();
        for view in accepted {
            self.ambiguity.on_accepted(view.0, view.0, travel_m);
        }
        self.merged_matches.0 += found.confirmations.len();
        self.merged_matches.1 += found
            .contradictions
            .iter()
            .filter(|r| !self.atlas.is_current_epoch(r.from))
            .count();
        let mut accepted_hypotheses = Vec::new();
        // Contradictions of the own graph: rejected observations, recovery evidence.
        for record in &found.contradictions {
            self.ambiguity.on_rejected(record.from.0, travel_m);
            if !decisions.recover {
                continue;
            }
            let Some(map_from_view) = self.atlas.active().vertex(record.from).map(|v| v.pose)
            else {
                continue;
            };
            let robot_from_active = map_from_view.compose(&record.measurement).inverse();
            let observation = Observation {
                target: Target::Recovery,
                view: record.from.0,
                robot: record.to.0,
                robot_from_target: robot_from_active,
                covariance: decisions.observation_covariance(&record.covariance),
                ambiguous: self.ambiguity.is_ambiguous(record.from.0),
                edge: ObservedEdge::Recovery(*record),
            };
            accepted_hypotheses.extend(self.observe(observation, travel_m).1);
        }
        // Matches in inactive graphs: merge evidence; while a merge is conditional, the new
        // keyframe verified where G' puts it (the robot behaves as localised, Sec. 5.2).
        let merge_matches: Vec<(MapId, LoopEdge, Matrix3<f64>)> = found
            .merge_candidates
            .iter()
            .filter_map(|p| Some((p.map, *p.loops.first()?, p.covariance)))
            .collect();
        // Matches verified where a hypothesis puts the robot (G' of a conditional merge, or
        // the tracked hypothesis's estimate): they are checked for a rival placement nearby
        // (`decisions.track_unique`).
        let mut predicted: Vec<(MapId, LoopEdge)> = Vec::new();
        if let Some(conditional) = &self.conditional {
            if self.keyframes_in_epoch() % decisions.confirm_every_keyframes.max(1) == 0 {
                if let Some(node) = self.atlas.robot_node() {
                    predicted.extend(
                        self.atlas
                            .confirm_in_preview(
                                &conditional.graph,
                                conditional.map,
                                &[node],
                                &self.verifier,
                            )
                            .into_iter()
                            .map(|edge| (conditional.map, edge)),
                    );
                }
            }
        } else if let Some(every) = decisions.track_every_keyframes {
            if self.keyframes_in_epoch() % every.max(1) == 0 {
                if let (Some((map, estimate)), Some(robot)) =
                    (self.tracked_hypothesis(), self.atlas.robot_node())
                {
                    predicted.extend(
                        self.atlas
                            .confirm_at(map, &estimate, &[robot], &self.verifier)
                            .into_iter()
                            .map(|edge| (map, edge)),
                    );
                }
            }
        }
        let starting = decisions.start_unique && self.atlas.starting_session();
        for (map, edge, covariance) in merge_matches {
            let ambiguous = starting && self.has_rival(map, &edge);
            accepted_hypotheses.extend(self.observe_merge_match(
                map,
                edge,
                &covariance,
                ambiguous,
                travel_m,
            ));
        }
        for (map, edge) in predicted {
            let ambiguous = decisions.track_unique && self.has_rival(map, &edge);
            accepted_hypotheses.extend(self.observe_merge_match(
                map,
                edge,
                &covariance_of(&edge),
                ambiguous,
                travel_m,
            ));
        }
        let newly = self.ambiguity.update(travel_m);
        if !newly.is_empty() {
            self.filter.discount_views(&newly.iter().copied().collect());
            self.log_decision(Decision::AmbiguousViews { views: newly });
        }
        // Full acceptances first (one takes over its own conditional merge), then G' follows
        // the filter's conditional hypothesis.
        let mut decided = false;
        for hypothesis in accepted_hypotheses {
            decided |= self.accept_fully(hypothesis)?;
        }
        decided |= self.sync_conditional()?;
        Ok(decided)
    }

    /// A verified match of active keyframe `edge.active` against view `edge.inactive` of
    /// inactive graph `map` as a merge observation (Eq. 3), made at robot travel `travel_m`;
    /// the view is searched for self-similarity first. A keyframe older than the robot's is
    /// brought into the robot's frame along the active graph. The observation is ambiguous
    /// when its view is, or when `ambiguous` says so (a predicted match with a rival). Returns
    /// the hypotheses it made fully accepted.
    fn observe_merge_match(
        &mut self,
        map: MapId,
        edge: LoopEdge,
        covariance: &Matrix3<f64>,
        ambiguous: bool,
        travel_m: f64,
    ) -> Vec<Hypothesis<ObservedEdge>> {
        let Some(map_from_keyframe) = self.keyframe_in_map(map, &edge) else {
            return Vec::new();
        };
        let mut robot_from_inactive = map_from_keyframe.inverse();
        if let Some(robot) = self.atlas.robot_node().filter(|r| *r != edge.active) {
            let active = self.atlas.active();
            let (Some(robot_pose), Some(keyframe_pose)) = (
                active.vertex(robot).map(|v| v.pose),
                active.vertex(edge.active).map(|v| v.pose),
            ) else {
                return Vec::new();
            };
            robot_from_inactive = robot_pose
                .between(&keyframe_pose)
                .compose(&robot_from_inactive);
        }
        let view_self_similar = self.check_self_similarity(map, edge.inactive);
        let observation = Observation {
            target: Target::Merge { map: map.0 },
            view: edge.inactive.0,
            robot: edge.active.0,
            robot_from_target: robot_from_inactive,
            covariance: self.params.decisions.observation_covariance(covariance),
            ambiguous: ambiguous || self.ambiguity.is_ambiguous(edge.inactive.0),
            edge: ObservedEdge::Merge(edge),
        };
        let (id, accepted) = self.observe(observation, travel_m);
        let mut accepted: Vec<_> = accepted.into_iter().collect();
        if let (true, Some(id)) = (view_self_similar, id) {
            accepted.extend(self.count_jointly_unique_views(id, map));
        }
        accepted
    }

    /// True when the active keyframe of `edge` fits the surroundings of its view in inactive
    /// graph `map` at another place as well (from `decisions.self_similar_from_score`): the
    /// rival search of `decisions.track_unique`, logged as an event. False when
    /// `decisions.self_similarity` is off or a local map is missing.
    fn has_rival(&mut self, map: MapId, edge: &LoopEdge) -> bool {
        let Some(search) = self.self_similarity.as_ref() else {
            return false;
        };
        let started = std::time::Instant::now();
        let radius_m = search.params().radius_m;
        let score = self
            .atlas
            .view_surroundings(map, edge.inactive, radius_m, RIVAL_SPACING_M, RIVAL_VIEWS)
            .zip(self.atlas.query_keyframe(edge.active))
            .and_then(|(surroundings, query)| {
                search.best_rival_placement(&surroundings, &query, &edge.inactive_from_active)
            })
            .map_or(0.0, |(_, proof)| proof.score);
        // Beyond the surroundings: wherever retrieval finds the robot's local map in the
        // graph (a hall's turned twin, an aisle at the far end), away from the match.
        let score = score.max(self.retrieved_rival_score(map, edge));
        self.self_similarity_seconds += started.elapsed().as_secs_f64();
        self.log_decision(Decision::TrackedRival {
            map,
            view: edge.inactive.0,
            robot: edge.active.0,
            score,
        });
        score >= self.params.decisions.self_similar_from_score
    }

    /// Where match `edge` puts its active keyframe in inactive graph `map`
    /// (`map_from_keyframe`); `None` for an unknown graph or view.
    fn keyframe_in_map(&self, map: MapId, edge: &LoopEdge) -> Option<Se2> {
        let map_from_view = self.atlas.inactive(map)?.vertex(edge.inactive)?.pose;
        Some(map_from_view.compose(&edge.inactive_from_active))
    }

    /// The best score of a placement of `edge.active` in inactive graph `map` that place
    /// retrieval and verification find away from where `edge` puts it (beyond
    /// `place.same_place_m` or `place.same_place_rad`); 0 when there is none.
    fn retrieved_rival_score(&self, map: MapId, edge: &LoopEdge) -> f64 {
        let Some(matched) = self.keyframe_in_map(map, edge) else {
            return 0.0;
        };
        let place = &self.params.atlas.recognition.place;
        self.atlas
            .placements_by_retrieval(map, edge.active, &self.verifier)
            .into_iter()
            .filter(|(_, map_from_query, _)| {
                let apart = matched.between(map_from_query);
                apart.translation().norm() > place.same_place_m
                    || apart.theta_rad.abs() > place.same_place_rad
            })
            .map(|(_, _, score)| score)
            .fold(0.0, f64::max)
    }

    /// Marks view `node` of inactive graph `map` ambiguous when its own local map fits itself
    /// at another place (`decisions.self_similarity`); each view is searched once.
    fn check_self_similarity(&mut self, map: MapId, node: NodeId) -> bool {
        let threshold = self.params.decisions.self_similar_from_score;
        if let Some(score) = self.self_similarity_of_view.get(&node) {
            return *score >= threshold;
        }
        let Some(score) = self.self_similarity_score(|atlas| atlas.view_keyframe(map, node)) else {
            return false;
        };
        self.self_similarity_of_view.insert(node, score);
        self.log_decision(Decision::SelfSimilarity {
            map,
            node: node.0,
            score,
        });
        let self_similar = score >= threshold;
        if self_similar && self.ambiguity.mark(node.0) {
            self.log_decision(Decision::AmbiguousViews {
                views: vec![node.0],
            });
        }
        self_similar
    }

    /// The score of the best placement of a local map on itself away from the identity (0
    /// when there is none, or no such local map), the map made by `local_map` from the atlas;
    /// `None` when `decisions.self_similarity` is off. Its time counts in
    /// `self_similarity_seconds`.
    fn self_similarity_score(
        &mut self,
        local_map: impl FnOnce(&Atlas) -> Option<mapmerge_place::Keyframe>,
    ) -> Option<f64> {
        let search = self.self_similarity.as_ref()?;
        let started = std::time::Instant::now();
        let score = local_map(&self.atlas)
            .and_then(|keyframe| search.best_other_placement(&keyframe))
            .map_or(0.0, |(_, proof)| proof.score);
        self.self_similarity_seconds += started.elapsed().as_secs_f64();
        Some(score)
    }

    /// A merge hypothesis whose views fit themselves elsewhere one by one counts them in
    /// full when their joint local map fits nowhere else (`decisions.joint_views`): rack
    /// rows seen from two aisles, one of them beside the wall, are one place only. Only
    /// those views are joined (a view that is no look-alike counts already, and would make
    /// any set look unique). Searched once per set of views. Returns the hypothesis if that
    /// made it fully accepted.
    fn count_jointly_unique_views(
        &mut self,
        id: HypothesisId,
        map: MapId,
    ) -> Option<Hypothesis<ObservedEdge>> {
        let decisions = &self.params.decisions;
        let threshold = decisions.self_similar_from_score;
        let hypothesis = self.filter.hypothesis(id)?;
        if !decisions.joint_views
            || self.self_similarity.is_none()
            || !matches!(
                hypothesis.state(),
                HypothesisState::Tentative | HypothesisState::Conditional
            )
        {
            return None;
        }
        let views: BTreeSet<u64> = hypothesis
            .observations()
            .iter()
            .map(|r| r.observation.view)
            .collect();
        let self_similar: BTreeSet<u64> = views
            .iter()
            .filter(|v| {
                self.self_similarity_of_view
                    .get(&NodeId(**v))
                    .is_some_and(|score| *score >= threshold)
            })
            .copied()
            .collect();
        if self_similar.len() < 2 {
            return None;
        }
        // At most `JOINT_VIEWS_MAX` of them, spread over the set.
        let all: Vec<u64> = self_similar.iter().copied().collect();
        let step = all.len().div_ceil(JOINT_VIEWS_MAX).max(1);
        let joint: Vec<u64> = all.iter().step_by(step).copied().collect();
        let score = match self.joint_self_similarity.get(&joint) {
            Some(score) => *score,
            None => {
                let nodes: Vec<NodeId> = joint.iter().map(|v| NodeId(*v)).collect();
                let score =
                    self.self_similarity_score(|atlas| atlas.joint_view_keyframe(map, &nodes))?;
                self.joint_self_similarity.insert(joint, score);
                score
            }
        };
        if score >= threshold {
            return None;
        }
        let outcome = self
            .filter
            .count_again(id, |o| self_similar.contains(&o.view))?;
        self.log_filter_events(outcome.events);
        outcome.accepted
    }

    /// One observation into the filter; its events are logged. An observation the filter
    /// refuses (non-finite, a covariance that is not positive definite) is skipped: the
    /// filter is unchanged then. Returns the hypothesis it made fully accepted, if any.
    fn observe(
        &mut self,
        observation: Observation<ObservedEdge>,
        travel_m: f64,
    ) -> (Option<HypothesisId>, Option<Hypothesis<ObservedEdge>>) {
        let Ok(outcome) = self.filter.observe(observation, travel_m, None) else {
            return (None, None);
        };
        self.log_filter_events(outcome.events);
        (Some(outcome.hypothesis), outcome.accepted)
    }

    /// Keeps the conditional merge in step with the filter's conditional hypothesis: drops
    /// G' when the filter no longer holds it (superseded, expired, rejected), makes G' for a
    /// new one. Returns whether a conditional merge started.
    fn sync_conditional(&mut self) -> Result<bool, EngineError> {
        let wanted = self.filter.conditional().map(|h| h.id());
        if let Some(current) = self.conditional.as_mut() {
            if Some(current.hypothesis) == wanted {
                // G' gets the hypothesis's newer edges too.
                if let Some(hypothesis) = self.filter.conditional() {
                    for edge in merge_edges_of(hypothesis) {
                        if !current
                            .edges
                            .iter()
                            .any(|e| e.active == edge.active && e.inactive == edge.inactive)
                        {
                            current.edges.push(edge);
                        }
                    }
                }
                return Ok(false);
            }
            self.drop_conditional("superseded or expired".into());
        }
        let Some(hypothesis) = self.filter.conditional() else {
            return Ok(false);
        };
        let id = hypothesis.id();
        let Target::Merge { map } = hypothesis.target() else {
            return Ok(false);
        };
        let map = MapId(map);
        let edges: Vec<LoopEdge> = merge_edges_of(hypothesis);
        let counts = hypothesis.counts(self.params.decisions.filter.ambiguous_weight);
        let Some(active_from_inactive) = self.estimate_of(hypothesis) else {
            return Ok(false);
        };
        if self.is_refused(map, &active_from_inactive) {
            let event = self.filter.reject(
                id,
                RejectReason::Caller {
                    note: "an undone or rejected merge of this epoch".into(),
                },
            );
            self.log_filter_events(event.into_iter().collect());
            return Ok(false);
        }
        let request = MergeRequest {
            map,
            active_from_inactive: Some(active_from_inactive),
            loops: edges,
            reason: MergeReason::Forced {
                note: format!("conditional merge of hypothesis {}", id.0),
            },
        };
        let preview = match self.atlas.preview_merge(&request, Some(&self.verifier)) {
            Ok(preview) => preview,
            // A merge the atlas refuses (e.g. vanished vertices) is no merge at all.
            Err(error) => {
                let event = self.filter.reject(
                    id,
                    RejectReason::Caller {
                        note: format!("conditional merge refused: {error}"),
                    },
                );
                self.log_filter_events(event.into_iter().collect());
                return Ok(false);
            }
        };
        // G''s merge edges: the observations' and the overlap loops.
        let edges: Vec<LoopEdge> = preview
            .graph
            .edges()
            .filter(|(_, e)| {
                let active = self.atlas.active();
                e.kind == EdgeKind::Merge
                    && active.contains_vertex(e.to)
                    && !active.contains_vertex(e.from)
            })
            .map(|(_, e)| LoopEdge {
                active: e.to,
                inactive: e.from,
                inactive_from_active: e.measurement,
                information: e.information,
            })
            .collect();
        let transform = mapmerge_atlas::pose_array(&preview.active_from_inactive);
        self.merge_log.push(MergeRecord::new(
            self.atlas.current_epoch().0,
            (self.scans, self.travel_m()),
            Some((id, &counts)),
            map,
            None,
            transform,
            edges
                .iter()
                .map(|e| (e.inactive, e.active, e.inactive_from_active))
                .collect(),
        ));
        self.log_decision(Decision::ConditionalMerge {
            hypothesis: id.0,
            map,
            edges: edges.len(),
            active_from_inactive: transform,
        });
        self.before_last_change = Some(self.atlas.active().clone());
        self.conditional = Some(Conditional {
            hypothesis: id,
            map,
            record: self.merge_log.len() - 1,
            edges,
            graph: preview.graph,
        });
        self.restart_detector();
        Ok(true)
    }

    /// Makes G' anew from the atlas's graphs and the conditional merge's edges ("every time
    /// G is modified, we copy it into G' and add the edges from h_c", Sec. 5.2); drops the
    /// conditional merge when that fails.
    fn refresh_conditional_graph(&mut self) {
        let Some(conditional) = &self.conditional else {
            return;
        };
        let request = MergeRequest {
            map: conditional.map,
            active_from_inactive: None,
            loops: conditional.edges.clone(),
            reason: MergeReason::Forced { note: "G'".into() },
        };
        match self.atlas.preview_merge(&request, None) {
            Ok(preview) => {
                if let Some(c) = self.conditional.as_mut() {
                    c.graph = preview.graph;
                }
            }
            Err(error) => {
                let id = conditional.hypothesis;
                let event = self.filter.reject(
                    id,
                    RejectReason::Caller {
                        note: format!("G' failed: {error}"),
                    },
                );
                self.log_filter_events(event.into_iter().collect());
                self.drop_conditional(format!("G' failed: {error}"));
            }
        }
    }

    /// Rejects the conditional merge's hypothesis in the filter and drops G' with `note`;
    /// with `refuse`, its estimate is refused for the rest of the epoch.
    fn reject_conditional(&mut self, reason: RejectReason, note: String, refuse: bool) {
        let Some(conditional) = &self.conditional else {
            return;
        };
        let (id, map) = (conditional.hypothesis, conditional.map);
        if refuse {
            if let Some(r) = self.merge_log.get(conditional.record) {
                let [x, y, theta] = r.active_from_inactive;
                self.refused.push((map, Se2::new(x, y, theta)));
            }
        }
        let event = self.filter.reject(id, reason);
        self.log_filter_events(event.into_iter().collect());
        self.drop_conditional(note);
    }

    /// Drops the conditional merge (G' discarded) with its reason.
    fn drop_conditional(&mut self, reason: String) {
        let Some(conditional) = self.conditional.take() else {
            return;
        };
        let (scan, travel_m) = (self.scans, self.travel_m());
        if let Some(record) = self.merge_log.get_mut(conditional.record) {
            record.state = MergeState::Rejected;
            record.ended_at_scan = Some(scan);
            record.ended_travel_m = Some(travel_m);
            record.reason = Some(reason.clone());
        }
        self.log_decision(Decision::ConditionalDropped {
            hypothesis: conditional.hypothesis.0,
            map: conditional.map,
            reason,
        });
        self.restart_detector();
    }

    /// A fully accepted hypothesis: a merge goes into the atlas (undoable), a recovery adds
    /// its loop edges. Returns whether a merge was made.
    fn accept_fully(&mut self, hypothesis: Hypothesis<ObservedEdge>) -> Result<bool, EngineError> {
        let id = hypothesis.id();
        match hypothesis.target() {
            Target::Recovery => {
                let records: Vec<LoopRecord> = hypothesis
                    .edges()
                    .filter_map(|e| match e {
                        ObservedEdge::Recovery(r) => Some(*r),
                        ObservedEdge::Merge(_) => None,
                    })
                    .collect();
                let added = self.atlas.add_recovered_loops(&records)?;
                self.log_decision(Decision::Recovery {
                    hypothesis: id.0,
                    edges: added,
                });
                Ok(false)
            }
            Target::Merge { map } => {
                let map = MapId(map);
                let Some(active_from_inactive) = self.estimate_of(&hypothesis) else {
                    return Ok(false);
                };
                if self.atlas.inactive(map).is_none() || self.is_refused(map, &active_from_inactive)
                {
                    if self
                        .conditional
                        .as_ref()
                        .is_some_and(|c| c.hypothesis == id)
                    {
                        self.drop_conditional("refused at full acceptance".into());
                    }
                    return Ok(false);
                }
                // Its edges: those G' had (observations and overlap loops) and any newer.
                let conditional = self.conditional.take().filter(|c| c.hypothesis == id);
                let mut edges = conditional
                    .as_ref()
                    .map_or_else(Vec::new, |c| c.edges.clone());
                for edge in merge_edges_of(&hypothesis) {
                    if !edges
                        .iter()
                        .any(|e| e.active == edge.active && e.inactive == edge.inactive)
                    {
                        edges.push(edge);
                    }
                }
                let counts = hypothesis.counts(self.params.decisions.filter.ambiguous_weight);
                let score = hypothesis.observations().len() as f64;
                let request = MergeRequest {
                    map,
                    active_from_inactive: Some(active_from_inactive),
                    loops: edges,
                    reason: MergeReason::PlaceRecognition {
                        loops: counts.observations,
                        score,
                        confidence: counts.weighted_views,
                    },
                };
                let (event, merge_edges) = self.commit_merge(request)?;
                let record = MergeRecord::new(
                    self.atlas.current_epoch().0,
                    (self.scans, self.travel_m()),
                    Some((id, &counts)),
                    map,
                    Some(event.merge),
                    event.active_from_inactive,
                    merge_edges,
                );
                match conditional.and_then(|c| self.merge_log.get_mut(c.record)) {
                    Some(existing) => {
                        existing.state = MergeState::Full;
                        existing.full_at_scan = record.full_at_scan;
                        existing.full_travel_m = record.full_travel_m;
                        existing.merge = record.merge;
                        existing.observations = record.observations;
                        existing.views = record.views;
                        existing.active_from_inactive = record.active_from_inactive;
                        existing.edges = record.edges;
                    }
                    None => self.merge_log.push(record),
                }
                self.log_decision(Decision::FullMerge {
                    hypothesis: id.0,
                    merge: event.merge,
                });
                self.restart_detector();
                Ok(true)
            }
        }
    }

    /// True while a full merge of this epoch can be undone and the newest is within its
    /// probation (`decisions.probation_m` of travel since it was made).
    fn on_probation(&self) -> bool {
        if !self.atlas.is_undoable() {
            return false;
        }
        let travel_m = self.travel_m();
        let epoch = self.atlas.current_epoch().0;
        self.merge_log
            .iter()
            .filter(|r| r.epoch == epoch && r.state == MergeState::Full)
            .filter_map(|r| r.full_travel_m)
            .any(|made_m| travel_m - made_m <= self.params.decisions.probation_m)
    }

    /// Keyframes of the current epoch so far.
    fn keyframes_in_epoch(&self) -> usize {
        self.tracker.info().keyframes
    }

    /// The live merge hypothesis with the most weighted observations (the newest observed
    /// among equals), with its map and estimate (`decisions.track_every_keyframes`).
    fn tracked_hypothesis(&self) -> Option<(MapId, Se2)> {
        let weight = self.params.decisions.filter.ambiguous_weight;
        let best = self
            .filter
            .hypotheses()
            .filter(|h| h.state() == HypothesisState::Tentative)
            .filter(|h| matches!(h.target(), Target::Merge { .. }))
            .max_by(|a, b| {
                let (ca, cb) = (a.counts(weight), b.counts(weight));
                ca.weighted_observations
                    .total_cmp(&cb.weighted_observations)
                    .then(
                        a.last_observation_travel_m()
                            .total_cmp(&b.last_observation_travel_m()),
                    )
            })?;
        let Target::Merge { map } = best.target() else {
            return None;
        };
        Some((MapId(map), self.estimate_of(best)?))
    }

    /// `active_from_inactive` of a merge hypothesis from its EKF state: the robot's pose in
    /// the active graph composed with `robot_from_target`.
    fn estimate_of(&self, hypothesis: &Hypothesis<ObservedEdge>) -> Option<Se2> {
        let robot = self.atlas.robot_node()?;
        let active_from_robot = self.atlas.active().vertex(robot)?.pose;
        let estimate = active_from_robot.compose(hypothesis.robot_from_target());
        estimate.is_finite().then_some(estimate)
    }

    /// True when a merge of `map` at `active_from_inactive` was undone or rejected in this
    /// epoch.
    fn is_refused(&self, map: MapId, active_from_inactive: &Se2) -> bool {
        let (m, rad) = self.params.refused_within;
        self.refused.iter().any(|(refused_map, t)| {
            *refused_map == map
                && (t.translation() - active_from_inactive.translation()).norm() <= m
                && wrap_angle_rad(t.theta_rad - active_from_inactive.theta_rad).abs() <= rad
        })
    }

    /// The merged map as the detectors see it: the current-epoch and other-epoch keyframes
    /// of [`Engine::map_graph`] at their poses, with their points.
    pub fn merged_map_scans(&self) -> (Vec<DetectorScan>, Vec<DetectorScan>) {
        merged_map_scans(&self.atlas, self.map_graph(), &self.detector_revisits)
    }

    /// Starts the detector over on the map it now judges (G' or the merged graph), without
    /// the merged epochs' revisits of places they mapped.
    fn restart_detector(&mut self) {
        let (current, mut other) = merged_map_scans(&self.atlas, self.map_graph(), &HashSet::new());
        let mut poses: Vec<(NodeId, Se2)> =
            other.iter().map(|s| (s.node, s.map_from_robot)).collect();
        poses.sort_by_key(|(node, _)| *node);
        let spacing_m = self.atlas.params().loops.revisit_spacing_m;
        self.detector_revisits = revisits_among(&poses, spacing_m);
        other.retain(|s| !self.detector_revisits.contains(&s.node));
        if let Some(detector) = self.detector.as_mut() {
            if !other.is_empty() {
                detector.on_merge(&MergedMap {
                    current: &current,
                    other: &other,
                });
            }
        }
    }

    /// Steps 6 and 7. A conditional merge that would be older than
    /// `decisions.conditional_max_m` of travel at the next keyframe is rejected. While a merge
    /// is conditional, the detector judges G': above `decisions.conditional_reject_threshold`
    /// the conditional merge is rejected. Otherwise, while full merges can be undone, the
    /// detector judges the active graph: above `unmerge_threshold` every merge is undone.
    /// Rejected and undone merges are refused for the rest of the epoch.
    fn verify_and_undo(&mut self) -> Result<(), EngineError> {
        if self.conditional.is_none() && !self.on_probation() {
            return Ok(());
        }
        if let (Some(conditional), Some(max_m)) =
            (&self.conditional, self.params.decisions.conditional_max_m)
        {
            let since_m = self
                .merge_log
                .get(conditional.record)
                .and_then(|r| r.conditional_travel_m)
                .map_or(0.0, |started_m| self.travel_m() - started_m);
            // Rejected now if the next keyframe, as far on as the epoch's longest step so
            // far, would pass the bound.
            let ahead_m = self.atlas.longest_recent_keyframe_step_m(usize::MAX);
            if since_m + ahead_m > max_m {
                let note = format!("not made full within {max_m} m");
                self.reject_conditional(RejectReason::Caller { note: note.clone() }, note, false);
                return Ok(());
            }
        }
        let (current, other) =
            merged_map_scans(&self.atlas, self.map_graph(), &self.detector_revisits);
        let Some(detector) = self.detector.as_mut() else {
            return Ok(());
        };
        let invalidity = detector.on_vertex(&MergedMap {
            current: &current,
            other: &other,
        });
        let name = detector.name().to_owned();
        let supported = |evidence| evidence == RatioSupport::Supported;
        let readings: Vec<(&str, f64, bool)> =
            std::iter::once((detector.name(), invalidity, supported(detector.evidence())))
                .chain(
                    detector
                        .component_readings()
                        .into_iter()
                        .map(|(method, ratio, evidence)| (method, ratio, supported(evidence))),
                )
                .collect();
        // The merge being judged: the conditional one, else the newest full one.
        let epoch = self.atlas.current_epoch().0;
        let judged = match &self.conditional {
            Some(conditional) => Some(conditional.record),
            None => self
                .merge_log
                .iter()
                .rposition(|r| r.epoch == epoch && r.state == MergeState::Full),
        };
        if let Some(record) = judged.and_then(|k| self.merge_log.get_mut(k)) {
            record.note_readings(&readings);
        }
        if self.conditional.is_some() {
            if invalidity > self.params.decisions.conditional_reject_threshold {
                let note = format!("{name} invalidity {invalidity:.2}");
                self.reject_conditional(RejectReason::Detector { name, invalidity }, note, true);
            }
            return Ok(());
        }
        if invalidity > self.params.unmerge_threshold {
            self.undo_all(UnmergeReason::InvalidMerge {
                detector: name,
                invalidity,
            })?;
        }
        Ok(())
    }

    /// Undoes every merge into the active graph for `reason`: the restored maps are refused
    /// at their transforms for the rest of the epoch, and the merges' records say why.
    fn undo_all(&mut self, reason: UnmergeReason) -> Result<(), EngineError> {
        self.before_last_change = Some(self.atlas.active().clone());
        let note = reason.summary();
        let Some(undone) = self.atlas.unmerge_all(reason)? else {
            return Ok(());
        };
        self.merged_matches = (0, 0);
        self.refused.extend(
            undone
                .restored_maps
                .iter()
                .zip(&undone.undone_transforms)
                .map(|(map, t)| (*map, Se2::new(t[0], t[1], t[2]))),
        );
        let (scan, travel_m) = (self.scans, self.travel_m());
        for record in self.merge_log.iter_mut().filter(|r| {
            r.state == MergeState::Full
                && r.merge
                    .is_some_and(|m| undone.merges.iter().any(|u| u.0 == m))
        }) {
            record.state = MergeState::Undone;
            record.ended_at_scan = Some(scan);
            record.ended_travel_m = Some(travel_m);
            record.reason = Some(note.clone());
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
        let (event, edges) =
            self.commit_merge(MergeRequest::forced(map, active_from_inactive, note))?;
        self.merge_log.push(MergeRecord::new(
            self.atlas.current_epoch().0,
            (self.scans, self.travel_m()),
            None,
            map,
            Some(event.merge),
            event.active_from_inactive,
            edges,
        ));
        self.restart_detector();
        self.collect_events();
        Ok(())
    }

    /// Merges into the atlas (with the overlap search); keeps the active graph as it was for
    /// pictures. Returns the atlas's event and the merge edges `(from, to, measurement)`
    /// the merge added (an undo removes them from the graph; the record keeps them).
    #[allow(clippy::type_complexity)]
    fn commit_merge(
        &mut self,
        request: MergeRequest,
    ) -> Result<(mapmerge_atlas::MergeEvent, Vec<(NodeId, NodeId, Se2)>), EngineError> {
        let before = self.atlas.active().clone();
        let first_edge = before.next_edge_id();
        let event = self.atlas.merge(request, Some(&self.verifier))?;
        self.before_last_change = Some(before);
        let edges = self
            .atlas
            .active()
            .edges()
            .filter(|(id, e)| id.0 >= first_edge.0 && e.kind == EdgeKind::Merge)
            .map(|(_, e)| (e.from, e.to, e.measurement))
            .collect();
        Ok((event, edges))
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
            .find_map(|e| match e.atlas() {
                Some(AtlasEvent::EpochEnded { map, .. }) => *map,
                _ => None,
            })
            .ok_or_else(|| EngineError::Import("the imported graph is empty".into()))
    }

    fn log_filter_events(&mut self, events: Vec<FilterEvent>) {
        self.collect_events();
        let travel_m = self.travel_m();
        self.events
            .extend(events.into_iter().map(|event| EngineEvent {
                scan: self.scans,
                travel_m,
                event: EventKind::Hypothesis(event),
            }));
    }

    fn log_decision(&mut self, decision: Decision) {
        self.collect_events();
        let travel_m = self.travel_m();
        self.events.push(EngineEvent {
            scan: self.scans,
            travel_m,
            event: EventKind::Decision(decision),
        });
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
                event: EventKind::Atlas(event.clone()),
            });
        }
        self.atlas_events_seen = self.atlas.events().len();
    }
}

/// A loop edge's covariance (zero where its information cannot be inverted; the
/// observation's floor is added to it).
fn covariance_of(edge: &LoopEdge) -> Matrix3<f64> {
    edge.information
        .try_inverse()
        .unwrap_or_else(Matrix3::zeros)
}

/// The merge edges a merge hypothesis's observations carry.
fn merge_edges_of(hypothesis: &Hypothesis<ObservedEdge>) -> Vec<LoopEdge> {
    hypothesis
        .edges()
        .filter_map(|e| match e {
            ObservedEdge::Merge(edge) => Some(*edge),
            ObservedEdge::Recovery(_) => None,
        })
        .collect()
}

/// The merged map as the detectors see it (see [`Engine::merged_map_scans`]): `graph`'s
/// keyframes with the atlas's points, the other epochs' without those in `left_out`.
fn merged_map_scans(
    atlas: &Atlas,
    graph: &PoseGraph2,
    left_out: &HashSet<NodeId>,
) -> (Vec<DetectorScan>, Vec<DetectorScan>) {
    let current_epoch = atlas.current_epoch().0;
    let (mut current, mut other) = (Vec::new(), Vec::new());
    for (node, vertex) in graph.vertices() {
        let Some(points) = atlas.keyframes().get(node) else {
            continue;
        };
        let scan = DetectorScan {
            node,
            epoch: vertex.meta.session.0,
            map_from_robot: vertex.pose,
            points_in_robot: Arc::clone(points),
        };
        if vertex.meta.session.0 == current_epoch {
            current.push(scan);
        } else if !left_out.contains(&node) {
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
/// merge or verify; no tracking-failure detector), each scan's `odom_from_robot` as the wheel odometry (scans without one
/// reuse the previous one), calling `progress(scans_done)` after every scan.
pub fn run_slam(
    log: &LaserLog,
    params: EngineParams,
    mut progress: impl FnMut(usize),
) -> Result<SlamRun, EngineError> {
    // One log, one graph: the tracker is never lost (a jump stays in the graph).
    let mut params = params;
    params.tracker.lost = None;
    let mut engine = Engine::new(EngineParams {
        detector: NO_DETECTOR.into(),
        ..params
    })?;
    let started = std::time::Instant::now();
    let mut odometry = Se2::identity();
    let mut keyframe_scans = Vec::new();
    for (index, record) in log.scans.iter().enumerate() {
        odometry = record.odom_from_robot.unwrap_or(odometry);
        let report = engine.add_scan(&odometry, &record.scan, None)?;
        if report.keyframe.is_some() {
            keyframe_scans.push(index);
        }
        progress(index + 1);
    }
    engine.finish()?;
    let seconds = started.elapsed().as_secs_f64();
    let graph = engine.atlas.active().clone();
    let trajectory = engine
        .anchors
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
