//! Epoch breaks judged against the true kidnaps (issue 65): a kidnap is found by the first
//! `tracking_lost` break whose scans in doubt start no earlier than [`DOUBT_BEFORE_SCANS`]
//! before it and before the next kidnap or the session's end; it is detected when that break
//! was decided no later than [`DETECT_WITHIN_SCANS`] scans after it, late otherwise. Every
//! other `tracking_lost` break is a false one. Travel is the reference path's,
//! carries left out, so false breaks are counted per distance actually driven.

use mapmerge_engine::{Decision, EngineEvent, EventKind};
use mapmerge_jobs::AtlasSession;
use serde::Serialize;

/// A kidnap counts as detected when the engine decided it was lost within this many scans
/// of it (the target) …
pub const DETECT_WITHIN_SCANS: usize = 10;
/// … with its scans in doubt starting at most this many scans before it (a doubt opened by
/// the scan before the carry).
pub const DOUBT_BEFORE_SCANS: usize = 2;

/// Kidnaps found and breaks made, over one run or many.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct BreakJudgement {
    /// True kidnaps.
    pub kidnaps: usize,
    /// Of those, detected within [`DETECT_WITHIN_SCANS`], and found later.
    pub detected: usize,
    pub late: usize,
    /// `tracking_lost` breaks that match no kidnap.
    pub false_breaks: usize,
    /// Reference travel (m), carries left out.
    pub travel_m: f64,
    /// Scans from each kidnap found (in time or late) to the decision.
    pub delays_scans: Vec<usize>,
}

impl BreakJudgement {
    /// Adds another run's counts.
    pub fn add(&mut self, other: &Self) {
        self.kidnaps += other.kidnaps;
        self.detected += other.detected;
        self.late += other.late;
        self.false_breaks += other.false_breaks;
        self.travel_m += other.travel_m;
        self.delays_scans.extend(&other.delays_scans);
    }

    /// False breaks per 500 m of travel (the unit); none without travel.
    pub fn false_per_500_m(&self) -> Option<f64> {
        (self.travel_m > 0.0).then(|| 500.0 * self.false_breaks as f64 / self.travel_m)
    }
}

/// Judges the `tracking_lost` decisions of `events` (scans counted over `sessions` in order)
/// against each session's kidnaps; travel from each session's reference, when it has one.
pub fn judge_breaks(events: &[EngineEvent], sessions: &[AtlasSession]) -> BreakJudgement {
    // Each kidnap with the scan its segment ends at (the next kidnap or the session's end).
    let mut kidnaps: Vec<(usize, usize)> = Vec::new();
    let mut judgement = BreakJudgement::default();
    let mut start = 0;
    for session in sessions {
        let end = start + session.log.scans.len();
        let mut sorted = session.kidnaps.clone();
        sorted.sort_unstable();
        for (i, k) in sorted.iter().enumerate() {
            let until = sorted.get(i + 1).map_or(end, |next| start + next);
            kidnaps.push((start + k, until));
        }
        start = end;
        if let Some(reference) = &session.reference {
            judgement.travel_m += reference
                .windows(2)
                .enumerate()
                .filter(|(i, _)| !session.kidnaps.contains(&(i + 1)))
                .map(|(_, w)| (w[1].translation() - w[0].translation()).norm())
                .sum::<f64>();
        }
    }
    judgement.kidnaps = kidnaps.len();
    // Each break: the first scan in doubt and the scan that decided.
    let breaks: Vec<(usize, usize)> = events
        .iter()
        .filter_map(|e| match &e.event {
            EventKind::Decision(Decision::TrackingLost { in_doubt, .. }) => {
                Some((e.scan, e.scan + in_doubt.len().saturating_sub(1)))
            }
            _ => None,
        })
        .collect();
    let mut matched = vec![false; breaks.len()];
    for (kidnap, until) in kidnaps {
        let hit = breaks.iter().enumerate().find(|(i, (first, _))| {
            !matched[*i] && *first + DOUBT_BEFORE_SCANS >= kidnap && *first < until
        });
        if let Some((i, (_, decided))) = hit {
            matched[i] = true;
            let delay = decided.saturating_sub(kidnap);
            if delay <= DETECT_WITHIN_SCANS {
                judgement.detected += 1;
            } else {
                judgement.late += 1;
            }
            judgement.delays_scans.push(delay);
        }
    }
    judgement.false_breaks = matched.iter().filter(|m| !**m).count();
    judgement
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapmerge_geometry::LieGroup;
    use mapmerge_geometry::Se2;
    use mapmerge_scan::{LaserLog, LaserScan, ScanRecord};
    use mapmerge_slam::{LostCause, ReadScan, TrackingReading};

    fn session(scans: usize, kidnaps: Vec<usize>) -> AtlasSession {
        let log = LaserLog {
            scans: (0..scans)
                .map(|k| ScanRecord {
                    stamp_secs: k as f64,
                    odom_from_robot: None,
                    scan: LaserScan {
                        angle_min_rad: 0.0,
                        angle_increment_rad: 0.1,
                        range_min_m: 0.0,
                        range_max_m: 10.0,
                        ranges_m: Vec::new(),
                        robot_from_sensor: Se2::identity(),
                    },
                    source_tag: String::new(),
                })
                .collect(),
            ..LaserLog::default()
        };
        AtlasSession {
            name: "s".into(),
            log,
            reference: Some((0..scans).map(|k| Se2::new(k as f64, 0.0, 0.0)).collect()),
            kidnaps,
        }
    }

    fn lost_at(scan: usize, in_doubt: usize) -> EngineEvent {
        let read = ReadScan {
            reading: TrackingReading::default(),
            stamp_gap_s: None,
            off: None,
        };
        EngineEvent {
            scan,
            travel_m: 0.0,
            event: EventKind::Decision(Decision::TrackingLost {
                cause: LostCause::OffReadings,
                in_doubt: vec![read; in_doubt],
            }),
        }
    }

    #[test]
    fn breaks_near_kidnaps_detect_them_and_the_rest_are_false() {
        // Two sessions: kidnaps at 40 and (second session) 100 + 30.
        let sessions = [session(100, vec![40]), session(100, vec![30])];
        let events = [
            lost_at(20, 2),  // before the first kidnap: false
            lost_at(41, 3),  // decided at 43: detected, 3 scans after it
            lost_at(70, 1),  // a second break in the same segment: false
            lost_at(135, 8), // decided at 142 > 130 + 10: found late
        ];
        let judged = judge_breaks(&events, &sessions);
        assert_eq!(judged.kidnaps, 2);
        assert_eq!((judged.detected, judged.late), (1, 1));
        assert_eq!(judged.delays_scans, vec![3, 12]);
        assert_eq!(judged.false_breaks, 2);
        // 99 + 99 steps of 1 m, less the two carries' jumps.
        assert!((judged.travel_m - 196.0).abs() < 1e-9);
        assert!((judged.false_per_500_m().unwrap_or_default() - 500.0 * 2.0 / 196.0).abs() < 1e-9);
    }
}
