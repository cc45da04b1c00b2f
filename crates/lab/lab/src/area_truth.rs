//! Door detection scored against the simulator's doors: every session of a simulated data set
//! is run through a [`DoorDetector`] on its odometry poses, as a robot would, and each
//! detection is placed in the world by the true pose of its scan. A detection is true when it
//! lies within `max_distance_m` of the centre of a door the true path crossed within
//! `max_scan_gap` scans of the detection's crossing; each true passing matches at most one
//! detection.

use std::time::Instant;

use mapmerge_scan::Point2;
use mapmerge_sim::{simulate, SessionData, SimParams};
use serde::{Deserialize, Serialize};

use mapmerge_areas::{
    Criteria, DoorDetector, DoorParams, DoorPassingDetection, ManagedMap, ManagerParams, MapSpan,
    MappedSession, Segmentation,
};

/// How detections are matched to the truth.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DoorScoring {
    /// Largest distance of a detection from the true door's centre (m) (default: 1, the
    /// issue's).
    pub max_distance_m: f64,
    /// Largest gap between the detected and the true crossing (scans) (default: 20, 2 s of
    /// the simulator's scans).
    pub max_scan_gap: usize,
}

impl Default for DoorScoring {
    fn default() -> Self {
        Self {
            max_distance_m: 1.0,
            max_scan_gap: 20,
        }
    }
}

/// Counts of one run or of many.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DoorCounts {
    /// True door passings.
    pub passings: usize,
    /// Detections.
    pub detections: usize,
    /// Detections matched to a true passing.
    pub true_detections: usize,
    /// Detections by how many criteria held: 2 or 3.
    pub with_two_criteria: usize,
    /// …
    pub with_three_criteria: usize,
    /// Scans run through the detector.
    pub scans: usize,
    /// Time in the detector (s).
    pub seconds: f64,
}

impl DoorCounts {
    /// Matched detections over detections (1 without detections).
    pub fn precision(&self) -> f64 {
        ratio(self.true_detections, self.detections)
    }

    /// Matched passings over passings (1 without passings).
    pub fn recall(&self) -> f64 {
        ratio(self.true_detections, self.passings)
    }

    /// Milliseconds per scan in the detector.
    pub fn ms_per_scan(&self) -> f64 {
        1e3 * self.seconds / self.scans.max(1) as f64
    }

    /// Adds `other`'s counts to these.
    pub fn add(&mut self, other: &DoorCounts) {
        self.passings += other.passings;
        self.detections += other.detections;
        self.true_detections += other.true_detections;
        self.with_two_criteria += other.with_two_criteria;
        self.with_three_criteria += other.with_three_criteria;
        self.scans += other.scans;
        self.seconds += other.seconds;
    }
}

fn ratio(a: usize, b: usize) -> f64 {
    if b == 0 {
        1.0
    } else {
        a as f64 / b as f64
    }
}

/// One world and seed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DoorRun {
    /// The world.
    pub world: String,
    /// The seed.
    pub seed: u64,
    /// Its counts.
    pub counts: DoorCounts,
    /// Detections that matched no passing, for looking at.
    pub false_detections: Vec<FalseDetection>,
    /// Passings no detection matched: session, scan, door.
    pub missed: Vec<(usize, usize, u32)>,
}

/// A detection that matched no true passing.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FalseDetection {
    /// The session.
    pub session: usize,
    /// The scan of its crossing.
    pub scan: usize,
    /// Where it was placed (world frame, m).
    pub position_m: [f64; 2],
    /// The criteria that held.
    pub criteria: Criteria,
    /// Distance to the nearest door (m).
    pub nearest_door_m: f64,
    /// Scans to the nearest true passing (none without passings).
    pub nearest_passing_scans: Option<usize>,
}

/// A whole evaluation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DoorReport {
    /// Every world and seed.
    pub runs: Vec<DoorRun>,
    /// Their sum.
    pub total: DoorCounts,
    /// Precision of the sum.
    pub precision: f64,
    /// Recall of the sum.
    pub recall: f64,
    /// Milliseconds per scan in the detector.
    pub ms_per_scan: f64,
}

/// A true door passing the detector missed: (session, scan, door id).
pub type MissedPassing = (usize, usize, u32);

/// Scores one session: runs the detector and matches its detections.
pub fn score_session(
    session: &SessionData,
    params: &DoorParams,
    scoring: &DoorScoring,
) -> Result<(DoorCounts, Vec<FalseDetection>, Vec<MissedPassing>), anyhow::Error> {
    let mut detector = DoorDetector::new(params.clone())?;
    let mut detections: Vec<DoorPassingDetection> = Vec::new();
    let started = Instant::now();
    for record in &session.log.scans {
        // Scans without an odometry pose cannot be placed; the simulator gives every one.
        let Some(pose) = record.odom_from_robot else {
            continue;
        };
        if let Some(found) = detector.push(&pose, &record.scan) {
            detections.push(found);
        }
    }
    let seconds = started.elapsed().as_secs_f64();
    let passings: Vec<_> = session
        .door_passings()
        .into_iter()
        .filter_map(|p| Some((p, session.world.door(p.door)?.center_m)))
        .collect();
    let (_, placed, matched) = place_and_match(&detections, session, scoring);
    let mut counts = DoorCounts {
        passings: passings.len(),
        detections: detections.len(),
        true_detections: matched.iter().filter(|m| m.is_some()).count(),
        scans: detector.scans(),
        seconds,
        ..DoorCounts::default()
    };
    for d in &detections {
        match d.criteria.count() {
            3 => counts.with_three_criteria += 1,
            _ => counts.with_two_criteria += 1,
        }
    }
    let false_detections = placed
        .iter()
        .zip(&detections)
        .zip(&matched)
        .filter(|(_, m)| m.is_none())
        .map(|(((scan, p), d), _)| FalseDetection {
            session: session.index,
            scan: *scan,
            position_m: [p.x, p.y],
            criteria: d.criteria,
            nearest_door_m: session
                .world
                .doors
                .iter()
                .map(|door| (door.center_m - p).norm())
                .fold(f64::INFINITY, f64::min),
            nearest_passing_scans: passings.iter().map(|(p, _)| p.scan.abs_diff(*scan)).min(),
        })
        .collect();
    let mut missed: Vec<MissedPassing> = passings
        .iter()
        .enumerate()
        .filter(|(t, _)| !matched.contains(&Some(*t)))
        .map(|(_, (p, _))| (session.index, p.scan, p.door.0))
        .collect();
    missed.sort_unstable();
    Ok((counts, false_detections, missed))
}

/// For each detection `(crossing scan, world position)`, the index of the true passing
/// `(scan, door centre)` it matches: greedily, closest in scans first, one to one.
pub fn match_detections(
    detections: &[(usize, Point2)],
    truth: &[(usize, Point2)],
    scoring: &DoorScoring,
) -> Vec<Option<usize>> {
    let mut pairs: Vec<(usize, usize, usize)> = Vec::new();
    for (d, (scan, p)) in detections.iter().enumerate() {
        for (t, (true_scan, door)) in truth.iter().enumerate() {
            let gap = scan.abs_diff(*true_scan);
            if gap <= scoring.max_scan_gap && (p - door).norm() <= scoring.max_distance_m {
                pairs.push((gap, d, t));
            }
        }
    }
    pairs.sort_unstable();
    let mut matched = vec![None; detections.len()];
    let mut taken = vec![false; truth.len()];
    for (_, d, t) in pairs {
        if matched[d].is_none() && !taken[t] {
            matched[d] = Some(t);
            taken[t] = true;
        }
    }
    matched
}

/// Simulates `sessions` sessions of `duration_secs` for each world and seed and scores door
/// detection over all of them.
pub fn evaluate(
    worlds: &[String],
    seeds: &[u64],
    sessions: usize,
    duration_secs: f64,
    params: &DoorParams,
    scoring: &DoorScoring,
) -> Result<DoorReport, anyhow::Error> {
    let mut runs = Vec::new();
    let mut total = DoorCounts::default();
    for world in worlds {
        for &seed in seeds {
            let sim = SimParams::default()
                .with_preset_name(world)?
                .with_sessions(sessions)
                .with_duration_secs(duration_secs);
            let dataset = simulate(&sim, seed)?;
            let mut counts = DoorCounts::default();
            let (mut false_detections, mut missed) = (Vec::new(), Vec::new());
            for session in &dataset.sessions {
                let (c, wrong, not_found) = score_session(session, params, scoring)?;
                counts.add(&c);
                false_detections.extend(wrong);
                missed.extend(not_found);
            }
            total.add(&counts);
            runs.push(DoorRun {
                world: world.clone(),
                seed,
                counts,
                false_detections,
                missed,
            });
        }
    }
    Ok(DoorReport {
        runs,
        precision: total.precision(),
        recall: total.recall(),
        ms_per_scan: total.ms_per_scan(),
        total,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    #[test]
    fn matching_is_one_to_one_within_distance_and_gap() {
        let truth = [(100, Point2::new(0.0, 0.0)), (300, Point2::new(5.0, 0.0))];
        let detections = [
            (104, Point2::new(0.5, 0.0)),
            (106, Point2::new(0.2, 0.0)),
            (300, Point2::new(6.5, 0.0)),
            (200, Point2::new(0.0, 0.0)),
        ];
        let matched = match_detections(&detections, &truth, &DoorScoring::default());
        assert_eq!(matched, vec![Some(0), None, None, None]);
    }
}

/// Global tracking and topological loop closure on one long simulated tour, scored by the
/// simulator's truth.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TourScore {
    /// The world.
    pub world: String,
    /// The seed.
    pub seed: u64,
    /// Sessions, and those placed in session 0's frame.
    pub sessions: usize,
    /// …
    pub sessions_placed: usize,
    /// Map boundaries (passings that started a new span).
    pub boundaries: usize,
    /// Boundaries within 1 m of a true door.
    pub at_doors: usize,
    /// Boundaries at a door an earlier boundary crossed (revisits).
    pub revisits: usize,
    /// Revisits closed with an earlier crossing of the same door.
    pub revisits_found: usize,
    /// Revisits where no earlier crossing of that door was within the search radius: the
    /// tracker had lost the robot.
    pub lost: usize,
    /// Topological loop closures.
    pub closures: usize,
    /// Closures joining crossings of two different doors, or, where a crossing is not at a
    /// door, of places more than 1 m apart.
    pub false_closures: usize,
    /// Closures where a crossing is not at a door (a doorway-like gap passed twice).
    pub closures_off_doors: usize,
    /// Closures at a link-point candidate (a door seen from another area, then passed) …
    #[serde(default)]
    pub candidate_closures: usize,
    /// … of them, where the door passed is not the door seen (or either is at no door) …
    #[serde(default)]
    pub false_candidate_closures: usize,
    /// … and where it is, but the wrong side joined the area the door was seen from.
    #[serde(default)]
    pub wrong_side_candidate_closures: usize,
    /// Link-point candidates left in the map.
    #[serde(default)]
    pub candidates: usize,
    /// Boundaries at a true door whose two sides ended in one area (a closure joined the
    /// wrong sides: one map then holds two rooms).
    #[serde(default)]
    pub doors_inside_areas: usize,
    /// RMS distance of the link-point graph's crossings from the truth after a rigid
    /// alignment (m), after optimisation …
    pub link_ate_m: f64,
    /// … and of the chain before any closure (m).
    pub chain_ate_m: f64,
    /// Areas and spans.
    pub areas: usize,
    /// …
    pub spans: usize,
    /// Each placed later session's placement error (m), see `placement_errors`…
    #[serde(default)]
    pub placement_errors_m: Vec<f64>,
    /// … and those placed where they are not: farther than `WRONG_PLACEMENT_M`.
    #[serde(default)]
    pub sessions_placed_wrongly: usize,
    /// Door passings every session detected (areas.json lists them all), scored as `eval
    /// doors` scores them.
    #[serde(default)]
    pub passings: DoorCounts,
    /// Pairs of areas of placed sessions, and those `route` joins.
    #[serde(default)]
    pub area_pairs: usize,
    /// …
    #[serde(default)]
    pub area_pairs_routed: usize,
}

/// A later session placed farther than this from where the truth puts it (m), beside session
/// 0, is placed wrongly: an aliased room or aisle is 3 m or more away in the simulator's
/// worlds; drift bends the warehouse's session maps by up to about 1.7 m.
pub const WRONG_PLACEMENT_M: f64 = 2.0;

/// Runs the map manager over `sessions` sessions of `world` (`duration_secs` each, no
/// kidnaps), mapping each span with `map_span` (scans in, `map_from_robot` per scan out), and
/// scores tracking, the placement of later sessions and the door passings of every session.
#[allow(clippy::too_many_arguments)]
pub fn score_tour(
    world: &str,
    seed: u64,
    sessions: usize,
    duration_secs: f64,
    params: &ManagerParams,
    verifier: &dyn mapmerge_place::GeometricVerifier,
    map_span: &mut MapSpan<'_>,
) -> Result<TourScore, anyhow::Error> {
    let mut sim = SimParams::default()
        .with_preset_name(world)?
        .with_sessions(sessions.max(1))
        .with_duration_secs(duration_secs);
    sim.kidnap.max_per_session = 0;
    let dataset = simulate(&sim, seed)?;
    let mapped: Vec<MappedSession> = dataset
        .sessions
        .iter()
        .enumerate()
        .map(|(s, session)| {
            mapmerge_areas::map_session(
                format!("session {s}"),
                session.log.clone(),
                params,
                map_span,
            )
        })
        .collect::<Result<_, _>>()?;
    let managed = mapmerge_areas::manage_mapped(&mapped, params, verifier)?;
    let splits: Vec<&Segmentation> = mapped.iter().map(|m| &m.segmentation).collect();
    let trajectories: Vec<&Vec<Vec<mapmerge_geometry::Se2>>> =
        mapped.iter().map(|m| &m.trajectories).collect();
    // Boundaries over all sessions, as `manage_sessions` numbers them: (session, scan).
    let boundary_scans: Vec<(usize, usize)> = splits
        .iter()
        .enumerate()
        .flat_map(|(s, split)| {
            split
                .boundaries
                .iter()
                .map(move |p| (s, split.passings[*p].crossing_scan))
        })
        .collect();
    let true_position = |b: usize| {
        let (s, scan) = *boundary_scans.get(b)?;
        Some(dataset.sessions.get(s)?.truth.get(scan)?.1.translation())
    };
    // Truth: the door within 1 m of a place, and at each boundary's crossing.
    let nearest_door = |p: mapmerge_scan::Point2| {
        dataset
            .world
            .doors
            .iter()
            .map(|d| ((d.center_m - p).norm(), d.id))
            .filter(|(d, _)| *d <= 1.0)
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, id)| id)
    };
    let doors: Vec<_> = (0..boundary_scans.len())
        .map(|b| nearest_door(true_position(b)?))
        .collect();
    let mut score = TourScore {
        world: world.to_owned(),
        seed,
        sessions: dataset.sessions.len(),
        sessions_placed: managed.session_placed.iter().filter(|p| **p).count(),
        boundaries: boundary_scans.len(),
        at_doors: doors.iter().filter(|d| d.is_some()).count(),
        closures: managed.closures.len(),
        candidate_closures: managed.candidate_closures.len(),
        candidates: managed.hybrid.candidates.len(),
        areas: managed.hybrid.areas.len(),
        spans: splits.iter().map(|s| s.spans.len()).sum(),
        ..TourScore::default()
    };
    for closure in &managed.closures {
        let (here, there) = (doors[closure.boundary], doors[closure.earlier]);
        // True: two crossings of one door, or, off doors, of one place (within 1 m).
        let same_place = match (here, there) {
            (Some(a), Some(b)) => a == b,
            _ => match (
                true_position(closure.boundary),
                true_position(closure.earlier),
            ) {
                (Some(a), Some(b)) => (a - b).norm() <= 1.0,
                _ => false,
            },
        };
        if here.is_none() || there.is_none() {
            score.closures_off_doors += 1;
        }
        if !same_place {
            score.false_closures += 1;
        }
    }
    // A candidate closure is true when the door passed is the door seen (placed by the true
    // pose of the scan that saw it).
    for closure in &managed.candidate_closures {
        let seer = dataset
            .sessions
            .get(closure.session)
            .and_then(|s| s.truth.get(closure.door.scan))
            .map(|(_, pose)| *pose);
        let seen = seer
            .and_then(|pose| nearest_door(pose.transform_point(&closure.door.center_in_robot_m())));
        let passed = doors.get(closure.boundary).copied().flatten();
        if seen.is_none() || seen != passed {
            score.false_candidate_closures += 1;
            continue;
        }
        // The side joined: the seer's side of the door is the side the robot came from when
        // the area before the crossing joined it, else the side it went to.
        let door = passed.and_then(|id| dataset.world.door(id));
        let (s, scan) = boundary_scans[closure.boundary];
        let before = dataset
            .sessions
            .get(s)
            .and_then(|session| session.truth.get(scan.saturating_sub(5)))
            .map(|(_, pose)| pose.translation());
        if let (Some(door), Some(seer), Some(before)) = (door, seer, before) {
            let side =
                |p: mapmerge_scan::Point2| (p - door.center_m).dot(&door.passage_direction()) > 0.0;
            if (side(before) == side(seer.translation())) == closure.joined_after {
                score.wrong_side_candidate_closures += 1;
            }
        }
    }
    for b in 0..doors.len() {
        let Some(door) = doors[b] else { continue };
        let earlier: Vec<usize> = (0..b).filter(|j| doors[*j] == Some(door)).collect();
        if earlier.is_empty() {
            continue;
        }
        score.revisits += 1;
        if managed
            .closures
            .iter()
            .any(|c| c.boundary == b && doors[c.earlier] == Some(door))
        {
            score.revisits_found += 1;
        }
        // Lost: no earlier crossing of the door was within the radius of the tracked one.
        let within = managed
            .tracking
            .get(b)
            .map_or(&[][..], |t| &t.within_radius[..]);
        if !earlier.iter().any(|j| within.contains(j)) {
            score.lost += 1;
        }
    }
    // Both sides of a passed door in one area.
    let mut first_span = 0usize;
    let mut b = 0usize;
    for split in &splits {
        for k in 0..split.boundaries.len() {
            let (before, after) = (first_span + k, first_span + k + 1);
            if doors.get(b).copied().flatten().is_some()
                && managed.span_area.get(before) == managed.span_area.get(after)
            {
                score.doors_inside_areas += 1;
            }
            b += 1;
        }
        first_span += split.spans.len();
    }
    // ATE over the crossings of placed sessions, in the world frame all sessions share.
    let placed_boundaries: Vec<usize> = (0..boundary_scans.len())
        .filter(|b| {
            managed
                .session_placed
                .get(boundary_scans[*b].0)
                .copied()
                .unwrap_or(false)
        })
        .collect();
    let truth: Vec<mapmerge_scan::Point2> = placed_boundaries
        .iter()
        .filter_map(|b| true_position(*b))
        .collect();
    let optimised: Vec<mapmerge_scan::Point2> = placed_boundaries
        .iter()
        .filter_map(|b| Some(managed.crossings.get(*b)?.translation()))
        .collect();
    score.link_ate_m = aligned_rms(&optimised, &truth);
    // The chain before any closure, session 0 alone (later sessions need a closure to be
    // placed at all).
    let first = splits.first();
    let chain: Vec<mapmerge_scan::Point2> = (0..first.map_or(0, |s| s.boundaries.len()))
        .filter_map(|b| Some(chain_crossing(first?, trajectories.first()?, b)?.translation()))
        .collect();
    score.chain_ate_m = aligned_rms(&chain, &truth[..chain.len().min(truth.len())]);
    score.placement_errors_m = placement_errors(&mapped, &managed, &dataset.sessions);
    score.sessions_placed_wrongly = score
        .placement_errors_m
        .iter()
        .filter(|e| **e > WRONG_PLACEMENT_M)
        .count();
    for (m, session) in mapped.iter().zip(&dataset.sessions) {
        score.passings.add(&passing_counts(
            &m.segmentation,
            session,
            &DoorScoring::default(),
        ));
    }
    let placed_areas: Vec<usize> = (0..managed.hybrid.areas.len())
        .filter(|a| {
            managed
                .span_area
                .iter()
                .zip(&managed.span_session)
                .any(|(area, s)| area == a && managed.session_placed.get(*s) == Some(&true))
        })
        .collect();
    let origin = mapmerge_scan::Point2::zeros();
    for (k, a) in placed_areas.iter().enumerate() {
        for b in &placed_areas[k + 1..] {
            score.area_pairs += 1;
            if managed.hybrid.route(*a, origin, *b, origin).is_some() {
                score.area_pairs_routed += 1;
            }
        }
    }
    Ok(score)
}

/// Door passings of a segmented session against the truth, as [`score_session`] scores a
/// detector's.
fn passing_counts(
    split: &Segmentation,
    session: &SessionData,
    scoring: &DoorScoring,
) -> DoorCounts {
    let (truth, _, matched) = place_and_match(&split.passings, session, scoring);
    DoorCounts {
        passings: truth.len(),
        detections: split.passings.len(),
        true_detections: matched.iter().filter(|m| m.is_some()).count(),
        ..DoorCounts::default()
    }
}

/// Passings as (crossing scan, door centre in the world).
type PlacedPassings = Vec<(usize, Point2)>;

/// The session's true passings (scan, door centre), each detection placed in the world by
/// the true pose of its scan (crossing scan, door centre), and the true passing it matches
/// ([`match_detections`]).
fn place_and_match(
    detections: &[DoorPassingDetection],
    session: &SessionData,
    scoring: &DoorScoring,
) -> (PlacedPassings, PlacedPassings, Vec<Option<usize>>) {
    let truth: PlacedPassings = session
        .door_passings()
        .into_iter()
        .filter_map(|p| Some((p.scan, session.world.door(p.door)?.center_m)))
        .collect();
    let placed: PlacedPassings = detections
        .iter()
        .filter_map(|d| {
            let (_, world_from_robot) = session.truth.get(d.scan)?;
            Some((
                d.crossing_scan,
                world_from_robot.transform_point(&d.center_in_robot_m),
            ))
        })
        .collect();
    let matched = match_detections(&placed, &truth, scoring);
    (truth, placed, matched)
}

/// Each placed later session's placement error (m): its frame as placed against its frame
/// as the truth has it, the median over its scans of the distance between the two places a
/// scan gets from the rigid fits of session 0's scans and of its own to the world. Drift
/// within a session goes into its fit's residuals, not into the error.
fn placement_errors(
    mapped: &[MappedSession],
    managed: &ManagedMap,
    truth: &[SessionData],
) -> Vec<f64> {
    use mapmerge_geometry::LieGroup;
    use nalgebra::Vector3;
    // Each placed session's scans: in the world, in the first frame.
    type Positions = (Vec<Vector3<f64>>, Vec<Vector3<f64>>);
    let mut scans: Vec<Positions> = vec![(Vec::new(), Vec::new()); mapped.len()];
    let mut g = 0usize;
    for (s, m) in mapped.iter().enumerate() {
        for (span, trajectory) in m.segmentation.spans.iter().zip(&m.trajectories) {
            let frame = managed.first_from_span.get(g).copied();
            g += 1;
            let (Some(frame), Some(true)) = (frame, managed.session_placed.get(s).copied()) else {
                continue;
            };
            for (scan, pose) in span.scans.clone().zip(trajectory) {
                if let Some((_, world_from_robot)) = truth.get(s).and_then(|t| t.truth.get(scan)) {
                    let (w, e) = (
                        world_from_robot.translation(),
                        frame.compose(pose).translation(),
                    );
                    scans[s].0.push(Vector3::new(w.x, w.y, 0.0));
                    scans[s].1.push(Vector3::new(e.x, e.y, 0.0));
                }
            }
        }
    }
    let fit = |(world, first): &(Vec<Vector3<f64>>, Vec<Vector3<f64>>)| {
        mapmerge_eval::align_rigid(world, first, true).ok()
    };
    let Some(world_from_first) = scans.first().and_then(fit) else {
        return Vec::new();
    };
    scans
        .iter()
        .skip(1)
        .filter_map(|session| {
            let own = fit(session)?;
            let mut errors: Vec<f64> = session
                .1
                .iter()
                .map(|e| (world_from_first.apply(e) - own.apply(e)).norm())
                .collect();
            errors.sort_by(f64::total_cmp);
            errors.get(errors.len() / 2).copied()
        })
        .collect()
}

/// Boundary `b`'s crossing by the chain of spans alone (no closure), in span 0's frame.
fn chain_crossing(
    split: &Segmentation,
    trajectories: &[Vec<mapmerge_geometry::Se2>],
    b: usize,
) -> Option<mapmerge_geometry::Se2> {
    use mapmerge_geometry::{LieGroup, Se2};
    let pose = |span: usize, scan: usize| {
        trajectories
            .get(span)?
            .get(scan.checked_sub(split.spans.get(span)?.scans.start)?)
            .copied()
    };
    let mut first_from_span = Se2::identity();
    for k in 0..=b {
        let c = split.passings.get(*split.boundaries.get(k)?)?.crossing_scan;
        let exit = pose(k, c)?;
        if k == b {
            return Some(first_from_span.compose(&exit));
        }
        let entry = pose(k + 1, c)?;
        first_from_span = first_from_span.compose(&exit).compose(&entry.inverse());
    }
    None
}

/// RMS distance between `estimate` and `truth` (paired) after the rigid motion that fits
/// them best (`mapmerge_eval`'s ATE); 0 without points.
pub fn aligned_rms(estimate: &[Point2], truth: &[Point2]) -> f64 {
    let n = estimate.len().min(truth.len());
    let poses = |points: &[Point2]| -> Vec<mapmerge_geometry::Se2> {
        points[..n]
            .iter()
            .map(|p| mapmerge_geometry::Se2::new(p.x, p.y, 0.0))
            .collect()
    };
    mapmerge_eval::absolute_trajectory_error(&poses(truth), &poses(estimate), true)
        .map_or(0.0, |error| error.rms_m)
}
