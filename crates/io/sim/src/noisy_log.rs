//! Wheel odometry for *corrected* laser logs: the simulator's odometry model (`odometry.rs`)
//! applied to a log's increments, with slips over wheel travel.
//!
//! The public corrected CARMEN logs carry the corrected (scan-matched) pose in every scan's
//! odometry field, so a SLAM front-end fed with them would be handed the answer. To evaluate a
//! front-end, each scan's pose is replaced by a simulated wheel odometry that drifts: the
//! increment between consecutive scan poses, `u_k = x_k⁻¹ · x_{k+1}` (in the robot frame of scan
//! `k`), is corrupted and the noisy increments are chained from the first corrected pose.
//!
//! The corrected logs keep scans at very different spacings (the filter that produced them only
//! integrated some), which the model's density form absorbs: a per-scan noise would punish
//! densely sampled logs. Slip events are scheduled over wheel travel, since several logs'
//! stamps are broken; an event scales every increment that starts inside it.
//!
//! Everything is drawn from ChaCha8 seeded with the caller's seed, in scan order, so a seed
//! reproduces the same noisy log on every platform.

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::{LaserLog, OdometryReading};
use serde::{Deserialize, Serialize};

use crate::odometry::{
    schedule_slips_by_travel, Draws, SessionNoise, SlipCursor, SlipEvent, SlipSchedule, SlipSpan,
};
use crate::rng::seeded;
use crate::{OdometryNoiseParams, SimError};

/// Half the track of the assumed differential-drive robot (m): turning by `a` rad rolls each
/// wheel `0.25 · a` m, which is what slip events are scheduled over together with the distance.
const HALF_TRACK_M: f64 = 0.25;

/// The names [`OdometryNoiseProfile::from_name`] knows.
pub const NOISE_PROFILE_NAMES: [&str; 3] = ["default", "harsh", "none"];

/// The corrected logs' named odometry noise: `default`, `harsh` and `none`
/// ([`NOISE_PROFILE_NAMES`]). Each is an [`OdometryNoiseParams`] with slips over wheel travel;
/// this type only names them (it has no values).
#[derive(Clone, Copy, Debug)]
pub enum OdometryNoiseProfile {}

impl OdometryNoiseProfile {
    /// The `default` profile: σ_t 0.03 m/√m (3 cm after 1 m, 0.3 m after 100 m), σ_ra
    /// 0.03 rad/√rad, σ_rd 0.01 rad/√m (5.7° after 100 m straight), scale σ 0.005 / 0.005,
    /// 1 slip per 100 m of wheel travel, 0.5–2 m long, `m` in 0.2–0.5.
    #[allow(clippy::should_implement_trait)] // the `default` profile, an `OdometryNoiseParams`
    pub fn default() -> OdometryNoiseParams {
        OdometryNoiseParams {
            translation_sigma_per_sqrt_m: 0.03,
            rotation_sigma_per_sqrt_rad: 0.03,
            rotation_sigma_per_sqrt_m: 0.01,
            translation_scale_sigma: 0.005,
            rotation_scale_sigma: 0.005,
            slip_schedule: SlipSchedule::ByTravel {
                rate_per_100m: 1.0,
                length_min_m: 0.5,
                length_max_m: 2.0,
            },
            slip_magnitude_min: 0.2,
            slip_magnitude_max: 0.5,
        }
    }

    /// The `harsh` profile: 2–3 times the random noise of the default, four times its
    /// calibration error, four times as many slips, longer and stronger:
    /// σ_t 0.08 m/√m, σ_ra 0.08 rad/√rad, σ_rd 0.03 rad/√m, scale σ 0.02 / 0.02,
    /// 4 slips per 100 m of 0.5–3 m with `m` in 0.3–0.7.
    pub fn harsh() -> OdometryNoiseParams {
        OdometryNoiseParams {
            translation_sigma_per_sqrt_m: 0.08,
            rotation_sigma_per_sqrt_rad: 0.08,
            rotation_sigma_per_sqrt_m: 0.03,
            translation_scale_sigma: 0.02,
            rotation_scale_sigma: 0.02,
            slip_schedule: SlipSchedule::ByTravel {
                rate_per_100m: 4.0,
                length_min_m: 0.5,
                length_max_m: 3.0,
            },
            slip_magnitude_min: 0.3,
            slip_magnitude_max: 0.7,
        }
    }

    /// No noise at all (the `none` profile): the noisy log's poses equal the corrected ones up
    /// to rounding (about 1e-12 m after thousands of compositions).
    pub fn zero() -> OdometryNoiseParams {
        let default = Self::default();
        OdometryNoiseParams {
            translation_sigma_per_sqrt_m: 0.0,
            rotation_sigma_per_sqrt_rad: 0.0,
            rotation_sigma_per_sqrt_m: 0.0,
            translation_scale_sigma: 0.0,
            rotation_scale_sigma: 0.0,
            slip_schedule: SlipSchedule::ByTravel {
                rate_per_100m: 0.0,
                length_min_m: 0.5,
                length_max_m: 2.0,
            },
            ..default
        }
    }

    /// The profile called `name`: `default`, `harsh` or `none` ([`NOISE_PROFILE_NAMES`]).
    pub fn from_name(name: &str) -> Result<OdometryNoiseParams, SimError> {
        match name {
            "default" => Ok(Self::default()),
            "harsh" => Ok(Self::harsh()),
            "none" => Ok(Self::zero()),
            _ => Err(SimError::UnknownNoiseProfile {
                name: name.to_owned(),
                valid: NOISE_PROFILE_NAMES.join(", "),
            }),
        }
    }
}

/// A corrected log with simulated odometry, and what was done to it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NoisyLog {
    /// The same scans (ranges, stamps, sensor offsets) with every scan's `odom_from_robot`
    /// replaced by the noisy odometry pose, and the `ODOM` messages replaced by one per scan at
    /// the scan's stamp carrying the same noisy pose (velocities 0). The original `ODOM`
    /// messages lie on the *corrected* trajectory between scans; keeping them would hand the
    /// ground truth to any consumer that reads `ODOM` rather than the scan's pose, and noising
    /// them consistently would need poses between scans, which the corrected logs do not
    /// define. Velocities are 0 because several logs' stamps are broken (constant or bogus).
    pub log: LaserLog,
    /// The slip events that scaled at least one increment, in order ([`SlipSpan::Travel`]).
    pub slips: Vec<SlipEvent>,
    /// The drawn per-log translation scale (`s_t`).
    pub translation_scale: f64,
    /// The drawn per-log rotation scale (`s_r`).
    pub rotation_scale: f64,
}

impl NoisyLog {
    /// The noisy odometry pose of every scan, in scan order.
    pub fn odometry_poses(&self) -> Vec<Se2> {
        self.log
            .scans
            .iter()
            .map(|record| record.odom_from_robot.unwrap_or_else(Se2::identity))
            .collect()
    }
}

/// The robot pose of every scan of `log`; fails on the first scan without one.
pub fn scan_poses(log: &LaserLog) -> Result<Vec<Se2>, SimError> {
    log.scans
        .iter()
        .enumerate()
        .map(|(scan, record)| record.odom_from_robot.ok_or(SimError::MissingPose { scan }))
        .collect()
}

/// Replaces the odometry of a corrected log by a seeded, drifting simulation of wheel odometry
/// (the module docs: the model; [`NoisyLog::log`]: what changes in the log). Named parameters:
/// [`OdometryNoiseProfile`].
///
/// Fails if the parameters are invalid or schedule slips over time, or if a scan has no pose.
/// A log with fewer than two scans is returned with its poses unchanged.
pub fn add_odometry_noise(
    log: &LaserLog,
    params: &OdometryNoiseParams,
    seed: u64,
) -> Result<NoisyLog, SimError> {
    params.validate()?;
    if !matches!(params.slip_schedule, SlipSchedule::ByTravel { .. }) {
        return Err(SimError::InvalidParams {
            field: "odometry.slip_schedule",
            reason: "a corrected log's slips are scheduled over wheel travel \
                     (slip_rate_per_100m, slip_length_min_m, slip_length_max_m)"
                .to_owned(),
        });
    }
    let corrected = scan_poses(log)?;
    let mut rng = seeded(seed);
    let noise = SessionNoise::draw(&mut rng, params, Draws::CorrectedLog);

    // 1. The true increments and the wheel travel of each.
    let increments: Vec<Se2> = corrected.windows(2).map(|w| w[0].between(&w[1])).collect();
    let travel_m: Vec<f64> = increments
        .iter()
        .map(|u| u.translation().norm() + HALF_TRACK_M * u.theta_rad.abs())
        .collect();
    let total_travel_m: f64 = travel_m.iter().sum();

    // 2. Slip events over wheel travel.
    let schedule = schedule_slips_by_travel(&mut rng, params, total_travel_m);

    // 3. Corrupt and chain the increments; an event scales those that start inside it.
    let mut noisy = Vec::with_capacity(corrected.len());
    let mut slips: Vec<SlipEvent> = Vec::with_capacity(schedule.len());
    if let Some(first) = corrected.first() {
        noisy.push(*first);
    }
    let mut pose = corrected.first().copied().unwrap_or_else(Se2::identity);
    let mut in_force = SlipCursor::new(&schedule);
    let mut travelled_m = 0.0;
    for (k, (u, wheel_m)) in increments.iter().zip(&travel_m).enumerate() {
        let slip = in_force.at(travelled_m);
        if let Some(slip) = slip {
            match slips.last_mut() {
                Some(SlipEvent {
                    span:
                        SlipSpan::Travel {
                            start_m, to_scan, ..
                        },
                    ..
                }) if *start_m == slip.start => *to_scan = k,
                _ => slips.push(SlipEvent {
                    span: SlipSpan::Travel {
                        start_m: slip.start,
                        end_m: slip.end,
                        from_scan: k,
                        to_scan: k,
                    },
                    kind: slip.kind,
                    factor: slip.factor,
                }),
            }
        }
        let (dx, dy, dtheta) = noise.corrupt(&mut rng, slip, (u.x_m, u.y_m, u.theta_rad));
        pose = pose.compose(&Se2::new(dx, dy, dtheta));
        noisy.push(pose);
        travelled_m += wheel_m;
    }

    // 4. The noisy log: same scans, noisy poses, one ODOM per scan.
    let mut out = log.clone();
    out.odometry.clear();
    for (record, pose) in out.scans.iter_mut().zip(&noisy) {
        record.odom_from_robot = Some(*pose);
        out.odometry.push(OdometryReading {
            stamp_secs: record.stamp_secs,
            odom_from_robot: *pose,
            velocity_m_per_s: 0.0,
            turn_rate_rad_per_s: 0.0,
        });
    }
    Ok(NoisyLog {
        log: out,
        slips,
        translation_scale: noise.translation_scale,
        rotation_scale: noise.rotation_scale,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;
    use crate::SlipKind;
    use mapmerge_scan::{LaserScan, ScanRecord};

    /// A log whose scans follow a figure of loops, one pose every ~0.3 m.
    fn looping_log(n: usize) -> LaserLog {
        let mut log = LaserLog::default();
        for k in 0..n {
            let t = k as f64 * 0.05;
            let pose = Se2::new(
                6.0 * t.cos() + 0.1 * t,
                4.0 * (2.0 * t).sin(),
                t + std::f64::consts::FRAC_PI_2,
            );
            log.scans.push(ScanRecord {
                stamp_secs: k as f64 * 0.2,
                scan: LaserScan::new(-1.5, 1.5, 30.0, vec![1.0, 2.0, 3.0]),
                odom_from_robot: Some(pose),
                source_tag: "FLASER".to_owned(),
            });
            log.odometry.push(OdometryReading {
                stamp_secs: k as f64 * 0.2 + 0.1,
                odom_from_robot: pose,
                velocity_m_per_s: 0.0,
                turn_rate_rad_per_s: 0.0,
            });
        }
        log
    }

    #[test]
    fn noise_is_deterministic_per_seed() {
        let log = looping_log(600);
        let profile = OdometryNoiseProfile::harsh();
        let a = add_odometry_noise(&log, &profile, 3).unwrap();
        let b = add_odometry_noise(&log, &profile, 3).unwrap();
        let c = add_odometry_noise(&log, &profile, 4).unwrap();
        assert_eq!(a, b);
        assert_ne!(a.odometry_poses(), c.odometry_poses());
        assert!(!a.slips.is_empty());
    }

    #[test]
    fn zero_noise_leaves_poses_unchanged() {
        let log = looping_log(800);
        let noisy = add_odometry_noise(&log, &OdometryNoiseProfile::zero(), 11).unwrap();
        assert!(noisy.slips.is_empty());
        for (record, pose) in log.scans.iter().zip(noisy.odometry_poses()) {
            let truth = record.odom_from_robot.unwrap();
            assert!((truth.x_m - pose.x_m).abs() < 1e-9 && (truth.y_m - pose.y_m).abs() < 1e-9);
            assert!(truth.between(&pose).theta_rad.abs() < 1e-9);
        }
        // Scans are untouched, ODOM is one per scan at the scan's stamp.
        assert_eq!(noisy.log.scans.len(), log.scans.len());
        assert_eq!(noisy.log.odometry.len(), log.scans.len());
        for (a, b) in noisy.log.scans.iter().zip(&log.scans) {
            assert_eq!(a.scan, b.scan);
            assert_eq!(a.stamp_secs, b.stamp_secs);
        }
        for (odom, record) in noisy.log.odometry.iter().zip(&noisy.log.scans) {
            assert_eq!(odom.stamp_secs, record.stamp_secs);
            assert_eq!(Some(odom.odom_from_robot), record.odom_from_robot);
        }
    }

    #[test]
    fn harsh_drifts_more_than_default() {
        let log = looping_log(1500);
        let truth = scan_poses(&log).unwrap();
        let end_error = |profile: &OdometryNoiseParams| {
            // Mean final position error over several seeds.
            (0..20)
                .map(|seed| {
                    let poses = add_odometry_noise(&log, profile, seed)
                        .unwrap()
                        .odometry_poses();
                    (poses[poses.len() - 1].translation() - truth[truth.len() - 1].translation())
                        .norm()
                })
                .sum::<f64>()
                / 20.0
        };
        let (default, harsh) = (
            end_error(&OdometryNoiseProfile::default()),
            end_error(&OdometryNoiseProfile::harsh()),
        );
        assert!(default > 0.05, "{default}");
        assert!(harsh > 1.5 * default, "{harsh} vs {default}");
    }

    #[test]
    fn slips_cover_the_increments_they_scale() {
        let log = looping_log(2000);
        let profile = OdometryNoiseParams {
            slip_schedule: SlipSchedule::ByTravel {
                rate_per_100m: 10.0,
                length_min_m: 0.5,
                length_max_m: 2.0,
            },
            ..OdometryNoiseProfile::zero()
        };
        let noisy = add_odometry_noise(&log, &profile, 5).unwrap();
        assert!(noisy.slips.len() > 3);
        let truth = scan_poses(&log).unwrap();
        let poses = noisy.odometry_poses();
        for slip in &noisy.slips {
            let SlipSpan::Travel { from_scan: k, .. } = slip.span else {
                panic!("{slip:?} is not on wheel travel");
            };
            let (u, v) = (
                truth[k].between(&truth[k + 1]),
                poses[k].between(&poses[k + 1]),
            );
            match slip.kind {
                SlipKind::Translation => {
                    let ratio = v.translation().norm() / u.translation().norm();
                    assert!((ratio - slip.factor).abs() < 1e-6, "{ratio} vs {slip:?}");
                }
                SlipKind::Rotation => {
                    assert!((v.theta_rad / u.theta_rad - slip.factor).abs() < 1e-6);
                }
            }
        }
    }

    #[test]
    fn profiles_by_name_and_validation() {
        assert_eq!(
            OdometryNoiseProfile::from_name("harsh").unwrap(),
            OdometryNoiseProfile::harsh()
        );
        let err = OdometryNoiseProfile::from_name("gentle").unwrap_err();
        assert!(err.to_string().contains("default, harsh, none"), "{err}");
        for name in NOISE_PROFILE_NAMES {
            OdometryNoiseProfile::from_name(name)
                .unwrap()
                .validate()
                .unwrap();
        }
        let bad = OdometryNoiseParams {
            slip_magnitude_max: 1.5,
            ..OdometryNoiseProfile::default()
        };
        assert!(bad.validate().is_err());
        let log = looping_log(3);
        // The simulator's parameters schedule slips over time, which a log cannot.
        assert!(matches!(
            add_odometry_noise(&log, &OdometryNoiseParams::default(), 0),
            Err(SimError::InvalidParams { .. })
        ));
        let mut log = log;
        log.scans[1].odom_from_robot = None;
        assert_eq!(
            add_odometry_noise(&log, &OdometryNoiseProfile::default(), 0),
            Err(SimError::MissingPose { scan: 1 })
        );
    }
}
