//! The map manager's run over one log (Ehlers et al., Sec. II): door passings split the log
//! into areas, each area is mapped on its own with the configuration its environment calls
//! for, and each passing becomes a link point known in the two maps it joins.
//!
//! The maps overlap at each door: an area's scans run `overlap_m` of travel past the door it
//! leaves by, and start `overlap_m` before the door it enters by, so the crossing's pose is in
//! both maps (Sec. II-A: link points lie "in an area where both maps slightly overlap").

use std::collections::BTreeMap;
use std::f64::consts::FRAC_PI_2;
use std::ops::Range;

use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_params::{Checker, Real, Validate};
use mapmerge_place::{
    find_loop_candidates_with_poses, GeometricVerifier, Keyframe, KeyframeId, PlaceParams,
    Verification,
};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph2, Vertex};
use mapmerge_scan::{voxel_downsample, BeamFilter, LaserScan, Point2};
use mapmerge_solve::{marginal_covariances, optimize, OptimizerParams};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use crate::door::{DoorDetector, DoorParams, DoorPassingDetection, UnpassedDoor};
use crate::environment::{Environment, Extents};
use crate::error::AreasError;
use crate::hybrid::{Area, HybridMap, LinkCandidate, LinkPoint};

/// Parameters of the map manager.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ManagerParams {
    /// Door detection.
    pub doors: DoorParams,
    /// How far adjacent maps overlap on each side of a door (m) (default: 1).
    pub overlap_m: f64,
    /// An area with fewer scans joins the one before it: its door passing is not a map
    /// boundary (default: 20).
    pub min_area_scans: usize,
    /// The first area's environment is judged after this many scans (default: 20).
    pub first_environment_scans: usize,
    /// Global tracking and topological loop closure (Sec. II-C, II-D).
    pub tracking: TrackingParams,
}

/// Global tracking across maps (Sec. II-D) and topological loop closure (Sec. II-C).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackingParams {
    /// r_orig of Eq. 3 (m) (default: 1).
    pub base_radius_m: f64,
    /// Growth of the position variance with travel since the last link point: a random walk
    /// of this many m²/m (default: 0.0025, 5 cm after 1 m)…
    pub variance_per_m: f64,
    /// … and of the heading, whose effect on position grows with the cube of the travel
    /// (rad²/m) (default: 1e-4, 1° after 3 m).
    pub heading_variance_per_m: f64,
    /// Local maps compared at link points: scans within this travel of the crossing (m)
    /// (default: 2).
    pub local_map_m: f64,
    /// A re-observed link point is accepted at this verification score (default: 0.95)…
    pub min_score: f64,
    /// … when the verified crossing lies within this of the earlier crossing (two passings of
    /// one door cross it within its width) (m) (default: 1; 1.5 let one neighbouring door
    /// through on the simulator's tuning tours), and within the search radius of where
    /// tracking put it.
    pub same_door_m: f64,
    /// Stop after this many link points were checked at one passing (default: 5).
    pub max_candidates: usize,
    /// A later session is placed by a global search over every placed area (no doors needed):
    /// its views, one every this much travel (m) (default: 1), are looked up in the placed
    /// sessions' views and verified (the place crate's search)…
    pub placement_spacing_m: f64,
    /// … a match counts at this verification score (default: 0.97)…
    pub placement_min_score: f64,
    /// … when no distinct place verifies within this of it: a symmetric building has
    /// look-alike rooms (default: 0.01)…
    pub placement_margin: f64,
    /// … and the session is placed where at least this many matches agree (default: 2).
    /// Matches agree when a chain of them joins them, each link either within this much of
    /// the session's travel (m) (default: 10) and within Eq. 3's radius, for the travel
    /// between them, of where the next puts the session (the tracking of Eq. 3 from match
    /// to match, so that drift along a session does not split it), or farther apart and
    /// placing the session within `base_radius_m` of each other; a look-alike room a few
    /// metres off joins neither way…
    pub placement_min_support: usize,
    /// … (see `placement_min_support`).
    pub placement_track_m: f64,
    /// … spread over at least this much of its travel (m) (default: 2: one spot fits several
    /// places)…
    pub placement_min_spread_m: f64,
    /// … and at least this many times as many as agree on any other placement (default: 2).
    pub placement_rival_ratio: f64,
    /// At most this many of the agreeing matches join the session to the map as edges
    /// (default: 8).
    pub placement_max_edges: usize,
}

impl Default for TrackingParams {
    fn default() -> Self {
        Self {
            base_radius_m: 1.0,
            variance_per_m: 0.0025,
            heading_variance_per_m: 1e-4,
            local_map_m: 2.0,
            min_score: 0.95,
            same_door_m: 1.0,
            max_candidates: 5,
            placement_spacing_m: 1.0,
            placement_min_score: 0.97,
            placement_margin: 0.01,
            placement_min_support: 2,
            placement_track_m: 10.0,
            placement_min_spread_m: 2.0,
            placement_rival_ratio: 2.0,
            placement_max_edges: 8,
        }
    }
}

impl Validate for TrackingParams {
    fn check(&self, check: &mut Checker) {
        check
            .real("base_radius_m", self.base_radius_m, Real::non_negative())
            .real("variance_per_m", self.variance_per_m, Real::non_negative())
            .real(
                "heading_variance_per_m",
                self.heading_variance_per_m,
                Real::non_negative(),
            )
            .real("local_map_m", self.local_map_m, Real::positive())
            .real("min_score", self.min_score, Real::fraction())
            .real("same_door_m", self.same_door_m, Real::positive())
            .size("max_candidates", self.max_candidates, 0, 1_000)
            .real(
                "placement_spacing_m",
                self.placement_spacing_m,
                Real::positive(),
            )
            .real(
                "placement_min_score",
                self.placement_min_score,
                Real::fraction(),
            )
            .real("placement_margin", self.placement_margin, Real::fraction())
            .size(
                "placement_min_support",
                self.placement_min_support,
                1,
                10_000,
            )
            .real(
                "placement_track_m",
                self.placement_track_m,
                Real::non_negative(),
            )
            .real(
                "placement_min_spread_m",
                self.placement_min_spread_m,
                Real::non_negative(),
            )
            .real(
                "placement_rival_ratio",
                self.placement_rival_ratio,
                Real::non_negative(),
            )
            .size("placement_max_edges", self.placement_max_edges, 1, 1_000);
    }
}

impl TrackingParams {
    /// Eq. 3 for the travel model: r = r_orig + 2·√(5.991·λ_max), λ_max the largest
    /// eigenvalue of the position covariance after `travel_m` of travel (5.991: χ² 95 % with
    /// 2 degrees of freedom), here σ² = q·d + q_θ·d³/3. Tracking takes λ_max from the
    /// solver's marginal covariance of the crossing; this serves where the graph gives none
    /// and for the agreement of two matches along one session.
    pub fn search_radius_m(&self, travel_m: f64) -> f64 {
        let d = travel_m.max(0.0);
        self.radius_for_variance_m(
            self.variance_per_m * d + self.heading_variance_per_m * d.powi(3) / 3.0,
        )
    }

    /// Eq. 3 for a position covariance whose largest eigenvalue is `lambda_max_m2`.
    pub fn radius_for_variance_m(&self, lambda_max_m2: f64) -> f64 {
        self.base_radius_m + 2.0 * (5.991 * lambda_max_m2.max(0.0)).sqrt()
    }
}

impl Default for ManagerParams {
    fn default() -> Self {
        Self {
            doors: DoorParams::default(),
            overlap_m: 1.0,
            min_area_scans: 20,
            first_environment_scans: 20,
            tracking: TrackingParams::default(),
        }
    }
}

impl Validate for ManagerParams {
    fn check(&self, check: &mut Checker) {
        check
            .nested("doors", &self.doors)
            .real("overlap_m", self.overlap_m, Real::non_negative())
            .size("min_area_scans", self.min_area_scans, 0, 100_000)
            .size(
                "first_environment_scans",
                self.first_environment_scans,
                0,
                100_000,
            )
            .nested("tracking", &self.tracking);
    }
}

/// The scans of one area.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AreaSpan {
    /// Scan indices (into the log), overlap included.
    pub scans: Range<usize>,
    /// Its environment.
    pub environment: Environment,
}

/// A log split at its door passings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Segmentation {
    /// Every passing detected (boundaries or not).
    pub passings: Vec<DoorPassingDetection>,
    /// The areas, in time order.
    pub spans: Vec<AreaSpan>,
    /// For each boundary between span `k` and `k + 1`: the passing (index into `passings`).
    pub boundaries: Vec<usize>,
    /// Doors seen but never passed (link-point candidates), in the order they were forgotten.
    #[serde(default)]
    pub unpassed: Vec<UnpassedDoor>,
}

/// Splits a log (`odom_from_robot` and scan of each scan) at its door passings.
pub fn segment<'a>(
    scans: impl IntoIterator<Item = (Se2, &'a LaserScan)>,
    params: &ManagerParams,
) -> Result<Segmentation, AreasError> {
    params.validate()?;
    let mut detector = DoorDetector::new(params.doors.clone())?;
    let mut first_environment = Extents::new(params.doors.environment.clone(), f64::INFINITY);
    let mut environment_of_first = None;
    let mut passings = Vec::new();
    let mut travel = Vec::new();
    let mut previous: Option<Se2> = None;
    for (index, (odom_from_robot, scan)) in scans.into_iter().enumerate() {
        let step = previous.map_or(0.0, |p| {
            (odom_from_robot.translation() - p.translation()).norm()
        });
        travel.push(travel.last().copied().unwrap_or(0.0) + step);
        previous = Some(odom_from_robot);
        if environment_of_first.is_none() {
            first_environment.push(&odom_from_robot, scan, travel[index]);
            if index + 1 >= params.first_environment_scans {
                environment_of_first = Some(first_environment.environment(&odom_from_robot));
            }
        }
        if let Some(found) = detector.push(&odom_from_robot, scan) {
            passings.push(found);
        }
    }
    let n = travel.len();
    let environment_of_first = environment_of_first
        .or_else(|| previous.map(|p| first_environment.environment(&p)))
        .unwrap_or(Environment::Indoor);
    // Boundaries at crossings, each area at least `min_area_scans` long.
    let mut cuts: Vec<(usize, usize)> = Vec::new(); // (crossing scan, passing)
    let mut last_cut = 0usize;
    for (i, passing) in passings.iter().enumerate() {
        let c = passing.crossing_scan;
        if c >= last_cut + params.min_area_scans && c + params.min_area_scans <= n {
            cuts.push((c, i));
            last_cut = c;
        }
    }
    // Scan indices `overlap_m` of travel before and after a crossing.
    let before = |c: usize| {
        let limit = travel[c] - params.overlap_m;
        (0..=c).rev().find(|&k| travel[k] <= limit).unwrap_or(0)
    };
    let after = |c: usize| {
        let limit = travel[c] + params.overlap_m;
        (c..n).find(|&k| travel[k] >= limit).map_or(n, |k| k + 1)
    };
    let mut spans = Vec::with_capacity(cuts.len() + 1);
    let mut start = 0;
    let mut environment = environment_of_first;
    for &(c, i) in &cuts {
        spans.push(AreaSpan {
            scans: start..after(c),
            environment,
        });
        start = before(c);
        environment = passings[i].environment;
    }
    if n > 0 {
        spans.push(AreaSpan {
            scans: start..n,
            environment,
        });
    }
    Ok(Segmentation {
        passings,
        boundaries: cuts.iter().map(|(_, i)| *i).collect(),
        spans,
        unpassed: detector.finish(),
    })
}

/// A topological loop closure: a passing recognised as the re-observation of an earlier
/// link point (the same door).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Closure {
    /// The boundary whose passing it was.
    pub boundary: usize,
    /// The earlier boundary it re-observed.
    pub earlier: usize,
    /// The verification's score.
    pub score: f64,
}

/// A topological loop closure at a link-point candidate: a passing through a door seen
/// earlier, but not passed, from another area.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CandidateClosure {
    /// The passing's boundary (over all sessions).
    pub boundary: usize,
    /// The session that saw the door …
    pub session: usize,
    /// … and the door as it saw it.
    pub door: UnpassedDoor,
    /// The verification's score.
    pub score: f64,
    /// Whether the span after the crossing joined the seen side's area (else the one before).
    #[serde(default)]
    pub joined_after: bool,
}

/// Global tracking at one boundary (Sec. II-D).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrackingStep {
    /// The boundary.
    pub boundary: usize,
    /// Travel since the last link point whose global pose was re-observed (m).
    pub travel_since_closure_m: f64,
    /// Eq. 3's search radius (m): from the crossing's marginal covariance in the link-point
    /// graph (from the travel since the last closure where the solver gives none).
    pub radius_m: f64,
    /// Earlier boundaries (not themselves re-observations) whose crossing lay within it;
    /// the nearest `max_candidates` were checked.
    pub within_radius: Vec<usize>,
}

/// The map manager's result for one log.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ManagedMap {
    /// The hybrid map: one area per group of spans found to be the same place, one link
    /// point per door.
    pub hybrid: HybridMap,
    /// The area of each span (spans of all sessions, in order).
    pub span_area: Vec<usize>,
    /// The session of each span.
    pub span_session: Vec<usize>,
    /// Where each span's frame lies in the first span's frame, after optimisation.
    pub first_from_span: Vec<Se2>,
    /// Each boundary's crossing in the first span's frame, after optimisation.
    pub crossings: Vec<Se2>,
    /// The link point (of `hybrid`) of each boundary: its own, the earlier one it
    /// re-observed, or none when both its sides are one area.
    pub boundary_link: Vec<Option<usize>>,
    /// Topological loop closures.
    pub closures: Vec<Closure>,
    /// Topological loop closures at link-point candidates.
    #[serde(default)]
    pub candidate_closures: Vec<CandidateClosure>,
    /// Global tracking at each boundary (boundaries of all sessions, in order).
    pub tracking: Vec<TrackingStep>,
    /// Whether each session was placed in session 0's frame (session 0 is; a later one when
    /// the global search placed it). Unplaced sessions' areas stay in their own frames.
    pub session_placed: Vec<bool>,
    /// How each placed later session was placed. Not stored: the lifelong store keeps the
    /// map in a fixed binary layout, and a map read back from it has none.
    #[serde(skip)]
    pub placements: Vec<SessionPlacement>,
}

impl ManagedMap {
    /// Where span `g`'s frame lies in its area's frame.
    pub fn area_from_span(&self, g: usize) -> Option<Se2> {
        let area = self.hybrid.areas.get(*self.span_area.get(g)?)?;
        Some(
            area.first_from_area
                .inverse()
                .compose(self.first_from_span.get(g)?),
        )
    }
}

/// Builds the hybrid map of a segmented log ([`manage_sessions`] with one session).
pub fn manage(
    segmentation: &Segmentation,
    trajectories: &[Vec<Se2>],
    scans: &[&LaserScan],
    params: &ManagerParams,
    verifier: &dyn GeometricVerifier,
) -> Result<ManagedMap, AreasError> {
    let session = SessionInput {
        segmentation,
        trajectories,
        scans,
    };
    manage_sessions(&[session], params, verifier)
}

/// One session's input to [`manage_sessions`].
#[derive(Clone, Copy, Debug)]
pub struct SessionInput<'a> {
    /// Its log split at door passings.
    pub segmentation: &'a Segmentation,
    /// Each span's trajectory (`map_from_robot` of each of its scans, in its own frame).
    pub trajectories: &'a [Vec<Se2>],
    /// The log's scans.
    pub scans: &'a [&'a LaserScan],
}

/// A boundary of one session, indexed over all sessions.
#[derive(Clone, Copy, Debug)]
struct Boundary {
    session: usize,
    /// The crossing's scan (in its session's log).
    crossing: usize,
    /// Global span indices before and after it.
    before: usize,
    after: usize,
    /// The crossing's pose in each of the two spans' frames.
    exit: Se2,
    entry: Se2,
    /// Travel along `before` from its entry to this crossing (m).
    leg_m: f64,
}

/// Builds the hybrid map of one or more sessions (logs) from each span's trajectory and the
/// logs' scans:
///
/// 1. the link-point graph: a node at each session's start and at each boundary's crossing,
///    an edge between consecutive nodes of a session measured in the span between them (its
///    variance growing with the travel between them); session 0's start is the origin;
/// 2. a later session is placed before its crossings are tracked, by a global search that
///    needs no door: a view every `placement_spacing_m` of its travel is looked up among the
///    placed sessions' views and verified (`mapmerge-place`'s search); matches agree when
///    Eq. 3's tracking leads from one to the next (each within the radius, for the travel
///    between them, of where the next puts the session), and the largest such chain, spread
///    over `placement_min_spread_m` and outnumbering any other, places the session. Its
///    nodes then move onto the map, the chain's best matches join it as edges (their
///    information allowing for each span's drift from its entry), and the spans they join
///    become one area when both views lie inside them. A session the search cannot place
///    keeps its own frame;
/// 3. global tracking (Sec. II-D): each new crossing's pose through the chain, and Eq. 3's
///    radius from its marginal covariance in the link-point graph (the solver's);
/// 4. topological loop closure (Sec. II-C): the earlier crossings within the radius are
///    verified by scan matching their local maps (`verifier`, our place recognition's, in
///    place of the paper's images); the best accepted one becomes a loop edge, the graph is
///    optimised (the re-observed link point is the landmark), and the spans on each side of
///    the door are joined into one area. Without an earlier crossing to close with, the
///    link-point candidates of other areas (doors seen there before, not passed) are tried
///    the same way, and a verified one joins the span on the side the door was seen from;
/// 5. areas, link points (one per door), candidates left and edges.
pub fn manage_sessions(
    sessions: &[SessionInput<'_>],
    params: &ManagerParams,
    verifier: &dyn GeometricVerifier,
) -> Result<ManagedMap, AreasError> {
    params.validate()?;
    let mapping = |text: String| AreasError::Mapping(text);
    // Spans over all sessions, in order: (session, local index).
    let mut span_refs: Vec<(usize, usize)> = Vec::new();
    for (s, session) in sessions.iter().enumerate() {
        let spans = &session.segmentation.spans;
        if session.trajectories.len() != spans.len() {
            return Err(mapping(format!(
                "session {s}: {} trajectories for {} areas",
                session.trajectories.len(),
                spans.len()
            )));
        }
        for (k, (span, trajectory)) in spans.iter().zip(session.trajectories).enumerate() {
            if trajectory.len() != span.scans.len() || span.scans.end > session.scans.len() {
                return Err(mapping(format!(
                    "session {s} area {k}: {} poses for scans {:?} of {}",
                    trajectory.len(),
                    span.scans,
                    session.scans.len()
                )));
            }
            span_refs.push((s, k));
        }
    }
    let span_of = |g: usize| -> (&AreaSpan, &Vec<Se2>, usize) {
        let (s, k) = span_refs[g];
        (
            &sessions[s].segmentation.spans[k],
            &sessions[s].trajectories[k],
            s,
        )
    };
    let pose_at = |g: usize, scan: usize| -> Result<Se2, AreasError> {
        let (span, trajectory, s) = span_of(g);
        scan.checked_sub(span.scans.start)
            .and_then(|k| trajectory.get(k).copied())
            .ok_or_else(|| mapping(format!("session {s}: no pose for scan {scan}")))
    };
    let travel_between = |g: usize, a: usize, b: usize| -> f64 {
        let (span, t, _) = span_of(g);
        let start = span.scans.start;
        (a.max(start)..b)
            .filter_map(|k| {
                Some((t.get(k + 1 - start)?.translation() - t.get(k - start)?.translation()).norm())
            })
            .sum()
    };
    // Boundaries over all sessions; each span's entry node and pose.
    let mut boundaries: Vec<Boundary> = Vec::new();
    let mut entry_pose = vec![Se2::identity(); span_refs.len()];
    let mut entry_scan = vec![0usize; span_refs.len()];
    let mut entry_node = vec![0usize; span_refs.len()];
    let mut session_start = Vec::with_capacity(sessions.len());
    let mut nodes = 0usize;
    let mut first_span = 0usize;
    for (s, session) in sessions.iter().enumerate() {
        let seg = session.segmentation;
        session_start.push(nodes);
        if !seg.spans.is_empty() {
            entry_node[first_span] = nodes;
            entry_scan[first_span] = seg.spans[0].scans.start;
        }
        nodes += 1;
        for (b, passing) in seg.boundaries.iter().enumerate() {
            let c = seg
                .passings
                .get(*passing)
                .map(|p| p.crossing_scan)
                .ok_or_else(|| mapping(format!("session {s}: no passing {passing}")))?;
            let (before, after) = (first_span + b, first_span + b + 1);
            boundaries.push(Boundary {
                session: s,
                crossing: c,
                before,
                after,
                exit: pose_at(before, c)?,
                entry: pose_at(after, c)?,
                leg_m: travel_between(before, entry_scan[before], c),
            });
            entry_pose[after] = pose_at(after, c)?;
            entry_scan[after] = c;
            entry_node[after] = nodes;
            nodes += 1;
        }
        first_span += seg.spans.len();
    }
    // The node of boundary i.
    let node_of: Vec<usize> = boundaries.iter().map(|b| entry_node[b.after]).collect();
    let tracking = &params.tracking;
    let node = |k: usize| NodeId(k as u64);
    let graph_error = |e: mapmerge_posegraph::GraphError| mapping(e.to_string());
    let mut graph = PoseGraph2::new();
    for start in &session_start {
        // Every session's start holds its component until it is placed.
        graph
            .add_vertex(
                node(*start),
                Vertex {
                    pose: Se2::identity(),
                    fixed: true,
                    meta: Default::default(),
                },
            )
            .map_err(graph_error)?;
    }
    for (i, b) in boundaries.iter().enumerate() {
        let measurement = entry_pose[b.before].inverse().compose(&b.exit);
        let from = entry_node[b.before];
        let previous = graph
            .vertex(node(from))
            .map(|v| v.pose)
            .unwrap_or_else(Se2::identity);
        graph
            .add_vertex(
                node(node_of[i]),
                Vertex::new(previous.compose(&measurement)),
            )
            .map_err(graph_error)?;
        graph
            .add_edge(Edge {
                from: node(from),
                to: node(node_of[i]),
                measurement,
                information: leg_information(tracking, b.leg_m),
                kind: EdgeKind::Odometry,
            })
            .map_err(graph_error)?;
    }
    let local_map_at = |i: usize| {
        let b = &boundaries[i];
        let (span, trajectory, s) = span_of(b.before);
        local_map(
            b.crossing,
            &b.exit,
            span,
            trajectory,
            sessions[s].scans,
            tracking,
        )
    };
    // Link-point candidates: doors a span saw and no boundary of that span passed.
    let mut span_candidates: Vec<SpanCandidate> = Vec::new();
    let mut first = 0usize;
    for (s, session) in sessions.iter().enumerate() {
        let seg = session.segmentation;
        for door in &seg.unpassed {
            // The span whose own part (between its crossings, overlaps aside) holds the scan:
            // the robot's side of the doors at that scan.
            let k = seg
                .boundaries
                .iter()
                .filter_map(|p| seg.passings.get(*p))
                .filter(|p| p.crossing_scan <= door.scan)
                .count();
            if k >= seg.spans.len() {
                continue;
            }
            let g = first + k;
            let robot_in_span = pose_at(g, door.scan)?;
            let centre = door.center_in_robot_m();
            let along = door.posts_in_robot_m[1] - door.posts_in_robot_m[0];
            let mut normal = Point2::new(-along.y, along.x);
            if normal.dot(&centre) < 0.0 {
                normal = -normal;
            }
            let door_in_robot = Se2::new(centre.x, centre.y, normal.y.atan2(normal.x));
            let in_span = robot_in_span.compose(&door_in_robot);
            let near =
                |p: Se2| (p.translation() - in_span.translation()).norm() <= tracking.same_door_m;
            let passed = boundaries
                .iter()
                .any(|b| (b.before == g && near(b.exit)) || (b.after == g && near(b.entry)));
            let duplicate = span_candidates
                .iter()
                .any(|c| c.span == g && near(c.in_span));
            if !passed && !duplicate {
                span_candidates.push(SpanCandidate {
                    span: g,
                    session: s,
                    door: *door,
                    robot_in_span,
                    door_in_robot,
                    in_span,
                    used: false,
                });
            }
        }
        first += seg.spans.len();
    }
    // Where span g's frame lies in the graph's.
    let frame_of = |graph: &PoseGraph2, g: usize| {
        graph
            .vertex(node(entry_node[g]))
            .map(|v| v.pose)
            .unwrap_or_else(Se2::identity)
            .compose(&entry_pose[g].inverse())
    };
    let mut candidate_closures = Vec::new();
    // Each span's own part: from its entry crossing to its exit crossing (the overlaps are
    // its neighbours').
    let mut exit_scan: Vec<usize> = (0..span_refs.len())
        .map(|g| span_of(g).0.scans.end)
        .collect();
    for b in &boundaries {
        exit_scan[b.before] = b.crossing + 1;
    }
    // Views every `placement_spacing_m` of a span's own part, with their travel from the
    // span's entry: what a placement search queries and looks up.
    let has_entry: Vec<bool> = (0..span_refs.len())
        .map(|g| boundaries.iter().any(|b| b.after == g))
        .collect();
    let has_exit: Vec<bool> = (0..span_refs.len())
        .map(|g| boundaries.iter().any(|b| b.before == g))
        .collect();
    let span_views = |g: usize| -> Vec<View> {
        let (span, trajectory, s) = span_of(g);
        let mut views: Vec<View> = Vec::new();
        let (mut travel_m, mut previous) = (0.0, None::<Se2>);
        for k in entry_scan[g]..exit_scan[g] {
            let Some(pose) = k
                .checked_sub(span.scans.start)
                .and_then(|i| trajectory.get(i))
            else {
                continue;
            };
            if let Some(p) = previous {
                travel_m += (pose.translation() - p.translation()).norm();
            }
            previous = Some(*pose);
            if views
                .last()
                .is_none_or(|v| travel_m - v.travel_m >= tracking.placement_spacing_m)
            {
                views.push(View {
                    span: g,
                    in_span: *pose,
                    from_entry_m: travel_m,
                    to_exit_m: 0.0,
                    travel_m,
                    inside: false,
                    keyframe: local_map(k, pose, span, trajectory, sessions[s].scans, tracking),
                });
            }
        }
        for v in &mut views {
            v.to_exit_m = travel_m - v.from_entry_m;
            v.inside = (!has_entry[g] || v.from_entry_m >= tracking.local_map_m)
                && (!has_exit[g] || v.to_exit_m >= tracking.local_map_m);
        }
        views
    };
    // Each span's views, built once: as a later session's queries, then as what the sessions
    // after it look up once it is placed.
    let mut views_of_span: Vec<Option<Vec<View>>> = vec![None; span_refs.len()];
    let mut placements: Vec<SessionPlacement> = Vec::new();
    // 2–4. A later session is placed, then tracking and closures, boundary by boundary.
    let mut placed: Vec<bool> = (0..sessions.len()).map(|s| s == 0).collect();
    let mut groups = UnionFind::new(span_refs.len());
    let mut closures = Vec::new();
    let mut steps = Vec::with_capacity(boundaries.len());
    let mut merged_into: Vec<Option<usize>> = vec![None; boundaries.len()];
    let mut session_spans = Vec::with_capacity(sessions.len());
    let mut first = 0usize;
    for session in sessions {
        session_spans.push(first..first + session.segmentation.spans.len());
        first += session.segmentation.spans.len();
    }
    for (s, own_spans) in session_spans.iter().enumerate() {
        if s > 0 {
            for (g, (owner, _)) in span_refs.iter().enumerate() {
                if (placed[*owner] || own_spans.contains(&g)) && views_of_span[g].is_none() {
                    views_of_span[g] = Some(span_views(g));
                }
            }
            // This session's views, with their travel over the session.
            let mut queries: Vec<View> = Vec::new();
            let mut offset_m = 0.0;
            for g in own_spans.clone() {
                let views = views_of_span[g].iter().flatten().cloned();
                queries.extend(views.map(|mut v| {
                    v.travel_m += offset_m;
                    v
                }));
                offset_m += boundaries
                    .iter()
                    .find(|b| b.before == g)
                    .map_or(0.0, |b| b.leg_m);
            }
            // The placed sessions' views, in the graph's frame.
            let known: Vec<&View> = span_refs
                .iter()
                .zip(&views_of_span)
                .filter(|((owner, _), _)| placed[*owner])
                .flat_map(|(_, views)| views.iter().flatten())
                .collect();
            let found = place_session(
                s,
                &queries,
                &known,
                |g| frame_of(&graph, g),
                tracking,
                verifier,
            );
            if let Some(placement) = found {
                // Move the session's component onto the map, let its start go, and join it
                // by the agreeing matches.
                let members = std::iter::once(session_start[s]).chain(
                    boundaries
                        .iter()
                        .zip(&node_of)
                        .filter(|(x, _)| x.session == s)
                        .map(|(_, n)| *n),
                );
                for n in members {
                    if let Some(v) = graph.vertex_mut(node(n)) {
                        v.pose = placement.first_from_session.compose(&v.pose);
                    }
                }
                if let Some(v) = graph.vertex_mut(node(session_start[s])) {
                    v.fixed = false;
                }
                for m in &placement.joins {
                    let (query, view) = (&queries[m.query], known[m.view]);
                    graph
                        .add_edge(Edge {
                            from: node(entry_node[view.span]),
                            to: node(entry_node[query.span]),
                            measurement: entry_pose[view.span]
                                .inverse()
                                .compose(&view.in_span)
                                .compose(&m.view_from_query)
                                .compose(&query.in_span.inverse())
                                .compose(&entry_pose[query.span]),
                            // The match, and the drift of each span from its entry to the
                            // view.
                            information: closure_information(
                                &(m.covariance
                                    + leg_covariance(tracking, view.from_entry_m)
                                    + leg_covariance(tracking, query.from_entry_m)),
                            ),
                            kind: EdgeKind::Loop,
                        })
                        .map_err(graph_error)?;
                    // Both views inside their spans, at one place: one area.
                    if view.inside && query.inside {
                        groups.union(view.span, query.span);
                    }
                }
                let _ = optimize(&mut graph, &OptimizerParams::default());
                placed[s] = true;
                placements.push(placement.report);
            }
        }
        let mut since_closure_m = 0.0;
        for i in (0..boundaries.len()).filter(|i| boundaries[*i].session == s) {
            let b = boundaries[i];
            since_closure_m += b.leg_m;
            // Eq. 3 from the crossing's marginal covariance in the link-point graph; the
            // travel model where the graph gives none.
            let marginal = position_variance_m2(&graph, node(node_of[i]));
            let radius_m = marginal.map_or_else(
                || tracking.search_radius_m(since_closure_m),
                |variance| tracking.radius_for_variance_m(variance),
            );
            let pose = |graph: &PoseGraph2, i: usize| {
                graph
                    .vertex(node(node_of[i]))
                    .map(|v| v.pose)
                    .unwrap_or_else(Se2::identity)
            };
            let here = pose(&graph, i);
            // Earlier crossings of this session or a placed one, within the radius.
            let mut candidates: Vec<(f64, usize)> = (0..i)
                .filter(|j| merged_into[*j].is_none())
                .filter(|j| boundaries[*j].session == s || placed[boundaries[*j].session])
                .filter_map(|j| {
                    let d = (pose(&graph, j).translation() - here.translation()).norm();
                    (d <= radius_m).then_some((d, j))
                })
                .collect();
            candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
            steps.push(TrackingStep {
                boundary: i,
                travel_since_closure_m: since_closure_m,
                radius_m,
                within_radius: candidates.iter().map(|(_, j)| *j).collect(),
            });
            candidates.truncate(tracking.max_candidates);
            // Nothing to verify against: no local map to build.
            if candidates.is_empty() && span_candidates.iter().all(|c| c.used) {
                continue;
            }
            let query = local_map_at(i);
            let mut best: Option<(usize, Verification)> = None;
            for (_, j) in &candidates {
                let there = pose(&graph, *j);
                let candidate = local_map_at(*j);
                let guess = there.inverse().compose(&here);
                let Some(found) = verifier.verify(&query, &candidate, &guess) else {
                    continue;
                };
                let correction_m = guess
                    .between(&found.candidate_from_query)
                    .translation()
                    .norm();
                let same_door =
                    found.candidate_from_query.translation().norm() <= tracking.same_door_m;
                if found.score >= tracking.min_score
                    && same_door
                    && correction_m <= radius_m
                    && best.as_ref().is_none_or(|(_, v)| found.score > v.score)
                {
                    best = Some((*j, found));
                }
            }
            let Some((j, found)) = best else {
                // No earlier crossing: a door seen from another area and not passed there, within
                // the radius, verified on the local map around where it was seen.
                let mut near: Vec<(f64, usize)> = span_candidates
                    .iter()
                    .enumerate()
                    .filter(|(_, c)| !c.used && groups.find(c.span) != groups.find(b.before))
                    // Seen before this crossing: in an earlier session that is placed, or earlier
                    // in this one.
                    .filter(|(_, c)| {
                        (c.session < b.session && placed[c.session])
                            || (c.session == b.session && c.door.scan < b.crossing)
                    })
                    .filter_map(|(k, c)| {
                        let at = frame_of(&graph, c.span).compose(&c.in_span);
                        let d = (at.translation() - here.translation()).norm();
                        (d <= radius_m).then_some((d, k))
                    })
                    .collect();
                near.sort_by(|a, b| a.0.total_cmp(&b.0));
                near.truncate(tracking.max_candidates);
                let mut chosen: Option<(usize, Verification)> = None;
                for (_, k) in &near {
                    let c = &span_candidates[*k];
                    let (span, trajectory, s) = span_of(c.span);
                    let seen = local_map(
                        c.door.scan,
                        &c.robot_in_span,
                        span,
                        trajectory,
                        sessions[s].scans,
                        tracking,
                    );
                    let guess = frame_of(&graph, c.span)
                        .compose(&c.robot_in_span)
                        .inverse()
                        .compose(&here);
                    let Some(found) = verifier.verify(&query, &seen, &guess) else {
                        continue;
                    };
                    let correction_m = guess
                        .between(&found.candidate_from_query)
                        .translation()
                        .norm();
                    let at_door = (found.candidate_from_query.translation()
                        - c.door_in_robot.translation())
                    .norm()
                        <= tracking.same_door_m;
                    if found.score >= tracking.min_score
                        && at_door
                        && correction_m <= radius_m
                        && chosen.as_ref().is_none_or(|(_, v)| found.score > v.score)
                    {
                        chosen = Some((*k, found));
                    }
                }
                let Some((k, found)) = chosen else {
                    continue;
                };
                span_candidates[k].used = true;
                let c = span_candidates[k];
                graph
                    .add_edge(Edge {
                        from: node(entry_node[c.span]),
                        to: node(node_of[i]),
                        measurement: entry_pose[c.span]
                            .inverse()
                            .compose(&c.robot_in_span)
                            .compose(&found.candidate_from_query),
                        information: closure_information(&found.covariance),
                        kind: EdgeKind::Loop,
                    })
                    .map_err(graph_error)?;
                let _ = optimize(&mut graph, &OptimizerParams::default());
                // Heading along the door's normal, away from where it was seen: the robot leaves
                // the side it was seen from.
                let leaving_seen_side =
                    (found.candidate_from_query.theta_rad - c.door_in_robot.theta_rad).cos() > 0.0;
                if leaving_seen_side {
                    groups.union(b.before, c.span);
                } else {
                    groups.union(b.after, c.span);
                }
                candidate_closures.push(CandidateClosure {
                    boundary: i,
                    session: c.session,
                    door: c.door,
                    score: found.score,
                    joined_after: !leaving_seen_side,
                });
                since_closure_m = 0.0;
                continue;
            };
            // The closure to add.
            let joins = vec![(i, j, found)];
            for (i, j, found) in &joins {
                graph
                    .add_edge(Edge {
                        from: node(node_of[*j]),
                        to: node(node_of[*i]),
                        measurement: found.candidate_from_query,
                        information: closure_information(&found.covariance),
                        kind: EdgeKind::Loop,
                    })
                    .map_err(graph_error)?;
            }
            // A numerical failure keeps the last good state, which is the chain: still a map.
            let _ = optimize(&mut graph, &OptimizerParams::default());
            for (i, j, found) in joins {
                let (there, here) = (pose(&graph, j), pose(&graph, i));
                let (now, earlier) = (boundaries[i], boundaries[j]);
                // Same direction through the door: the same sides; else swapped.
                if wrap_angle_rad(here.theta_rad - there.theta_rad).abs() < FRAC_PI_2 {
                    groups.union(now.before, earlier.before);
                    groups.union(now.after, earlier.after);
                } else {
                    groups.union(now.before, earlier.after);
                    groups.union(now.after, earlier.before);
                }
                merged_into[i] = Some(j);
                closures.push(Closure {
                    boundary: i,
                    earlier: j,
                    score: found.score,
                });
            }
            since_closure_m = 0.0;
        }
    }

    // 5. Frames, areas, link points.
    let pose_of = |n: usize| {
        graph
            .vertex(node(n))
            .map(|v| v.pose)
            .unwrap_or_else(Se2::identity)
    };
    let first_from_span: Vec<Se2> = (0..span_refs.len())
        .map(|g| pose_of(entry_node[g]).compose(&entry_pose[g].inverse()))
        .collect();
    let crossings: Vec<Se2> = node_of.iter().map(|n| pose_of(*n)).collect();
    let mut area_of_root = BTreeMap::new();
    let mut span_area = Vec::with_capacity(span_refs.len());
    let mut first_span_of_area = Vec::new();
    for g in 0..span_refs.len() {
        let root = groups.find(g);
        let area = *area_of_root.entry(root).or_insert_with(|| {
            first_span_of_area.push(g);
            first_span_of_area.len() - 1
        });
        span_area.push(area);
    }
    let areas: Vec<Area> = first_span_of_area
        .iter()
        .enumerate()
        .map(|(id, g)| Area {
            id,
            environment: span_of(*g).0.environment,
            first_from_area: first_from_span[*g],
        })
        .collect();
    let area_from_span: Vec<Se2> = (0..span_refs.len())
        .map(|g| {
            areas[span_area[g]]
                .first_from_area
                .inverse()
                .compose(&first_from_span[g])
        })
        .collect();
    let mut link_points: Vec<LinkPoint> = Vec::new();
    let mut boundary_link = vec![None; boundaries.len()];
    for (i, b) in boundaries.iter().enumerate() {
        if let Some(j) = merged_into[i] {
            boundary_link[i] = boundary_link[j];
            continue;
        }
        let (a0, a1) = (span_area[b.before], span_area[b.after]);
        if a0 == a1 {
            continue;
        }
        boundary_link[i] = Some(link_points.len());
        link_points.push(LinkPoint {
            id: link_points.len(),
            areas: [a0, a1],
            poses: [
                area_from_span[b.before].compose(&b.exit),
                area_from_span[b.after].compose(&b.entry),
            ],
        });
    }
    // Candidates not passed, one per door of an area, none at a link point.
    let mut candidates: Vec<LinkCandidate> = Vec::new();
    for c in span_candidates.iter().filter(|c| !c.used) {
        let area = span_area[c.span];
        let pose = area_from_span[c.span].compose(&c.in_span);
        let near = |p: Se2| (p.translation() - pose.translation()).norm() <= tracking.same_door_m;
        let known = candidates.iter().any(|k| k.area == area && near(k.pose))
            || link_points
                .iter()
                .any(|l| l.pose_in(area).is_some_and(near));
        if !known {
            candidates.push(LinkCandidate {
                id: candidates.len(),
                area,
                pose,
            });
        }
    }
    let mut hybrid = HybridMap {
        areas,
        link_points,
        edges: Vec::new(),
        candidates,
    };
    hybrid.connect();
    let span_session: Vec<usize> = span_refs.iter().map(|(s, _)| *s).collect();
    Ok(ManagedMap {
        hybrid,
        span_area,
        span_session,
        first_from_span,
        crossings,
        boundary_link,
        closures,
        candidate_closures,
        tracking: steps,
        session_placed: placed,
        placements,
    })
}

/// A view of a span for the placement search: the local map at one of its scans.
#[derive(Clone, Debug)]
struct View {
    /// The span (over all sessions).
    span: usize,
    /// The robot at the view, in the span's frame.
    in_span: Se2,
    /// Its travel from the span's entry and to its exit (m)…
    from_entry_m: f64,
    to_exit_m: f64,
    /// … and from its session's start, for a query (m).
    travel_m: f64,
    /// Whether it lies `local_map_m` or more from its span's crossings: its local map then
    /// sees its own area only.
    inside: bool,
    /// The local map around it, in the robot's frame.
    keyframe: Keyframe,
}

/// A verified match of a view of the session being placed to a placed one.
#[derive(Clone, Debug)]
struct PlacementMatch {
    /// Ordinals of the query view and of the placed view.
    query: usize,
    view: usize,
    /// The query view in the placed view's frame, its covariance and score.
    view_from_query: Se2,
    covariance: Matrix3<f64>,
    score: f64,
    /// Where the session's frame lies in the graph's frame for this match.
    first_from_session: Se2,
}

/// A session placed by the global search.
#[derive(Clone, Debug)]
struct Placement {
    first_from_session: Se2,
    /// The matches that join it to the map.
    joins: Vec<PlacementMatch>,
    report: SessionPlacement,
}

/// How a later session was placed: by a global search over the placed areas, its matches
/// agreeing as Eq. 3's tracking says they must.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SessionPlacement {
    /// The session.
    pub session: usize,
    /// Its views searched, and those verified unambiguously in a placed area.
    pub views: usize,
    /// …
    pub matches: usize,
    /// Matches agreeing with the placement, and the most agreeing with any other.
    pub support: usize,
    /// …
    pub rival_support: usize,
    /// The session's travel the agreeing matches spread over (m).
    pub spread_m: f64,
    /// Matches that became edges of the link-point graph.
    pub edges: usize,
}

/// The global search for a later session (`queries`, its views, in its own frame through
/// `first_from_span`) in the placed areas (`known`): every view is looked up and verified;
/// each unambiguous match says where the session's frame lies. Matches are chained by the
/// tracking of Eq. 3 (see `TrackingParams::placement_min_support`); the largest chain places
/// the session when it is large enough, spread over enough travel, and clearly larger than
/// the next.
fn place_session(
    session: usize,
    queries: &[View],
    known: &[&View],
    first_from_span: impl Fn(usize) -> Se2,
    tracking: &TrackingParams,
    verifier: &dyn GeometricVerifier,
) -> Option<Placement> {
    if queries.is_empty() || known.is_empty() {
        return None;
    }
    let keyframe = |v: &View, ordinal: usize| {
        let mut k = v.keyframe.clone();
        k.id = KeyframeId(ordinal as u64);
        k
    };
    let query_keyframes: Vec<Keyframe> = queries
        .iter()
        .enumerate()
        .map(|(k, v)| keyframe(v, k))
        .collect();
    let known_keyframes: Vec<Keyframe> = known
        .iter()
        .enumerate()
        .map(|(k, v)| keyframe(v, k))
        .collect();
    let first_from_view = |v: &View| first_from_span(v.span).compose(&v.in_span);
    let known_poses: Vec<Se2> = known.iter().map(|v| first_from_view(v)).collect();
    let params = PlaceParams {
        min_score: tracking.placement_min_score,
        ..PlaceParams::default()
    };
    let loops = find_loop_candidates_with_poses(
        &query_keyframes,
        &known_keyframes,
        &known_poses,
        &verifier,
        &params,
    );
    let matches: Vec<PlacementMatch> = loops
        .iter()
        .filter(|l| l.score * l.confidence > tracking.placement_margin)
        .filter_map(|l| {
            let (query, view) = (l.a.0 as usize, l.b.0 as usize);
            let session_from_query = first_from_view(queries.get(query)?);
            Some(PlacementMatch {
                query,
                view,
                view_from_query: l.b_from_a,
                covariance: l.covariance,
                score: l.score,
                first_from_session: known_poses
                    .get(view)?
                    .compose(&l.b_from_a)
                    .compose(&session_from_query.inverse()),
            })
        })
        .collect();
    // Tracking from match to match (Eq. 3) chains matches that agree; farther apart along
    // the session, matches agree when they place it within r_orig of each other.
    let agree = |a: &PlacementMatch, b: &PlacementMatch| {
        let (qa, qb) = (&queries[a.query], &queries[b.query]);
        let travel_m = (qa.travel_m - qb.travel_m).abs();
        let tolerance_m = if travel_m <= tracking.placement_track_m {
            tracking.search_radius_m(travel_m)
        } else {
            tracking.base_radius_m
        };
        [qa, qb].iter().all(|q| {
            let at = first_from_view(q);
            let (pa, pb) = (
                a.first_from_session.compose(&at),
                b.first_from_session.compose(&at),
            );
            (pa.translation() - pb.translation()).norm() <= tolerance_m
        })
    };
    let mut chains = UnionFind::new(matches.len());
    for a in 0..matches.len() {
        for b in a + 1..matches.len() {
            if agree(&matches[a], &matches[b]) {
                chains.union(a, b);
            }
        }
    }
    let mut members: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for k in 0..matches.len() {
        members.entry(chains.find(k)).or_default().push(k);
    }
    let score_of = |set: &[usize]| set.iter().map(|k| matches[*k].score).sum::<f64>();
    let mut ranked_chains: Vec<Vec<usize>> = members.into_values().collect();
    ranked_chains.sort_by(|a, b| {
        b.len()
            .cmp(&a.len())
            .then(score_of(b).total_cmp(&score_of(a)))
    });
    let agreeing = ranked_chains.first()?;
    let rival_support = ranked_chains.get(1).map_or(0, Vec::len);
    let travels = agreeing.iter().map(|k| queries[matches[*k].query].travel_m);
    let spread_m =
        travels.clone().fold(f64::NEG_INFINITY, f64::max) - travels.fold(f64::INFINITY, f64::min);
    if agreeing.len() < tracking.placement_min_support
        || spread_m < tracking.placement_min_spread_m
        || (agreeing.len() as f64) < tracking.placement_rival_ratio * rival_support as f64
    {
        return None;
    }
    // The best-scored agreeing matches, a view's spacing apart, join the session.
    let mut ranked: Vec<&PlacementMatch> = agreeing.iter().map(|k| &matches[*k]).collect();
    ranked.sort_by(|a, b| b.score.total_cmp(&a.score).then(a.query.cmp(&b.query)));
    let mut joins: Vec<PlacementMatch> = Vec::new();
    for m in ranked {
        let travel_m = queries[m.query].travel_m;
        let apart = joins
            .iter()
            .all(|j| (queries[j.query].travel_m - travel_m).abs() >= tracking.placement_spacing_m);
        if apart && joins.len() < tracking.placement_max_edges.max(1) {
            joins.push(m.clone());
        }
    }
    let first_from_session = joins.first()?.first_from_session;
    Some(Placement {
        first_from_session,
        report: SessionPlacement {
            session,
            views: queries.len(),
            matches: matches.len(),
            support: agreeing.len(),
            rival_support,
            spread_m,
            edges: joins.len(),
        },
        joins,
    })
}

/// The largest eigenvalue of a vertex's marginal position covariance in the graph (m²), for
/// Eq. 3; `None` when the solver cannot give it (a singular graph).
fn position_variance_m2(graph: &PoseGraph2, vertex: NodeId) -> Option<f64> {
    let covariance = *marginal_covariances(graph, &[vertex]).ok()?.first()?;
    let (a, b, c) = (covariance[(0, 0)], covariance[(0, 1)], covariance[(1, 1)]);
    let lambda = 0.5 * (a + c) + (0.25 * (a - c).powi(2) + b * b).sqrt();
    lambda.is_finite().then_some(lambda.max(0.0))
}

/// A door a span saw and did not pass: a link-point candidate while the manager runs.
#[derive(Clone, Copy, Debug)]
struct SpanCandidate {
    /// The span (over all sessions) and its session.
    span: usize,
    session: usize,
    /// The door as the detector reported it.
    door: UnpassedDoor,
    /// The robot at the door's closest sighting, in the span's frame.
    robot_in_span: Se2,
    /// The doorway in that robot frame: centre, heading along its normal away from the robot.
    door_in_robot: Se2,
    /// … and in the span's frame.
    in_span: Se2,
    /// Whether a passing joined it.
    used: bool,
}

/// Information of the link-point edge over a leg of `leg_m` travel.
fn leg_information(tracking: &TrackingParams, leg_m: f64) -> Matrix3<f64> {
    let covariance = leg_covariance(tracking, leg_m.max(0.1));
    Matrix3::from_diagonal(&covariance.diagonal().map(|v| 1.0 / v))
}

/// Covariance of a leg of `leg_m` travel: the travel model of Eq. 3's radius.
fn leg_covariance(tracking: &TrackingParams, leg_m: f64) -> Matrix3<f64> {
    let d = leg_m.max(0.0);
    let position = tracking.variance_per_m * d + tracking.heading_variance_per_m * d.powi(3) / 3.0;
    let heading = tracking.heading_variance_per_m * d;
    Matrix3::from_diagonal(&Vector3::new(position, position, heading))
}

/// Information of a closure: its verification's covariance with 5 cm and 1° floors.
fn closure_information(covariance: &Matrix3<f64>) -> Matrix3<f64> {
    let floor = Matrix3::from_diagonal(&Vector3::new(
        0.05f64.powi(2),
        0.05f64.powi(2),
        1f64.to_radians().powi(2),
    ));
    (covariance + floor)
        .try_inverse()
        .unwrap_or_else(|| floor.try_inverse().unwrap_or_else(Matrix3::identity))
}

/// The local map at a crossing: the scans of a span (`span`, its `trajectory`, the log's
/// `scans`) within `local_map_m` of scan `c`, in the robot frame at `c` (`map_from_crossing`
/// in the span's frame), with their rays.
fn local_map(
    c: usize,
    map_from_crossing: &Se2,
    span: &AreaSpan,
    trajectory: &[Se2],
    scans: &[&LaserScan],
    tracking: &TrackingParams,
) -> Keyframe {
    let range = &span.scans;
    let crossing_from_map = map_from_crossing.inverse();
    let mut points = Vec::new();
    let mut rays = Vec::new();
    let filter = BeamFilter::default();
    let Some(at_crossing) = c.checked_sub(range.start).and_then(|k| trajectory.get(k)) else {
        return Keyframe::new(c as u64, points);
    };
    for k in range.clone() {
        let (Some(pose), Some(scan)) = (trajectory.get(k - range.start), scans.get(k)) else {
            continue;
        };
        if (pose.translation() - at_crossing.translation()).norm() > tracking.local_map_m {
            continue;
        }
        let crossing_from_robot = crossing_from_map.compose(pose);
        let origin = crossing_from_robot.translation();
        for p in scan.points_in_robot(&filter) {
            let q = crossing_from_robot.transform_point(&p);
            points.push(q);
            rays.push((origin, q));
        }
    }
    let points = voxel_downsample(&points, 0.05);
    Keyframe::new(c as u64, points).with_rays(0.1, rays)
}

/// Union–find over spans.
struct UnionFind {
    parent: Vec<usize>,
}

impl UnionFind {
    fn new(n: usize) -> Self {
        Self {
            parent: (0..n).collect(),
        }
    }

    fn find(&mut self, k: usize) -> usize {
        let mut root = k;
        while let Some(&p) = self.parent.get(root) {
            if p == root {
                break;
            }
            root = p;
        }
        // Path compression.
        let mut k = k;
        while let Some(&p) = self.parent.get(k) {
            if p == root {
                break;
            }
            self.parent[k] = root;
            k = p;
        }
        root
    }

    fn union(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            // The earlier span's root stays, so an area's first span is its root.
            let (keep, other) = if ra < rb { (ra, rb) } else { (rb, ra) };
            self.parent[other] = keep;
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use mapmerge_place::PlaceVerifierParams;
    use mapmerge_sim::{simulate, SessionData, SimParams};

    use super::*;

    #[test]
    fn manager_parameters_out_of_range_are_refused_with_their_path() {
        assert_eq!(Validate::validate(&ManagerParams::default()), Ok(()));
        let field = |params: &ManagerParams| Validate::validate(params).map_err(|e| e.field);
        let radius = ManagerParams {
            tracking: TrackingParams {
                base_radius_m: -1.0,
                ..TrackingParams::default()
            },
            ..ManagerParams::default()
        };
        assert_eq!(field(&radius), Err("tracking.base_radius_m".into()));
        // Segmenting refuses them too.
        let scans = std::iter::empty::<(Se2, &LaserScan)>();
        assert!(matches!(
            segment(scans, &radius),
            Err(AreasError::Params(ref e)) if e.field == "tracking.base_radius_m"
        ));
        let mut params = ManagerParams::default();
        params.tracking.placement_max_edges = usize::MAX;
        assert_eq!(field(&params), Err("tracking.placement_max_edges".into()));
        let mut params = ManagerParams::default();
        params.tracking.min_score = 1.5;
        assert_eq!(field(&params), Err("tracking.min_score".into()));
        let mut params = ManagerParams::default();
        params.doors.match_m = -0.5;
        assert_eq!(field(&params), Err("doors.match_m".into()));
        let mut params = ManagerParams::default();
        params.doors.environment.far_m = f64::INFINITY;
        assert_eq!(field(&params), Err("doors.environment.far_m".into()));
        let scans = ManagerParams {
            min_area_scans: usize::MAX,
            ..ManagerParams::default()
        };
        assert_eq!(field(&scans), Err("min_area_scans".into()));
    }

    /// Each span mapped by the true poses, in a frame of its own (its first pose).
    fn true_trajectories(split: &Segmentation, session: &SessionData) -> Vec<Vec<Se2>> {
        split
            .spans
            .iter()
            .map(|span| {
                let origin = session.truth[span.scans.start].1;
                span.scans
                    .clone()
                    .map(|k| origin.inverse().compose(&session.truth[k].1))
                    .collect()
            })
            .collect()
    }

    #[test]
    fn a_simulated_session_splits_at_its_doors_and_chains_back_together() {
        let sim = SimParams::default()
            .with_preset_name("office")
            .unwrap()
            .with_sessions(1)
            .with_duration_secs(120.0);
        let data = simulate(&sim, 1).unwrap();
        let session = &data.sessions[0];
        let scans = session
            .log
            .scans
            .iter()
            .map(|r| (r.odom_from_robot.unwrap(), &r.scan));
        let params = ManagerParams::default();
        let split = segment(scans, &params).unwrap();
        assert!(split.spans.len() >= 3, "{} areas", split.spans.len());
        assert_eq!(split.spans.len(), split.boundaries.len() + 1);
        for pair in split.spans.windows(2) {
            assert!(
                pair[1].scans.start < pair[0].scans.end,
                "adjacent maps overlap"
            );
        }
        assert_eq!(split.spans.first().unwrap().scans.start, 0);
        assert_eq!(
            split.spans.last().unwrap().scans.end,
            session.log.scans.len()
        );
        // Each area mapped by the true poses in a frame of its own (its first pose): the chain
        // through the link points must put every area back where the truth has it.
        let trajectories = true_trajectories(&split, session);
        let scans: Vec<&LaserScan> = session.log.scans.iter().map(|r| &r.scan).collect();
        let verifier = PlaceVerifierParams::default().verifier().unwrap();
        let managed = manage(&split, &trajectories, &scans, &params, &verifier).unwrap();
        let world_from_first = session.truth[0].1;
        for (k, span) in split.spans.iter().enumerate() {
            let world_from_span = session.truth[span.scans.start].1;
            let error = world_from_first
                .compose(&managed.first_from_span[k])
                .between(&world_from_span);
            assert!(error.translation().norm() < 0.05, "span {k}: {error:?}");
        }
        // Every closure joins two passings of one true door.
        let nearest_door = |p: Point2| {
            session
                .world
                .doors
                .iter()
                .min_by(|x, y| (x.center_m - p).norm().total_cmp(&(y.center_m - p).norm()))
                .map(|d| d.id)
        };
        let door_at = |b: usize| {
            let c = split.passings[split.boundaries[b]].crossing_scan;
            nearest_door(session.truth[c].1.translation())
        };
        for closure in &managed.closures {
            assert_eq!(
                door_at(closure.boundary),
                door_at(closure.earlier),
                "{closure:?}"
            );
        }
        // Every closure at a link-point candidate passes the door that was seen.
        for closure in &managed.candidate_closures {
            let seen = session.truth[closure.door.scan]
                .1
                .transform_point(&closure.door.center_in_robot_m());
            assert_eq!(nearest_door(seen), door_at(closure.boundary), "{closure:?}");
        }
        // Doors seen but not passed are candidates, each in an area of the map.
        assert!(!split.unpassed.is_empty());
        for candidate in &managed.hybrid.candidates {
            assert!(candidate.area < managed.hybrid.areas.len());
        }
        assert!(managed.hybrid.areas.len() <= split.spans.len());
        assert_eq!(managed.span_area.len(), split.spans.len());
        assert!(manage(&split, &trajectories[1..], &scans, &params, &verifier).is_err());
    }

    /// Two simulated sessions (of `worlds`, seed `seed`), split at their doors and mapped by
    /// the true poses.
    type Sessions = (Vec<SessionData>, Vec<Segmentation>, Vec<Vec<Vec<Se2>>>);

    fn sessions_of(worlds: &[(&str, u64)], params: &ManagerParams) -> Sessions {
        let mut data = Vec::new();
        for (world, seed) in worlds {
            let mut sim = SimParams::default()
                .with_preset_name(world)
                .unwrap()
                .with_sessions(2)
                .with_duration_secs(300.0);
            sim.kidnap.max_per_session = 0;
            let simulated = simulate(&sim, *seed).unwrap();
            data.push(simulated.sessions[data.len()].clone());
        }
        let mut splits = Vec::new();
        let mut trajectories = Vec::new();
        for session in &data {
            let split = segment(
                session
                    .log
                    .scans
                    .iter()
                    .map(|r| (r.odom_from_robot.unwrap(), &r.scan)),
                params,
            )
            .unwrap();
            trajectories.push(true_trajectories(&split, session));
            splits.push(split);
        }
        (data, splits, trajectories)
    }

    fn manage_all(
        data: &[SessionData],
        splits: &[Segmentation],
        trajectories: &[Vec<Vec<Se2>>],
        params: &ManagerParams,
    ) -> ManagedMap {
        let scans: Vec<Vec<&LaserScan>> = data
            .iter()
            .map(|session| session.log.scans.iter().map(|r| &r.scan).collect())
            .collect();
        let inputs: Vec<SessionInput> = (0..data.len())
            .map(|s| SessionInput {
                segmentation: &splits[s],
                trajectories: &trajectories[s],
                scans: &scans[s],
            })
            .collect();
        let verifier = PlaceVerifierParams::default().verifier().unwrap();
        manage_sessions(&inputs, params, &verifier).unwrap()
    }

    /// Whether every span of every placed session lies within 0.1 m of the truth.
    fn spans_where_the_truth_puts_them(
        data: &[SessionData],
        splits: &[Segmentation],
        managed: &ManagedMap,
    ) {
        let world_from_first = data[0].truth[0].1;
        let mut g = 0;
        for (s, split) in splits.iter().enumerate() {
            for span in &split.spans {
                let world_from_span = data[s].truth[span.scans.start].1;
                let error = world_from_first
                    .compose(&managed.first_from_span[g])
                    .between(&world_from_span);
                assert!(
                    error.translation().norm() < 0.1,
                    "session {s} span {g}: {error:?}"
                );
                g += 1;
            }
        }
    }

    #[test]
    fn a_second_session_is_placed_by_the_global_search_and_shares_areas() {
        let params = ManagerParams::default();
        let (data, splits, trajectories) = sessions_of(&[("office", 2), ("office", 2)], &params);
        let managed = manage_all(&data, &splits, &trajectories, &params);
        assert_eq!(managed.session_placed, vec![true, true], "session 1 placed");
        let placement = &managed.placements[0];
        assert_eq!(placement.session, 1);
        assert!(
            placement.support >= 2 && placement.edges >= 2,
            "{placement:?}"
        );
        spans_where_the_truth_puts_them(&data, &splits, &managed);
        // Some area holds spans of both sessions.
        let shared = (0..managed.hybrid.areas.len()).any(|a| {
            let sessions: Vec<usize> = managed
                .span_area
                .iter()
                .zip(&managed.span_session)
                .filter(|(x, _)| **x == a)
                .map(|(_, s)| *s)
                .collect();
            sessions.contains(&0) && sessions.contains(&1)
        });
        assert!(shared);
    }

    #[test]
    fn a_session_that_passes_no_door_is_placed_all_the_same() {
        let params = ManagerParams::default();
        let (data, mut splits, mut trajectories) =
            sessions_of(&[("office", 2), ("office", 2)], &params);
        // Session 1 as one span: no passing, no boundary, no door to relocalise at.
        let n = data[1].log.scans.len();
        splits[1] = Segmentation {
            passings: Vec::new(),
            spans: vec![AreaSpan {
                scans: 0..n,
                environment: Environment::Indoor,
            }],
            boundaries: Vec::new(),
            unpassed: Vec::new(),
        };
        trajectories[1] = true_trajectories(&splits[1], &data[1]);
        let managed = manage_all(&data, &splits, &trajectories, &params);
        assert_eq!(managed.session_placed, vec![true, true]);
        spans_where_the_truth_puts_them(&data, &splits, &managed);
    }

    #[test]
    fn a_session_of_another_building_is_left_unplaced() {
        let params = ManagerParams::default();
        let (data, splits, trajectories) =
            sessions_of(&[("office", 2), ("corridor-loop", 5)], &params);
        let managed = manage_all(&data, &splits, &trajectories, &params);
        assert_eq!(managed.session_placed, vec![true, false]);
        assert!(managed.placements.is_empty());
        // Its areas are its own.
        let (first, second): (Vec<_>, Vec<_>) = managed
            .span_area
            .iter()
            .zip(&managed.span_session)
            .partition(|(_, s)| **s == 0);
        assert!(first
            .iter()
            .all(|(a, _)| second.iter().all(|(b, _)| a != b)));
    }

    #[test]
    fn eq_3_radius_follows_the_marginal_covariance_of_the_chain_and_shrinks_at_a_closure() {
        let tracking = TrackingParams {
            heading_variance_per_m: 1e-12,
            ..TrackingParams::default()
        };
        let mut graph = PoseGraph2::new();
        let fixed = Vertex {
            pose: Se2::identity(),
            fixed: true,
            meta: Default::default(),
        };
        graph.add_vertex(NodeId(0), fixed).unwrap();
        let legs_m = [3.0, 4.0, 5.0];
        let mut x = 0.0;
        for (k, leg) in legs_m.iter().enumerate() {
            x += leg;
            graph
                .add_vertex(NodeId(k as u64 + 1), Vertex::new(Se2::new(x, 0.0, 0.0)))
                .unwrap();
            graph
                .add_edge(Edge {
                    from: NodeId(k as u64),
                    to: NodeId(k as u64 + 1),
                    measurement: Se2::new(*leg, 0.0, 0.0),
                    information: leg_information(&tracking, *leg),
                    kind: EdgeKind::Odometry,
                })
                .unwrap();
        }
        let last = NodeId(legs_m.len() as u64);
        let chain = position_variance_m2(&graph, last).unwrap();
        let travel_m: f64 = legs_m.iter().sum();
        let expected = tracking.search_radius_m(travel_m);
        assert!(
            (tracking.radius_for_variance_m(chain) - expected).abs() < 1e-6,
            "{chain} against {expected}"
        );
        // A closure to the origin makes the last crossing surer.
        graph
            .add_edge(Edge {
                from: NodeId(0),
                to: last,
                measurement: Se2::new(x, 0.0, 0.0),
                information: closure_information(&Matrix3::zeros()),
                kind: EdgeKind::Loop,
            })
            .unwrap();
        let closed = position_variance_m2(&graph, last).unwrap();
        // The closure's 5 cm floor in parallel with the chain.
        let expected = 1.0 / (1.0 / chain + 1.0 / 0.05f64.powi(2));
        assert!(
            (closed - expected).abs() < 1e-6,
            "{closed} against {expected}"
        );
        assert!(tracking.radius_for_variance_m(closed) < tracking.radius_for_variance_m(chain));
    }
}
