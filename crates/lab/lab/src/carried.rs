//! A corrected log as a kidnapped robot would have recorded it: at each kidnap the robot is
//! carried from where it is to a place further along the log. The scans of the carry are
//! missing, and the wheel odometry goes on as if the robot had not moved (no jump, no reset),
//! with the seeded noise model `slam --odometry-noise` uses. The corrected pose of every kept
//! scan is the reference.

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::LaserLog;
use mapmerge_sim::{add_odometry_noise, scan_poses, seeded, uniform, OdometryNoiseProfile};

use crate::bad_input;

/// One kidnap: the robot is picked up after scan `at - 1` and put down at scan `resume` of
/// the original log (`resume > at`); scans `at..resume` are never seen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Carry {
    pub at: usize,
    pub resume: usize,
}

/// A carried log: what a kidnapped robot recorded.
pub struct CarriedLog {
    /// The kept scans with the noisy odometry as their poses.
    pub log: LaserLog,
    /// The corrected pose of every kept scan.
    pub reference: Vec<Se2>,
    /// The scans of `log` where the robot was put down (each starts a new epoch when the
    /// kidnap is announced).
    pub kidnaps: Vec<usize>,
    /// The carries, in the original log's scan numbers.
    pub carries: Vec<Carry>,
}

/// Shortest and longest carry, as shares of the log's scans.
const CARRY_SHARE: (f64, f64) = (0.05, 0.15);
/// A kidnap per this much of the log's travel (m), one to four.
const TRAVEL_PER_KIDNAP_M: f64 = 150.0;
const MAX_KIDNAPS: usize = 4;

/// Draws the carries of `log` with `seed` when `kidnap_at` is empty (one per
/// [`TRAVEL_PER_KIDNAP_M`] of travel, one to four, spread over the log), else carries from the
/// given scans; each carry skips 5–15 % of the log's scans.
pub fn draw_carries(poses: &[Se2], kidnap_at: &[usize], seed: u64) -> anyhow::Result<Vec<Carry>> {
    let n = poses.len();
    let mut rng = seeded(seed ^ 0x6b69_646e_6170);
    let mut at: Vec<usize> = if kidnap_at.is_empty() {
        let travel_m: f64 = poses
            .windows(2)
            .map(|w| w[0].between(&w[1]).translation().norm())
            .sum();
        let count = ((travel_m / TRAVEL_PER_KIDNAP_M).round() as usize).clamp(1, MAX_KIDNAPS);
        // One kidnap inside each of `count` equal stretches, away from their ends.
        (0..count)
            .map(|k| {
                let stretch = n as f64 / count as f64;
                (stretch * (k as f64 + uniform(&mut rng, 0.3, 0.6))) as usize
            })
            .collect()
    } else {
        kidnap_at.to_vec()
    };
    at.sort_unstable();
    at.dedup();
    let mut carries = Vec::with_capacity(at.len());
    let mut free_from = 1;
    for a in at {
        if a < free_from || a + 1 >= n {
            return Err(bad_input(format!(
                "a kidnap at scan {a} does not fit in {n} scans after the carries before it"
            )));
        }
        let share = uniform(&mut rng, CARRY_SHARE.0, CARRY_SHARE.1);
        let resume = (a + ((share * n as f64) as usize).max(1)).min(n - 1);
        carries.push(Carry { at: a, resume });
        free_from = resume + 1;
    }
    Ok(carries)
}

/// `log` carried at `carries`, its odometry drawn from the named noise profile with `seed`.
pub fn carried_log(
    log: &LaserLog,
    carries: &[Carry],
    noise: &str,
    seed: u64,
) -> anyhow::Result<CarriedLog> {
    let profile = OdometryNoiseProfile::from_name(noise).map_err(bad_input)?;
    let corrected = scan_poses(log).map_err(bad_input)?;
    let skipped = |k: usize| carries.iter().any(|c| (c.at..c.resume).contains(&k));
    let kept: Vec<usize> = (0..corrected.len()).filter(|&k| !skipped(k)).collect();
    // The wheels' path: every kept scan's true increment from the previous kept scan, except
    // across a carry, where the wheels did not turn.
    let mut wheels = log.clone();
    wheels.scans = kept.iter().map(|&k| log.scans[k].clone()).collect();
    let mut pose = corrected.first().copied().unwrap_or_else(Se2::identity);
    let mut kidnaps = Vec::with_capacity(carries.len());
    for (i, pair) in kept.windows(2).enumerate() {
        let (previous, k) = (pair[0], pair[1]);
        if k == previous + 1 {
            pose = pose.compose(&corrected[previous].between(&corrected[k]));
        } else {
            kidnaps.push(i + 1);
        }
        wheels.scans[i + 1].odom_from_robot = Some(pose);
    }
    if let Some(first) = wheels.scans.first_mut() {
        first.odom_from_robot = corrected.first().copied();
    }
    wheels.odometry.clear();
    let noisy = add_odometry_noise(&wheels, &profile, seed).map_err(bad_input)?;
    Ok(CarriedLog {
        log: noisy.log,
        reference: kept.iter().map(|&k| corrected[k]).collect(),
        kidnaps,
        carries: carries.to_vec(),
    })
}

/// One session per log (`(name, log)`), each carried and noised with `seed` (plus its index):
/// `kidnap_at` counts the original scans over all logs from 0, and a log without one gets its
/// kidnaps drawn ([`draw_carries`]) when `draw_kidnaps`, else none. Every session carries its
/// reference and its kidnaps.
pub fn carried_sessions(
    logs: Vec<(String, LaserLog)>,
    kidnap_at: &[usize],
    draw_kidnaps: bool,
    noise: &str,
    seed: u64,
) -> anyhow::Result<(Vec<mapmerge_jobs::AtlasSession>, Vec<Vec<Carry>>)> {
    if logs.is_empty() {
        return Err(bad_input("give one or more logs, or --sim PRESET"));
    }
    let lengths: Vec<usize> = logs.iter().map(|(_, log)| log.scans.len()).collect();
    let kidnaps = mapmerge_jobs::kidnaps_per_log(kidnap_at, &lengths).map_err(crate::job_error)?;
    let mut sessions = Vec::with_capacity(logs.len());
    let mut all_carries = Vec::with_capacity(logs.len());
    for (k, ((name, log), here)) in logs.into_iter().zip(kidnaps).enumerate() {
        let session_seed = seed.wrapping_add(k as u64);
        let poses = scan_poses(&log).map_err(bad_input)?;
        let carries = if here.is_empty() && !draw_kidnaps {
            Vec::new()
        } else {
            draw_carries(&poses, &here, session_seed)
                .map_err(|e| bad_input(format!("{name}: {e}")))?
        };
        let carried = carried_log(&log, &carries, noise, session_seed)?;
        sessions.push(mapmerge_jobs::AtlasSession {
            name,
            log: carried.log,
            kidnaps: carried.kidnaps,
            reference: Some(carried.reference),
        });
        all_carries.push(carries);
    }
    Ok((sessions, all_carries))
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapmerge_scan::{LaserScan, ScanRecord};

    fn straight_log(n: usize) -> LaserLog {
        let mut log = LaserLog::default();
        for k in 0..n {
            log.scans.push(ScanRecord {
                stamp_secs: k as f64,
                odom_from_robot: Some(Se2::new(0.1 * k as f64, 0.0, 0.0)),
                scan: LaserScan {
                    angle_min_rad: 0.0,
                    angle_increment_rad: 0.1,
                    range_min_m: 0.0,
                    range_max_m: 10.0,
                    ranges_m: vec![1.0; 4],
                    robot_from_sensor: Se2::identity(),
                },
                source_tag: String::new(),
            });
        }
        log
    }

    #[test]
    fn a_carried_robot_loses_the_carry_and_its_odometry_does_not_jump() {
        let log = straight_log(1000);
        let carries = [Carry {
            at: 400,
            resume: 500,
        }];
        let carried = carried_log(&log, &carries, "none", 1).unwrap();
        assert_eq!(carried.log.scans.len(), 900);
        assert_eq!(carried.kidnaps, vec![400]);
        // The reference jumps 10 m across the carry; the odometry moves one step less than a
        // normal increment: not at all.
        let odometry = |k: usize| carried.log.scans[k].odom_from_robot.unwrap();
        assert!((carried.reference[400].x_m - carried.reference[399].x_m - 10.1).abs() < 1e-9);
        assert!(odometry(400).between(&odometry(399)).translation().norm() < 1e-9);
        assert!((odometry(401).x_m - odometry(400).x_m - 0.1).abs() < 1e-9);
        assert!((odometry(899).x_m - 89.8).abs() < 1e-6);
    }

    #[test]
    fn carries_are_drawn_by_travel_and_refused_when_they_overlap() {
        let poses: Vec<Se2> = (0..3000)
            .map(|k| Se2::new(0.2 * k as f64, 0.0, 0.0))
            .collect();
        // 600 m of travel: four kidnaps, each carry 5–15 % of the scans, in order.
        let carries = draw_carries(&poses, &[], 3).unwrap();
        assert_eq!(carries.len(), 4);
        for pair in carries.windows(2) {
            assert!(pair[0].resume < pair[1].at, "{carries:?}");
        }
        for c in &carries {
            assert!((150..=450).contains(&(c.resume - c.at)), "{c:?}");
        }
        assert_eq!(draw_carries(&poses, &[], 3).unwrap(), carries);
        assert!(draw_carries(&poses, &[100, 110], 3).is_err());
        assert!(draw_carries(&poses, &[2999], 3).is_err());
    }
}
