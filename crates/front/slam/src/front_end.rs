//! The 2D graph-SLAM front-end. Per scan, in order:
//! 1. predict the pose from the wheel odometry increment;
//! 2. match the scan against the older active submap (correlative search + ICP,
//!    `mapmerge-scanmatch`) in a window around the prediction;
//! 3. anchor the scan to the current keyframe, or make it a keyframe: a node with an edge to
//!    the matched submap's anchor (the match, weighted by its covariance) and a loose wheel
//!    odometry edge from the previous keyframe; insert it into the active submaps (Hess et
//!    al. 2016, Sec. IV: two active submaps, the older one matched against);
//! 4. search for loops from the new keyframe: finished submaps near the estimate, in a window
//!    that grows with the distance since the last loop, then place recognition; accepted
//!    loops become edges and the graph is optimised with a robust kernel (DCS).
//!
//! Poses: the front-end tracks `local_from_robot` (odometry corrected by scan matching);
//! graph nodes live in the map frame, `map_from_local` is re-derived after each
//! optimisation from the newest keyframe.

use std::collections::{BTreeMap, HashMap};
use std::time::Instant;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_place::{Keyframe, KeyframeId, PlaceIndex, ScanContext};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph2, Vertex};
use mapmerge_scan::{BeamFilter, LaserScan, Point2};
use mapmerge_scanmatch::{ScanMatchError, ScanMatchParams, ScanMatcher, SearchWindow};
use mapmerge_solve::{chi2_quantile_99, optimize, OptimizerParams, RobustKernel};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use crate::loop_closing::LoopClosureParams;
use crate::submap::Submap;
use crate::{KeyframePolicy, ScanAnchors};

mod loop_search;

/// Why the front-end refused a scan.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FrontEndError {
    /// The odometry pose is NaN or infinite.
    #[error("scan {scan}: non-finite odometry pose")]
    NonFiniteOdometry {
        /// Index of the scan.
        scan: usize,
    },
    /// The matcher's parameters are invalid, or a submap outgrew the matcher's grid limit.
    #[error(transparent)]
    Matcher(#[from] ScanMatchError),
}

/// Parameters of the front-end, one default for every log (no per-log tuning).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FrontEndParams {
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
    /// Loop closing.
    pub loops: LoopClosureParams,
}

impl Default for FrontEndParams {
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
            loops: LoopClosureParams::default(),
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

impl RefineFirst {
    /// True when the ICP-only match `refined` of a scan predicted at `guess` can be kept.
    fn accepts(&self, refined: &mapmerge_scanmatch::Match, guess: &Se2) -> bool {
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

/// Branch-and-bound depth of finished submaps: 128-cell blocks, a few roots per angle for
/// loop windows up to ±7 m at 5 cm.
const LOOP_BRANCH_AND_BOUND_DEPTH: usize = 7;

/// What happened to one scan.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ScanStep {
    /// The scan's pose in the front-end's local frame after matching.
    pub local_from_robot: Se2,
    /// Match score, when the scan was matched.
    pub score: Option<f64>,
    /// The node created when the scan became a keyframe.
    pub keyframe: Option<NodeId>,
    /// Loop edges added for this scan.
    pub loops: usize,
}

/// Counters over a run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct FrontEndInfo {
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
    /// Loop searches against nearby submaps, and loops they found.
    pub local_searches: usize,
    /// See `local_searches`.
    pub local_loops: usize,
    /// Place-recognition queries, and loops they found.
    pub place_queries: usize,
    /// See `place_queries`.
    pub place_loops: usize,
    /// Place-recognition matches refused because they would move the estimate further than
    /// its drift can explain.
    pub place_gated: usize,
    /// Graph optimisations run.
    pub optimizations: usize,
    /// Wall time (s) of scan-to-submap matching, submap insertion, loop search, place
    /// recognition and optimisation.
    pub seconds: StageSeconds,
}

/// Where the front-end's time went (s).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct StageSeconds {
    /// Scan-to-submap matching.
    pub matching: f64,
    /// Inserting keyframes into submaps and finishing submaps.
    pub submaps: f64,
    /// Searching nearby submaps for loops.
    pub local_loops: f64,
    /// Place recognition (descriptors, retrieval, verification).
    pub place: f64,
    /// Graph optimisation.
    pub optimization: f64,
}

/// How a loop edge was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LoopSource {
    /// Search of a nearby finished submap around the current estimate.
    Local,
    /// Place recognition (descriptor retrieval + verification), no pose guess.
    Place,
}

/// An accepted loop edge: from the matched submap's keyframe nearest to the match, to a
/// keyframe.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LoopRecord {
    /// The submap's keyframe nearest to the match.
    pub from: NodeId,
    /// The keyframe node.
    pub to: NodeId,
    /// The keyframe's pose in `from`'s frame (`from_from_to`).
    pub measurement: Se2,
    /// How it was found.
    pub source: LoopSource,
    /// The match score.
    pub score: f64,
    /// The match covariance (right tangent of `measurement`).
    pub covariance: Matrix3<f64>,
}

/// A keyframe's data.
struct KeyframeData {
    /// Points in the robot frame, beam order, range-limited.
    points_in_robot: Vec<Point2>,
    /// Distance travelled up to this keyframe (m).
    travel_m: f64,
}

/// The front-end's state: pose graph, submaps, keyframes, anchors of every scan.
pub struct FrontEnd {
    params: FrontEndParams,
    matcher: ScanMatcher,
    graph: PoseGraph2,
    anchors: ScanAnchors,
    keyframes: BTreeMap<NodeId, KeyframeData>,
    submaps: Vec<Submap>,
    /// Indices of the active submaps, oldest first (at most two).
    active: Vec<usize>,
    map_from_local: Se2,
    /// `(odom_from_robot, local_from_robot)` of the previous scan.
    previous: Option<(Se2, Se2)>,
    /// The current keyframe, its local pose, its wheel-odometry pose, and scans since it.
    current: Option<(NodeId, Se2, Se2, usize)>,
    travel_m: f64,
    /// Travel (m) at the last loop to a submap older than the active ones.
    travel_at_last_loop_m: f64,
    place_index: PlaceIndex<ScanContext>,
    /// Keyframes in the place index, by insertion ordinal, with their submap.
    place_keyframes: Vec<(Keyframe, usize)>,
    place_ordinal: HashMap<KeyframeId, usize>,
    keyframes_since_optimization: usize,
    loops_since_optimization: usize,
    loops: Vec<LoopRecord>,
    /// Loops with large corrections awaiting confirmation, with the pose they imply.
    pending_loops: Vec<(LoopRecord, Se2)>,
    /// The submap each keyframe was first inserted into.
    keyframe_submap: HashMap<NodeId, usize>,
    info: FrontEndInfo,
}

impl FrontEnd {
    /// A front-end with no scans yet.
    pub fn new(params: FrontEndParams) -> Result<Self, FrontEndError> {
        Ok(Self {
            matcher: ScanMatcher::new(params.matcher)?,
            place_index: PlaceIndex::new(params.loops.place.index.clone()),
            params,
            graph: PoseGraph2::new(),
            anchors: ScanAnchors::new(),
            keyframes: BTreeMap::new(),
            submaps: Vec::new(),
            active: Vec::new(),
            map_from_local: Se2::identity(),
            previous: None,
            current: None,
            travel_m: 0.0,
            travel_at_last_loop_m: 0.0,
            place_keyframes: Vec::new(),
            place_ordinal: HashMap::new(),
            keyframes_since_optimization: 0,
            loops_since_optimization: 0,
            loops: Vec::new(),
            pending_loops: Vec::new(),
            keyframe_submap: HashMap::new(),
            info: FrontEndInfo::default(),
        })
    }

    /// The pose graph (keyframe nodes; odometry, submap and loop edges).
    pub fn graph(&self) -> &PoseGraph2 {
        &self.graph
    }

    /// Every scan's keyframe and pose in it.
    pub fn anchors(&self) -> &ScanAnchors {
        &self.anchors
    }

    /// Counters.
    pub fn info(&self) -> FrontEndInfo {
        self.info
    }

    /// Points of a keyframe in its node's frame (range-limited, beam order).
    pub fn keyframe_points(&self, node: NodeId) -> Option<&[Point2]> {
        self.keyframes
            .get(&node)
            .map(|k| k.points_in_robot.as_slice())
    }

    /// Every loop edge added, in order.
    pub fn loops(&self) -> &[LoopRecord] {
        &self.loops
    }

    /// The submaps, in creation order.
    pub fn submaps(&self) -> &[Submap] {
        &self.submaps
    }

    /// Processes the next scan, taken at wheel-odometry pose `odom_from_robot`.
    pub fn add_scan(
        &mut self,
        odom_from_robot: &Se2,
        scan: &LaserScan,
    ) -> Result<ScanStep, FrontEndError> {
        let index = self.info.scans;
        if !odom_from_robot.is_finite() {
            return Err(FrontEndError::NonFiniteOdometry { scan: index });
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
        let matched = self.match_to_submap(&points, &predicted);
        self.info.seconds.matching += started.elapsed().as_secs_f64();
        let (local_from_robot, score) = match &matched {
            Some((_, m, local_from_robot)) => {
                self.info.matched += 1;
                (*local_from_robot, Some(m.score))
            }
            None => {
                self.info.odometry_only += 1;
                (predicted, None)
            }
        };
        if let Some((_, previous_local)) = self.previous {
            self.travel_m += previous_local
                .between(&local_from_robot)
                .translation()
                .norm();
        }
        self.previous = Some((*odom_from_robot, local_from_robot));
        // 3. Keyframe or anchor.
        let make_keyframe = match self.current {
            None => true,
            Some((_, keyframe_local, _, since)) => self
                .params
                .keyframes
                .is_keyframe(&keyframe_local.between(&local_from_robot), since + 1),
        };
        if !make_keyframe {
            if let Some((node, keyframe_local, _, since)) = self.current.as_mut() {
                *since += 1;
                self.anchors
                    .push(*node, keyframe_local.between(&local_from_robot));
            }
            return Ok(ScanStep {
                local_from_robot,
                score,
                keyframe: None,
                loops: 0,
            });
        }
        let submap_match = matched.map(|(s, m, _)| (s, m.target_from_query, m.covariance));
        let started = Instant::now();
        let node = self.add_keyframe(local_from_robot, *odom_from_robot, points, submap_match)?;
        self.info.seconds.submaps += started.elapsed().as_secs_f64();
        // 4. Loops.
        let loops = if self.params.loops.enabled {
            self.close_loops(node)
        } else {
            0
        };
        self.keyframes_since_optimization += 1;
        if loops > 0
            && self.keyframes_since_optimization >= self.params.loops.optimize_every_keyframes
        {
            self.optimize();
        }
        Ok(ScanStep {
            local_from_robot,
            score,
            keyframe: Some(node),
            loops,
        })
    }

    /// Matches `points` (robot frame) predicted at `predicted` (local frame) against the
    /// older active submap: ICP from the prediction when it clearly lands in the right basin,
    /// else the correlative search over the odometry window; then directions the match does
    /// not constrain (a corridor's axis) keep the prediction. The submap's index, the match
    /// in the submap frame, and the matched pose in the local frame.
    fn match_to_submap(
        &mut self,
        points: &[Point2],
        predicted: &Se2,
    ) -> Option<(usize, mapmerge_scanmatch::Match, Se2)> {
        let s = *self.active.first()?;
        let submap = self.submaps.get_mut(s)?;
        if submap.is_empty() {
            return None;
        }
        submap.prepare();
        let guess = submap.local_from_submap.between(predicted);
        let target = submap.target();
        let refined = self
            .matcher
            .refine(target, points, &guess)
            .filter(|m| self.params.refine_first.accepts(m, &guess));
        self.info.refined += usize::from(refined.is_some());
        let mut found = refined.or_else(|| {
            self.matcher
                .match_scan(target, points, &guess, &self.params.odometry_window)
        })?;
        let previous_local = self.previous.map_or(*predicted, |(_, local)| local);
        let prior_covariance = odometry_covariance(
            &previous_local.between(predicted),
            &self.params.odometry_prior,
        );
        found.target_from_query = fuse_with_prior(
            &found.target_from_query,
            &found.covariance,
            &guess,
            &prior_covariance,
        );
        let local_from_robot = submap.local_from_submap.compose(&found.target_from_query);
        Some((s, found, local_from_robot))
    }

    /// Optimises the graph if loops were added since the last optimisation (call after the
    /// last scan).
    pub fn finish(&mut self) {
        if self.loops_since_optimization > 0 {
            self.optimize();
        }
    }

    /// Adds a keyframe node with its edges and inserts it into the active submaps.
    fn add_keyframe(
        &mut self,
        local_from_robot: Se2,
        odom_from_robot: Se2,
        points_in_robot: Vec<Point2>,
        submap_match: Option<(usize, Se2, Matrix3<f64>)>,
    ) -> Result<NodeId, FrontEndError> {
        let node = NodeId(self.info.keyframes as u64);
        self.info.keyframes += 1;
        // Ids are fresh and edges join existing nodes, so adding cannot fail.
        let _ = self.graph.add_vertex(
            node,
            Vertex::new(self.map_from_local.compose(&local_from_robot)),
        );
        // The scan match: an edge from the submap's nearest keyframe.
        if let Some((s, submap_from_robot, covariance)) = submap_match {
            if let Some((member, member_from_robot)) = self
                .submaps
                .get(s)
                .and_then(|submap| submap.relative_to_nearest(&submap_from_robot))
            {
                if member != node {
                    let information = edge_information(&covariance, self.params.min_edge_sigma);
                    let _ = self.graph.add_edge(Edge {
                        from: member,
                        to: node,
                        measurement: member_from_robot,
                        information,
                        kind: EdgeKind::Odometry,
                    });
                }
            }
        }
        // Wheel odometry from the previous keyframe, loosely weighted.
        if let Some((previous, _, previous_odom, _)) = self.current {
            let measurement = previous_odom.between(&odom_from_robot);
            let information = edge_information(
                &odometry_covariance(&measurement, &self.params.odometry_prior),
                self.params.min_edge_sigma,
            );
            let _ = self.graph.add_edge(Edge {
                from: previous,
                to: node,
                measurement,
                information,
                kind: EdgeKind::Odometry,
            });
        }
        self.anchors.push(node, Se2::identity());
        self.current = Some((node, local_from_robot, odom_from_robot, 0));
        // Submaps: insert into the active ones; start a new one when the newest is half
        // full; finish the oldest when it is full.
        let start_new = match self.active.last().and_then(|&s| self.submaps.get(s)) {
            None => true,
            Some(newest) => {
                let started_at_m = newest
                    .keyframes
                    .first()
                    .and_then(|(first, _)| self.keyframes.get(first))
                    .map_or(self.travel_m, |k| k.travel_m);
                newest.keyframes.len() >= self.params.submap_keyframes.max(1)
                    || self.travel_m - started_at_m >= self.params.submap_travel_m
            }
        };
        if start_new {
            self.submaps
                .push(Submap::new(&self.matcher, node, local_from_robot)?);
            self.active.push(self.submaps.len() - 1);
            self.info.submaps += 1;
        }
        for &s in &self.active {
            if let Some(submap) = self.submaps.get_mut(s) {
                submap.insert(node, &local_from_robot, &points_in_robot)?;
                self.keyframe_submap.entry(node).or_insert(s);
            }
        }
        if self.active.len() > 2 {
            let finished = self.active.remove(0);
            self.finish_submap(finished)?;
        }
        self.keyframes.insert(
            node,
            KeyframeData {
                points_in_robot,
                travel_m: self.travel_m,
            },
        );
        Ok(node)
    }

    /// Finishes submap `s`: deep levels for loop search, its keyframes into the place index.
    fn finish_submap(&mut self, s: usize) -> Result<(), FrontEndError> {
        let Some(submap) = self.submaps.get_mut(s) else {
            return Ok(());
        };
        submap.finish(LOOP_BRANCH_AND_BOUND_DEPTH)?;
        let members: Vec<NodeId> = submap.keyframes.iter().map(|(node, _)| *node).collect();
        for node in members {
            // A keyframe inserted into two submaps is indexed with the first to finish.
            let id = KeyframeId(node.0);
            if self.place_ordinal.contains_key(&id) {
                continue;
            }
            let Some(data) = self.keyframes.get(&node) else {
                continue;
            };
            let descriptor =
                ScanContext::new(&data.points_in_robot, &self.params.loops.place.descriptor);
            self.place_index.insert(id, descriptor);
            self.place_ordinal.insert(id, self.place_keyframes.len());
            self.place_keyframes
                .push((Keyframe::new(node.0, data.points_in_robot.clone()), s));
        }
        Ok(())
    }

    /// Optimises the graph (Levenberg–Marquardt, DCS on every edge) and re-derives
    /// `map_from_local` from the newest keyframe. A failed optimisation keeps the graph's
    /// last good state (the solver's contract).
    fn optimize(&mut self) {
        let started = Instant::now();
        let params = OptimizerParams {
            robust: RobustKernel::Dcs {
                phi: chi2_quantile_99(3),
            },
            max_iterations: 20,
            ..OptimizerParams::default()
        };
        let _ = optimize(&mut self.graph, &params);
        self.info.optimizations += 1;
        self.info.seconds.optimization += started.elapsed().as_secs_f64();
        self.keyframes_since_optimization = 0;
        self.loops_since_optimization = 0;
        if let Some((node, local_from_robot, _, _)) = self.current {
            if let Some(vertex) = self.graph.vertex(node) {
                self.map_from_local = vertex.pose.compose(&local_from_robot.inverse());
            }
        }
    }
}

/// Information of an edge: the inverse of `covariance` with its standard deviations floored
/// at `min_sigma`.
fn edge_information(covariance: &Matrix3<f64>, min_sigma: (f64, f64)) -> Matrix3<f64> {
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
/// [`FrontEndParams::odometry_prior`].
fn odometry_covariance(increment: &Se2, model: &(f64, f64, f64, f64, f64)) -> Matrix3<f64> {
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

/// The result of [`run_front_end`]: every scan's pose and the counters.
#[derive(Clone, Debug)]
pub struct FrontEndRun {
    /// `map_from_robot` of every scan of the log, in log order (from the final graph).
    pub trajectory: Vec<Se2>,
    /// The final pose graph (node `k` is keyframe `k`).
    pub graph: PoseGraph2,
    /// Scan index (log order) of every keyframe node, by node id.
    pub keyframe_scans: Vec<usize>,
    /// Every loop edge added, in order.
    pub loops: Vec<LoopRecord>,
    /// Counters.
    pub info: FrontEndInfo,
    /// Wall time of the front-end alone (s).
    pub seconds: f64,
}

/// Runs the front-end over every scan of `log`, with each scan's `odom_from_robot` as the
/// wheel odometry (scans without one reuse the previous one).
pub fn run_front_end(
    log: &mapmerge_scan::LaserLog,
    params: FrontEndParams,
) -> Result<FrontEndRun, FrontEndError> {
    run_front_end_with_progress(log, params, |_| {})
}

/// As [`run_front_end`], calling `progress(scans_done)` after every scan.
pub fn run_front_end_with_progress(
    log: &mapmerge_scan::LaserLog,
    params: FrontEndParams,
    mut progress: impl FnMut(usize),
) -> Result<FrontEndRun, FrontEndError> {
    let mut front_end = FrontEnd::new(params)?;
    let started = std::time::Instant::now();
    let mut odometry = Se2::identity();
    let mut keyframe_scans = Vec::new();
    for (index, record) in log.scans.iter().enumerate() {
        odometry = record.odom_from_robot.unwrap_or(odometry);
        if front_end
            .add_scan(&odometry, &record.scan)?
            .keyframe
            .is_some()
        {
            keyframe_scans.push(index);
        }
        progress(index + 1);
    }
    front_end.finish();
    let seconds = started.elapsed().as_secs_f64();
    let trajectory = front_end
        .anchors()
        .trajectory(front_end.graph())
        .into_iter()
        .map(|pose| pose.unwrap_or_else(Se2::identity))
        .collect();
    Ok(FrontEndRun {
        trajectory,
        info: front_end.info(),
        loops: front_end.loops,
        graph: front_end.graph,
        keyframe_scans,
        seconds,
    })
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
        let model = FrontEndParams::default().odometry_prior;
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
