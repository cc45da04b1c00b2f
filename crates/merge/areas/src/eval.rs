//! Door detection scored against the simulator's doors (issue 18's first target): every
//! session of a simulated data set is run through a [`DoorDetector`] on its odometry poses,
//! as a robot would, and each detection is placed in the world by the true pose of its scan.
//! A detection is true when it lies within `max_distance_m` of the centre of a door the
//! true path crossed within `max_scan_gap` scans of the detection's crossing; each true
//! passing matches at most one detection.

use std::time::Instant;

use mapmerge_scan::Point2;
use mapmerge_sim::{simulate, SessionData, SimParams};
use serde::{Deserialize, Serialize};

use crate::door::{Criteria, DoorDetector, DoorParams, DoorPassingDetection};
use crate::error::AreasError;

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

    fn add(&mut self, other: &DoorCounts) {
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

/// Scores one session: runs the detector and matches its detections.
pub fn score_session(
    session: &SessionData,
    params: &DoorParams,
    scoring: &DoorScoring,
) -> Result<(DoorCounts, Vec<FalseDetection>, Vec<(usize, usize, u32)>), AreasError> {
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
    let truth: Vec<(usize, Point2)> = passings.iter().map(|(p, c)| (p.scan, *c)).collect();
    let placed: Vec<(usize, Point2)> = detections
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
    let mut counts = DoorCounts {
        passings: truth.len(),
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
            nearest_passing_scans: truth.iter().map(|(s, _)| s.abs_diff(*scan)).min(),
        })
        .collect();
    let mut missed: Vec<(usize, usize, u32)> = passings
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
) -> Result<DoorReport, AreasError> {
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
