//! The local tracker: the front half of 2D graph SLAM, in the manner of Cartographer's local
//! trajectory builder (Hess et al. 2016). It holds no pose graph: per scan, in order,
//! 1. predict the pose from the wheel odometry increment;
//! 2. match the scan against the older active **submap** (correlative search + ICP,
//!    `mapmerge-scanmatch`) in a window around the prediction, fused with the prediction;
//! 3. anchor the scan to the current keyframe, or make it a keyframe and hand it over as a
//!    [`KeyframeInsertion`]: its local pose, its points (shared, `Arc`), an edge from the
//!    matched submap's nearest keyframe (the match, weighted by its covariance), a loose
//!    wheel-odometry edge from the previous keyframe, and the submap it finished, if any
//!    (two active submaps, the older one matched against; Sec. IV).
//!
//! Whoever owns the pose graph (`mapmerge-atlas`) places the keyframe, searches loops against
//! the finished submaps it was handed, and optimises. Poses here are `local_from_robot`:
//! odometry corrected by scan matching, never moved by an optimisation.

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Instant;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_params::{Checker, ParamError, Real, Validate, NOISE_PER_UNIT, SIGMA_M, SIGMA_RAD};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId};
use mapmerge_scan::{BeamFilter, LaserScan, Point2};
use mapmerge_scanmatch::{ScanMatchError, ScanMatchParams, ScanMatcher, SearchWindow};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use crate::lost::{LostDetector, LostParams, LostReport, OffReading, TrackingState, Verdict};
use crate::submap::Submap;
use crate::KeyframePolicy;

/// Why the tracker refused a scan.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TrackerError {
    /// The odometry pose is NaN or infinite.
    #[error("scan {scan}: non-finite odometry pose")]
    NonFiniteOdometry {
        /// Index of the scan.
        scan: usize,
    },
    /// The matcher's parameters are invalid, or a submap outgrew the matcher's grid limit.
    #[error(transparent)]
    Matcher(#[from] ScanMatchError),
    /// A parameter is out of its range (the path from `TrackerParams`).
    #[error(transparent)]
    Params(#[from] ParamError),
}

/// Parameters of the tracker, one default for every log (no per-log tuning).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackerParams {
    /// When scans become keyframes.
    pub keyframes: KeyframePolicy,
    /// The scan matcher for scan-to-submap odometry.
    pub matcher: ScanMatchParams,
    /// Search window around the odometry prediction (m, rad).
    pub odometry_window: SearchWindow,
    /// When ICP from the prediction is trusted without the correlative search.
    pub refine_first: RefineFirst,
    /// Keyframes inserted into a submap before the next one starts; a submap is finished
    /// with twice this many (default: 20) ...
    pub submap_keyframes: usize,
    /// ... or once the robot travelled this far (m) since it started (default: 10), so a
    /// submap stays small enough to be rigid on logs with sparse scans.
    pub submap_travel_m: f64,
    /// Returns beyond this range are not used for matching (m): far returns are sparse and
    /// widen the angular search (Hess et al. 2016, Eq. 7).
    pub max_match_range_m: f32,
    /// Smallest standard deviations of a scan-matched edge (m, rad), so one lucky match
    /// cannot make an edge overconfident.
    pub min_edge_sigma: (f64, f64),
    /// Wheel-odometry noise assumed when fusing a match with the prediction and weighting
    /// odometry edges: standard deviations `(a, b)` of translation (m) `a + b·d` and of
    /// heading (rad) `c + e·|Δθ| + f·d` as `(a, b, c, e, f)` (default: 2 cm + 10 %,
    /// 1° + 10 % + 2°/m). Loose on purpose: it decides only where scans say little.
    pub odometry_prior: (f64, f64, f64, f64, f64),
    /// The tracking-failure detector (Colosi et al. 2019's states; null: never lost, as a
    /// single-log SLAM run wants).
    pub lost: Option<LostParams>,
}

impl Default for TrackerParams {
    fn default() -> Self {
        Self {
            keyframes: KeyframePolicy::default(),
            matcher: odometry_matcher_params(),
            odometry_window: SearchWindow::new(0.5, 15f64.to_radians()),
            refine_first: RefineFirst::default(),
            submap_keyframes: 20,
            submap_travel_m: 10.0,
            max_match_range_m: 20.0,
            min_edge_sigma: (0.01, 0.2f64.to_radians()),
            odometry_prior: (0.02, 0.1, 1f64.to_radians(), 0.1, 2f64.to_radians()),
            lost: Some(LostParams::default()),
        }
    }
}

/// ICP from the odometry prediction is trusted, and the correlative search skipped, when
/// nearly every point found a correspondence, the scan fits the map as well as a searched
/// match would, and ICP moved the pose only a little (Hess et al. 2016 likewise refine from
/// the prediction and keep the correlative search for when it is needed).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RefineFirst {
    /// Try ICP first at all (default: true).
    pub enabled: bool,
    /// Fraction of query points with a correspondence (default: 0.8).
    pub min_inlier_fraction: f64,
    /// Correlative score at the refined pose (default: 0.6).
    pub min_score: f64,
    /// Largest correction of the prediction (m, rad) (default: 0.15 m, 3°).
    pub max_correction: (f64, f64),
}

impl Default for RefineFirst {
    fn default() -> Self {
        Self {
            enabled: true,
            min_inlier_fraction: 0.8,
            min_score: 0.6,
            max_correction: (0.15, 3f64.to_radians()),
        }
    }
}

impl Validate for TrackerParams {
    fn check(&self, check: &mut Checker) {
        let (a, b, c, e, f) = self.odometry_prior;
        check
            .nested("keyframes", &self.keyframes)
            .nested("matcher", &self.matcher)
            .nested("odometry_window", &self.odometry_window)
            .nested("refine_first", &self.refine_first)
            .size("submap_keyframes", self.submap_keyframes, 1, 100_000)
            .real("submap_travel_m", self.submap_travel_m, Real::positive())
            .real(
                "max_match_range_m",
                f64::from(self.max_match_range_m),
                Real::positive_up_to(1000.0),
            )
            .reals(
                "min_edge_sigma",
                &[
                    (self.min_edge_sigma.0, SIGMA_M),
                    (self.min_edge_sigma.1, SIGMA_RAD),
                ],
            )
            .reals(
                "odometry_prior",
                &[
                    (a, SIGMA_M),
                    (b, NOISE_PER_UNIT),
                    (c, SIGMA_RAD),
                    (e, NOISE_PER_UNIT),
                    (f, NOISE_PER_UNIT),
                ],
            )
            .nested_opt("lost", self.lost.as_ref());
    }
}

impl Validate for RefineFirst {
    fn check(&self, check: &mut Checker) {
        check
            .real(
                "min_inlier_fraction",
                self.min_inlier_fraction,
                Real::fraction(),
            )
            .real("min_score", self.min_score, Real::fraction())
            .reals(
                "max_correction",
                &[
                    (self.max_correction.0, Real::non_negative()),
                    (
                        self.max_correction.1,
                        Real::within(0.0, std::f64::consts::PI),
                    ),
                ],
            );
    }
}

impl RefineFirst {
    /// True when the ICP-only match `refined` of a scan predicted at `guess` can be kept.
    pub fn accepts(&self, refined: &mapmerge_scanmatch::Match, guess: &Se2) -> bool {
        let correction = guess.between(&refined.target_from_query);
        self.enabled
            && refined
                .icp
                .is_some_and(|icp| icp.inlier_fraction >= self.min_inlier_fraction)
            && refined.score >= self.min_score
            && correction.translation().norm() <= self.max_correction.0
            && correction.theta_rad.abs() <= self.max_correction.1
    }
}

/// The scan matcher for scan-to-map odometry: the ±0.5 m window spans 20 cells, so
/// branch-and-bound levels beyond 2^4 = 16 cells only cost time to precompute.
fn odometry_matcher_params() -> ScanMatchParams {
    let mut params = ScanMatchParams::default();
    params.correlative.branch_and_bound_depth = 4;
    params
}

/// Cells of the free space a scan's rays cross when it is read against the submap (m) …
const SEEN_THROUGH_CELL_M: f64 = 0.1;
/// … and at most about this many submap points read.
const SEEN_THROUGH_POINTS: usize = 4000;

/// Branch-and-bound depth of finished submaps: 128-cell blocks, a few roots per angle for
/// loop windows up to ±7 m at 5 cm.
pub const LOOP_BRANCH_AND_BOUND_DEPTH: usize = 7;

/// A new keyframe, handed to whoever owns the pose graph.
#[derive(Debug)]
pub struct KeyframeInsertion {
    /// Its node id (the one passed to [`LocalTracker::add_scan`]).
    pub node: NodeId,
    /// Its pose in the tracker's local frame.
    pub local_from_robot: Se2,
    /// Its wheel-odometry pose.
    pub odom_from_robot: Se2,
    /// Its points in the robot frame (range-limited, beam order), shared, never copied.
    pub points_in_robot: Arc<[Point2]>,
    /// Robot travel up to it (m, tracker estimate).
    pub travel_m: f64,
    /// Edges to earlier keyframes (kind `Odometry`): from the matched submap's nearest
    /// keyframe (the scan match), and from the previous keyframe (loose wheel odometry).
    pub edges: Vec<Edge<Se2, 3>>,
    /// The anchor of the submap it was first inserted into (the older active one).
    pub submap: NodeId,
    /// The submap this keyframe finished (no more scans go in; deep branch-and-bound levels
    /// ready for loop search). Moved out of the tracker: the graph's owner keeps it.
    pub finished_submap: Option<Submap>,
}

/// How well one scan was tracked: what a tracking-failure detector reads
/// ([`crate::LostDetector`]). All `None` when the scan was not matched (no submap yet, or no
/// acceptable match).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrackingReading {
    /// The match's score (mean likelihood of the points in the submap, `[0, 1]`).
    pub score: Option<f64>,
    /// Fraction of the points ICP paired with the submap, when ICP ran.
    pub inlier_fraction: Option<f64>,
    /// How far the match moved the odometry prediction, in standard deviations of the
    /// odometry prior (Mahalanobis distance, before the two are fused).
    pub correction_sigma: Option<f64>,
    /// Read only when the match failed or jumped: the share of the submap's points near the
    /// robot that lie where the scan saw through, at the predicted pose (the scan
    /// contradicts the map there; new ground the map does not cover contradicts nothing).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seen_through: Option<f64>,
    /// The odometry window found nothing and a wider search in the submap did
    /// ([`crate::LostParams::relocalize_window`]): the score and correction are that match's.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub relocalized: bool,
}

/// What happened to one scan.
#[derive(Debug)]
pub struct TrackedScan {
    /// The scan's pose in the tracker's local frame after matching.
    pub local_from_robot: Se2,
    /// How well it was tracked (the match's score and more).
    pub reading: TrackingReading,
    /// The tracker's state after it: while relocalizing, scans make no keyframe and change
    /// no submap.
    pub state: TrackingState,
    /// When this scan made the tracker lost: why, and the scans in doubt (this one last),
    /// which belong to a new epoch.
    pub lost: Option<LostReport>,
    /// The keyframe the scan hangs on and its pose in that keyframe's frame.
    pub anchor: (NodeId, Se2),
    /// The keyframe the scan became.
    pub keyframe: Option<KeyframeInsertion>,
}

/// Counters over a run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct TrackerInfo {
    /// Scans seen.
    pub scans: usize,
    /// Scans matched against a submap.
    pub matched: usize,
    /// Scans that fell back on odometry (no submap yet, or no acceptable match).
    pub odometry_only: usize,
    /// Matched scans for which ICP from the prediction sufficed (no correlative search).
    pub refined: usize,
    /// Keyframes.
    pub keyframes: usize,
    /// Submaps started.
    pub submaps: usize,
    /// Wall time (s) of scan-to-submap matching.
    pub matching_seconds: f64,
    /// Wall time (s) of inserting keyframes into submaps and finishing submaps.
    pub submaps_seconds: f64,
    /// Scans relocalized by the wider search, read in doubt (relocalizing), and times the
    /// tracker lost track.
    pub relocalized: usize,
    pub in_doubt: usize,
    pub lost: usize,
}

impl std::ops::Add for TrackerInfo {
    type Output = Self;

    /// The counters of two runs (epochs) together.
    fn add(self, other: Self) -> Self {
        Self {
            scans: self.scans + other.scans,
            matched: self.matched + other.matched,
            odometry_only: self.odometry_only + other.odometry_only,
            refined: self.refined + other.refined,
            keyframes: self.keyframes + other.keyframes,
            submaps: self.submaps + other.submaps,
            matching_seconds: self.matching_seconds + other.matching_seconds,
            submaps_seconds: self.submaps_seconds + other.submaps_seconds,
            relocalized: self.relocalized + other.relocalized,
            in_doubt: self.in_doubt + other.in_doubt,
            lost: self.lost + other.lost,
        }
    }
}

/// The current keyframe: its node, local pose, wheel-odometry pose, scans since it.
#[derive(Clone, Copy, Debug)]
struct CurrentKeyframe {
    node: NodeId,
    local_from_robot: Se2,
    odom_from_robot: Se2,
    scans_since: usize,
}

/// The tracker's state: the active submaps and the current keyframe (no graph).
pub struct LocalTracker {
    params: TrackerParams,
    matcher: ScanMatcher,
    /// The active submaps, oldest first (at most two between scans).
    active: VecDeque<Submap>,
    /// `(odom_from_robot, local_from_robot)` of the previous scan.
    previous: Option<(Se2, Se2)>,
    current: Option<CurrentKeyframe>,
    travel_m: f64,
    /// Travel (m) when the newest submap started.
    newest_submap_started_m: f64,
    info: TrackerInfo,
    detector: Option<LostDetector>,
}

impl LocalTracker {
    /// A tracker with no scans yet.
    pub fn new(params: TrackerParams) -> Result<Self, TrackerError> {
        params.validate()?;
        Ok(Self {
            detector: params.lost.clone().map(LostDetector::new),
            matcher: ScanMatcher::new(params.matcher)?,
            params,
            active: VecDeque::new(),
            previous: None,
            current: None,
            travel_m: 0.0,
            newest_submap_started_m: 0.0,
            info: TrackerInfo::default(),
        })
    }

    /// The parameters.
    pub fn params(&self) -> &TrackerParams {
        &self.params
    }

    /// The scan matcher (its parameters serve loop search against the finished submaps).
    pub fn matcher(&self) -> &ScanMatcher {
        &self.matcher
    }

    /// Counters.
    pub fn info(&self) -> TrackerInfo {
        self.info
    }

    /// Robot travel so far (m).
    pub fn travel_m(&self) -> f64 {
        self.travel_m
    }

    /// Hands over the active submaps (the epoch ended): the graph's owner may keep them as
    /// loop-closure targets once finished. The tracker has none afterwards.
    pub fn take_active_submaps(&mut self) -> Result<Vec<Submap>, TrackerError> {
        let mut taken = Vec::with_capacity(self.active.len());
        for mut submap in self.active.drain(..) {
            submap.finish(LOOP_BRANCH_AND_BOUND_DEPTH)?;
            taken.push(submap);
        }
        Ok(taken)
    }

    /// Processes the next scan, taken at wheel-odometry pose `odom_from_robot` (stamped
    /// `stamp_secs`, if known). Should it become a keyframe, its node is `next_node` (the
    /// graph owner's next free id).
    pub fn add_scan(
        &mut self,
        odom_from_robot: &Se2,
        scan: &LaserScan,
        stamp_secs: Option<f64>,
        next_node: NodeId,
    ) -> Result<TrackedScan, TrackerError> {
        let index = self.info.scans;
        if !odom_from_robot.is_finite() {
            return Err(TrackerError::NonFiniteOdometry { scan: index });
        }
        self.info.scans += 1;
        // 1. Predict from the odometry increment.
        let predicted = match self.previous {
            Some((odom_previous, local_previous)) => {
                local_previous.compose(&odom_previous.between(odom_from_robot))
            }
            None => Se2::identity(),
        };
        // 2. Match against the older active submap.
        let filter = BeamFilter {
            max_range_m: self.params.max_match_range_m,
            ..BeamFilter::default()
        };
        let points = scan.points_in_robot(&filter);
        let started = Instant::now();
        let mut matched = self.match_to_submap(&points, &predicted);
        // Colosi et al.'s relocalization in the tracker's own map: where the odometry window
        // found nothing, a wider one around the prediction (a wheel slip, not a kidnap).
        if matched.is_none() {
            matched = self.relocalize(&points, &predicted);
        }
        self.info.matching_seconds += started.elapsed().as_secs_f64();
        let (mut local_from_robot, mut reading) = match &matched {
            Some((_, local_from_robot, reading)) => {
                self.info.matched += 1;
                (*local_from_robot, *reading)
            }
            None => {
                self.info.odometry_only += 1;
                (predicted, TrackingReading::default())
            }
        };
        if let Some(lost) = &self.params.lost {
            if !reading.relocalized
                && (reading.score.is_none()
                    || reading
                        .correction_sigma
                        .is_some_and(|s| s > lost.jump_sigma))
            {
                reading.seen_through = self.seen_through(scan, &points, &predicted);
            }
        }
        // The detector reads the scan (Colosi et al.'s states): an off match in doubt is not
        // followed, and nothing in doubt changes the map.
        let (state, verdict) = match self.detector.as_mut() {
            Some(detector) => {
                let verdict = detector.observe(&reading, stamp_secs);
                (detector.state(), verdict)
            }
            None => (TrackingState::Tracking, Verdict::default()),
        };
        let lost = verdict.lost;
        let in_doubt = state != TrackingState::Tracking;
        if in_doubt {
            self.info.in_doubt += 1;
            self.info.lost += usize::from(lost.is_some());
            if matches!(verdict.off, Some(OffReading::NoMatch | OffReading::Jump)) {
                local_from_robot = predicted;
            }
        }
        if let Some((_, previous_local)) = self.previous {
            self.travel_m += previous_local
                .between(&local_from_robot)
                .translation()
                .norm();
        }
        self.previous = Some((*odom_from_robot, local_from_robot));
        // 3. Keyframe or anchor.
        if let Some(current) = self.current.as_mut() {
            let keyframe_from_robot = current.local_from_robot.between(&local_from_robot);
            if in_doubt
                || !self
                    .params
                    .keyframes
                    .is_keyframe(&keyframe_from_robot, current.scans_since + 1)
            {
                current.scans_since += 1;
                return Ok(TrackedScan {
                    local_from_robot,
                    reading,
                    state,
                    lost,
                    anchor: (current.node, keyframe_from_robot),
                    keyframe: None,
                });
            }
        }
        let submap_match = matched.map(|(m, _, _)| (m.target_from_query, m.covariance));
        let started = Instant::now();
        let insertion = self.add_keyframe(
            next_node,
            local_from_robot,
            *odom_from_robot,
            points,
            submap_match,
        )?;
        self.info.submaps_seconds += started.elapsed().as_secs_f64();
        Ok(TrackedScan {
            local_from_robot,
            reading,
            state,
            lost,
            anchor: (next_node, Se2::identity()),
            keyframe: Some(insertion),
        })
    }

    /// Matches `points` (robot frame) predicted at `predicted` (local frame) against the
    /// older active submap: ICP from the prediction when it clearly lands in the right basin,
    /// else the correlative search over the odometry window; then directions the match does
    /// not constrain (a corridor's axis) keep the prediction. The match in the submap frame,
    /// the matched pose in the local frame and the reading.
    fn match_to_submap(
        &mut self,
        points: &[Point2],
        predicted: &Se2,
    ) -> Option<(mapmerge_scanmatch::Match, Se2, TrackingReading)> {
        let prior_covariance = self.prior_covariance(predicted);
        let submap = self.active.front_mut()?;
        if submap.is_empty() {
            return None;
        }
        let guess = submap.local_from_submap.between(predicted);
        let refined = self
            .matcher
            .refine(submap.target()?, points, &guess)
            .filter(|m| self.params.refine_first.accepts(m, &guess));
        self.info.refined += usize::from(refined.is_some());
        let mut found = match refined {
            Some(refined) => refined,
            // Only the correlative search reads the submap's coarse levels: they are brought
            // up to date here, not for every scan that ICP matched.
            None => {
                submap.prepare();
                self.matcher.match_scan(
                    submap.target()?,
                    points,
                    &guess,
                    &self.params.odometry_window,
                )?
            }
        };
        let reading = TrackingReading::of(&found, &guess, &prior_covariance, false);
        found.target_from_query = fuse_with_prior(
            &found.target_from_query,
            &found.covariance,
            &guess,
            &prior_covariance,
        );
        let local_from_robot = submap.local_from_submap.compose(&found.target_from_query);
        Some((found, local_from_robot, reading))
    }

    /// Covariance of the odometry increment from the previous scan to `predicted`.
    fn prior_covariance(&self, predicted: &Se2) -> Matrix3<f64> {
        let previous_local = self.previous.map_or(*predicted, |(_, local)| local);
        odometry_covariance(
            &previous_local.between(predicted),
            &self.params.odometry_prior,
        )
    }

    /// A match of `points` within the detector's `relocalize_window` around `predicted`
    /// scoring at least its `relocalize_min_score`, taken as it is (the prediction is what
    /// failed); `None` without a detector, a submap or such a match.
    fn relocalize(
        &mut self,
        points: &[Point2],
        predicted: &Se2,
    ) -> Option<(mapmerge_scanmatch::Match, Se2, TrackingReading)> {
        let lost = self.params.lost.as_ref()?;
        let (linear_m, angular_rad) = lost.relocalize_window?;
        let min_score = lost.relocalize_min_score;
        let prior_covariance = self.prior_covariance(predicted);
        let submap = self.active.front_mut()?;
        if submap.is_empty() {
            return None;
        }
        submap.prepare();
        let guess = submap.local_from_submap.between(predicted);
        let found = self.matcher.match_scan_above(
            submap.target()?,
            points,
            &guess,
            &SearchWindow::new(linear_m, angular_rad),
            min_score,
        )?;
        self.info.relocalized += 1;
        let reading = TrackingReading::of(&found, &guess, &prior_covariance, true);
        let local_from_robot = submap.local_from_submap.compose(&found.target_from_query);
        Some((found, local_from_robot, reading))
    }

    /// The share of the older active submap's points within reach of the scan (robot at
    /// `local_from_robot`) that lie in cells its rays crossed; `None` without a submap or
    /// with no submap point within reach.
    fn seen_through(
        &self,
        scan: &LaserScan,
        points_in_robot: &[Point2],
        local_from_robot: &Se2,
    ) -> Option<f64> {
        let submap = self.active.front()?;
        let sensor = scan.robot_from_sensor.translation();
        let free = mapmerge_grid::FreeSpace::from_rays(
            SEEN_THROUGH_CELL_M,
            points_in_robot.iter().map(|p| (sensor, *p)),
        )
        .ok()?;
        let robot_from_submap = local_from_robot.between(&submap.local_from_submap);
        let map_points = submap.target()?.correlative().points_in_target();
        let stride = (map_points.len() / SEEN_THROUGH_POINTS).max(1);
        let reach_m = f64::from(self.params.max_match_range_m);
        let (mut near, mut crossed) = (0usize, 0usize);
        for p in map_points.iter().step_by(stride) {
            let q = robot_from_submap.transform_point(p);
            if q.norm() > reach_m {
                continue;
            }
            near += 1;
            crossed += usize::from(free.is_free_around(&q));
        }
        (near > 0).then(|| crossed as f64 / near as f64)
    }

    /// Makes keyframe `node` with its edges and inserts it into the active submaps.
    fn add_keyframe(
        &mut self,
        node: NodeId,
        local_from_robot: Se2,
        odom_from_robot: Se2,
        points_in_robot: Vec<Point2>,
        submap_match: Option<(Se2, Matrix3<f64>)>,
    ) -> Result<KeyframeInsertion, TrackerError> {
        self.info.keyframes += 1;
        let mut edges = Vec::with_capacity(2);
        // The scan match: an edge from the matched (older active) submap's nearest keyframe.
        if let Some((submap_from_robot, covariance)) = submap_match {
            if let Some((member, member_from_robot)) = self
                .active
                .front()
                .and_then(|submap| submap.relative_to_nearest(&submap_from_robot))
            {
                if member != node {
                    edges.push(Edge {
                        from: member,
                        to: node,
                        measurement: member_from_robot,
                        information: edge_information(&covariance, self.params.min_edge_sigma),
                        kind: EdgeKind::Odometry,
                    });
                }
            }
        }
        // Wheel odometry from the previous keyframe, loosely weighted.
        if let Some(previous) = self.current {
            let measurement = previous.odom_from_robot.between(&odom_from_robot);
            let information = edge_information(
                &odometry_covariance(&measurement, &self.params.odometry_prior),
                self.params.min_edge_sigma,
            );
            edges.push(Edge {
                from: previous.node,
                to: node,
                measurement,
                information,
                kind: EdgeKind::Odometry,
            });
        }
        self.current = Some(CurrentKeyframe {
            node,
            local_from_robot,
            odom_from_robot,
            scans_since: 0,
        });
        // Submaps: insert into the active ones; start a new one when the newest is half
        // full; finish the oldest when it is full.
        let start_new = match self.active.back() {
            None => true,
            Some(newest) => {
                newest.keyframes.len() >= self.params.submap_keyframes.max(1)
                    || self.travel_m - self.newest_submap_started_m >= self.params.submap_travel_m
            }
        };
        if start_new {
            self.active
                .push_back(Submap::new(&self.matcher, node, local_from_robot)?);
            self.newest_submap_started_m = self.travel_m;
            self.info.submaps += 1;
        }
        let points_in_robot: Arc<[Point2]> = Arc::from(points_in_robot);
        for submap in &mut self.active {
            submap.insert(node, &local_from_robot, &points_in_robot)?;
        }
        let first_submap = self.active.front().map_or(node, |s| s.anchor);
        let finished_submap = if self.active.len() > 2 {
            match self.active.pop_front() {
                Some(mut finished) => {
                    finished.finish(LOOP_BRANCH_AND_BOUND_DEPTH)?;
                    Some(finished)
                }
                None => None,
            }
        } else {
            None
        };
        Ok(KeyframeInsertion {
            node,
            local_from_robot,
            odom_from_robot,
            points_in_robot,
            travel_m: self.travel_m,
            edges,
            submap: first_submap,
            finished_submap,
        })
    }
}

impl TrackingReading {
    /// The reading of match `found` of a scan predicted at `guess` (both in the submap
    /// frame), the prediction's covariance `prior_covariance`: the correction is the
    /// Mahalanobis distance `√(δᵀ Σ⁻¹ δ)` of the match from the prediction.
    fn of(
        found: &mapmerge_scanmatch::Match,
        guess: &Se2,
        prior_covariance: &Matrix3<f64>,
        relocalized: bool,
    ) -> Self {
        let offset = guess.local(&found.target_from_query);
        Self {
            score: Some(found.score),
            inlier_fraction: found.icp.map(|icp| icp.inlier_fraction),
            correction_sigma: prior_covariance.try_inverse().map(|information| {
                (offset.transpose() * information * offset)[0]
                    .max(0.0)
                    .sqrt()
            }),
            seen_through: None,
            relocalized,
        }
    }
}

/// Information of an edge: the inverse of `covariance` with its standard deviations floored
/// at `min_sigma`.
pub fn edge_information(covariance: &Matrix3<f64>, min_sigma: (f64, f64)) -> Matrix3<f64> {
    let floor = Matrix3::from_diagonal(&Vector3::new(
        min_sigma.0 * min_sigma.0,
        min_sigma.0 * min_sigma.0,
        min_sigma.1 * min_sigma.1,
    ));
    let covariance = if covariance.iter().all(|v| v.is_finite()) {
        *covariance
    } else {
        floor
    };
    (covariance + floor)
        .try_inverse()
        .filter(|i| i.iter().all(|v| v.is_finite()))
        .unwrap_or_else(|| floor.try_inverse().unwrap_or_else(Matrix3::identity))
}

/// Covariance of a wheel-odometry `increment` under the `(a, b, c, e, f)` model of
/// [`TrackerParams::odometry_prior`].
pub fn odometry_covariance(increment: &Se2, model: &(f64, f64, f64, f64, f64)) -> Matrix3<f64> {
    let (a, b, c, e, f) = *model;
    let d = increment.translation().norm();
    let translation = a + b * d;
    let heading = c + e * increment.theta_rad.abs() + f * d;
    Matrix3::from_diagonal(&Vector3::new(
        translation * translation,
        translation * translation,
        heading * heading,
    ))
}

/// Fuses a scan match (`matched`, covariance in its right tangent) with the odometry
/// prediction (`prior`, covariance in the same tangent, which is close enough for the small
/// differences involved): one Gauss–Newton step of `‖δ‖²_Ωm + ‖Log(prior⁻¹·matched) + δ‖²_Ωp`,
/// so the match decides where it is confident and the prediction where it is not (a
/// corridor's axis, Olson 2009's motivation for the prior in Sec. III).
fn fuse_with_prior(
    matched: &Se2,
    matched_covariance: &Matrix3<f64>,
    prior: &Se2,
    prior_covariance: &Matrix3<f64>,
) -> Se2 {
    let (Some(matched_information), Some(prior_information)) = (
        matched_covariance.try_inverse(),
        prior_covariance.try_inverse(),
    ) else {
        return *matched;
    };
    let Some(inverse) = (matched_information + prior_information).try_inverse() else {
        return *matched;
    };
    let offset = prior.local(matched);
    let delta = -(inverse * (prior_information * offset));
    let fused = matched.retract(&delta);
    if fused.is_finite() {
        fused
    } else {
        *matched
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn diagonal(x: f64, y: f64, theta: f64) -> Matrix3<f64> {
        Matrix3::from_diagonal(&Vector3::new(x * x, y * y, theta * theta))
    }

    #[test]
    fn fusion_keeps_the_match_where_it_is_sure_and_the_prior_where_it_is_not() {
        let matched = Se2::new(1.0, 0.5, 0.1);
        let prior = Se2::new(1.3, 0.4, 0.12);
        // A corridor along the match's x axis: x is unconstrained, y and θ are sharp.
        let corridor = diagonal(10.0, 0.005, 0.001);
        let odometry = diagonal(0.1, 0.1, 0.05);
        let fused = fuse_with_prior(&matched, &corridor, &prior, &odometry);
        let in_match = matched.between(&fused);
        let prior_in_match = matched.between(&prior);
        assert!(
            (in_match.x_m - prior_in_match.x_m).abs() < 0.01,
            "{in_match:?}"
        );
        assert!(in_match.y_m.abs() < 0.01 && in_match.theta_rad.abs() < 0.002);
        // A sure match everywhere stays put; a singular covariance returns the match.
        let sure = fuse_with_prior(&matched, &diagonal(1e-4, 1e-4, 1e-5), &prior, &odometry);
        assert!(matched.between(&sure).translation().norm() < 1e-3);
        let singular = fuse_with_prior(&matched, &Matrix3::zeros(), &prior, &odometry);
        assert_eq!(singular, matched);
    }

    #[test]
    fn odometry_noise_grows_with_motion() {
        let model = TrackerParams::default().odometry_prior;
        let still = odometry_covariance(&Se2::identity(), &model);
        let moved = odometry_covariance(&Se2::new(2.0, 0.0, 0.5), &model);
        for i in 0..3 {
            assert!(moved[(i, i)] > still[(i, i)]);
        }
        assert!((still[(0, 0)] - 0.02f64.powi(2)).abs() < 1e-12);
    }

    #[test]
    fn edge_information_is_floored_and_finite() {
        let information = edge_information(&Matrix3::zeros(), (0.01, 0.01));
        assert!((information[(0, 0)] - 1e4).abs() < 1e-6);
        let nan = Matrix3::from_element(f64::NAN);
        let information = edge_information(&nan, (0.1, 0.1));
        assert!(information.iter().all(|v| v.is_finite()));
    }
}
