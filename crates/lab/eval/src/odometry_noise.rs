//! Seeded, documented odometry noise for *corrected* laser logs.
//!
//! The public corrected CARMEN logs carry the corrected (scan-matched) pose in every scan's
//! odometry field, so a SLAM front-end fed with them would be handed the answer. To evaluate a
//! front-end we replace each scan's pose by a simulated wheel odometry that drifts: the
//! increment between consecutive scan poses, `u_k = x_k⁻¹ · x_{k+1}` (in the robot frame of scan
//! `k`), is corrupted and the noisy increments are chained from the first corrected pose.
//!
//! Noise model of one increment with translation `(dx, dy)`, length `d = |(dx, dy)|` and turn
//! `dθ` (`a = |dθ|`), after the odometry motion model of Thrun, Burgard & Fox, *Probabilistic
//! Robotics*, Sec. 5.4, in density form:
//!
//! - translation: `(dx, dy) · s_t · slip_t + n_t`, `n_t ~ N(0, σ_t² d · I₂)` with
//!   `σ_t = translation_sigma_per_sqrt_m`;
//! - rotation: `dθ · s_r · slip_r + n_r`, `n_r ~ N(0, σ_ra² a + σ_rd² d)` with
//!   `σ_ra = rotation_sigma_per_sqrt_rad`, `σ_rd = rotation_sigma_per_sqrt_m`;
//! - `s_t = 1 + translation_scale_sigma · N(0, 1)`, `s_r = 1 + rotation_scale_sigma · N(0, 1)`:
//!   one systematic calibration error per log (wheel radius, wheel base), drawn once;
//! - `slip_t`, `slip_r`: 1, except inside wheel-slip events (below).
//!
//! Variances grow **linearly** with distance and angle (standard deviations with their square
//! roots), so the noise accumulated over a stretch does not depend on how many scans it was cut
//! into: the corrected logs keep scans at very different spacings (the filter that produced
//! them only integrated some), and a per-scan noise would punish densely sampled logs.
//!
//! Wheel-slip events start as a Poisson process over the *wheel travel* `s = d + 0.25 m · a`
//! (the distance a wheel of a robot with a 0.5 m track rolls; turning on the spot slips too),
//! `slip_rate_per_100m` events per 100 m of wheel travel; each lasts a wheel travel uniform in
//! `[slip_length_min_m, slip_length_max_m]` and scales either the translation or the rotation of
//! every increment that starts inside it by `1 ± m`, `m` uniform in
//! `[slip_magnitude_min, slip_magnitude_max]` (over- or under-reporting, equally likely).
//!
//! Everything is drawn from ChaCha8 seeded with the caller's seed, in scan order, so a seed
//! reproduces the same noisy log on every platform.

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::{LaserLog, OdometryReading};
pub use mapmerge_sim::SlipKind;
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::rng::{gaussian, seeded};
use crate::EvalError;

/// Half the track of the assumed differential-drive robot (m): turning by `a` rad rolls each
/// wheel `0.25 · a` m, which is what slip events are scheduled over together with the distance.
const HALF_TRACK_M: f64 = 0.25;

/// The names [`OdometryNoiseProfile::from_name`] knows.
pub const NOISE_PROFILE_NAMES: [&str; 3] = ["default", "harsh", "none"];

/// How noisy the simulated wheel odometry is (see the module doc for the model).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OdometryNoiseProfile {
    /// Random translation error per square root of distance (m/√m), per axis of the robot
    /// frame (default: 0.03: after 1 m, 3 cm; after 100 m of driving, 0.3 m).
    pub translation_sigma_per_sqrt_m: f64,
    /// Random heading error per square root of angle turned (rad/√rad) (default: 0.03: a full
    /// turn on the spot, about 4.3°).
    pub rotation_sigma_per_sqrt_rad: f64,
    /// Random heading error per square root of distance driven (rad/√m) (default: 0.01: 0.6°
    /// after 1 m, 5.7° after 100 m straight).
    pub rotation_sigma_per_sqrt_m: f64,
    /// Standard deviation of the per-log translation scale error (default: 0.005: wheel radii
    /// off by about 0.5 %). Systematic: the drift it causes grows linearly.
    pub translation_scale_sigma: f64,
    /// Standard deviation of the per-log rotation scale error (default: 0.005: the wheel base
    /// off by about 0.5 %; it acts on the signed turn, so a run that circles one way drifts).
    pub rotation_scale_sigma: f64,
    /// Mean number of wheel-slip events per 100 m of wheel travel (default: 1).
    pub slip_rate_per_100m: f64,
    /// Shortest slip event, in wheel travel (m) (default: 0.5).
    pub slip_length_min_m: f64,
    /// Longest slip event, in wheel travel (m) (default: 2.0).
    pub slip_length_max_m: f64,
    /// Smallest relative error of a slip (default: 0.2): the factor is `1 ± m`.
    pub slip_magnitude_min: f64,
    /// Largest relative error of a slip (default: 0.5); must be below 1.
    pub slip_magnitude_max: f64,
}

impl Default for OdometryNoiseProfile {
    fn default() -> Self {
        Self {
            translation_sigma_per_sqrt_m: 0.03,
            rotation_sigma_per_sqrt_rad: 0.03,
            rotation_sigma_per_sqrt_m: 0.01,
            translation_scale_sigma: 0.005,
            rotation_scale_sigma: 0.005,
            slip_rate_per_100m: 1.0,
            slip_length_min_m: 0.5,
            slip_length_max_m: 2.0,
            slip_magnitude_min: 0.2,
            slip_magnitude_max: 0.5,
        }
    }
}

impl OdometryNoiseProfile {
    /// The `harsh` profile: 2–3 times the random noise of the default, four times its
    /// calibration error, four times as many slips, longer and stronger:
    /// σ_t 0.08 m/√m, σ_ra 0.08 rad/√rad, σ_rd 0.03 rad/√m, scale σ 0.02 / 0.02,
    /// 4 slips per 100 m of 0.5–3 m with `m` in 0.3–0.7.
    pub fn harsh() -> Self {
        Self {
            translation_sigma_per_sqrt_m: 0.08,
            rotation_sigma_per_sqrt_rad: 0.08,
            rotation_sigma_per_sqrt_m: 0.03,
            translation_scale_sigma: 0.02,
            rotation_scale_sigma: 0.02,
            slip_rate_per_100m: 4.0,
            slip_length_min_m: 0.5,
            slip_length_max_m: 3.0,
            slip_magnitude_min: 0.3,
            slip_magnitude_max: 0.7,
        }
    }

    /// No noise at all (the `none` profile): the noisy log's poses equal the corrected ones up
    /// to rounding (about 1e-12 m after thousands of compositions).
    pub fn zero() -> Self {
        Self {
            translation_sigma_per_sqrt_m: 0.0,
            rotation_sigma_per_sqrt_rad: 0.0,
            rotation_sigma_per_sqrt_m: 0.0,
            translation_scale_sigma: 0.0,
            rotation_scale_sigma: 0.0,
            slip_rate_per_100m: 0.0,
            ..Self::default()
        }
    }

    /// A named profile: `default`, `harsh` or `none` ([`NOISE_PROFILE_NAMES`]).
    pub fn from_name(name: &str) -> Result<Self, EvalError> {
        match name {
            "default" => Ok(Self::default()),
            "harsh" => Ok(Self::harsh()),
            "none" => Ok(Self::zero()),
            _ => Err(EvalError::InvalidParams {
                field: "profile",
                reason: format!(
                    "unknown odometry noise profile `{name}`; known: {}",
                    NOISE_PROFILE_NAMES.join(", ")
                ),
            }),
        }
    }

    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), EvalError> {
        let non_negative = [
            (
                "translation_sigma_per_sqrt_m",
                self.translation_sigma_per_sqrt_m,
            ),
            (
                "rotation_sigma_per_sqrt_rad",
                self.rotation_sigma_per_sqrt_rad,
            ),
            ("rotation_sigma_per_sqrt_m", self.rotation_sigma_per_sqrt_m),
            ("translation_scale_sigma", self.translation_scale_sigma),
            ("rotation_scale_sigma", self.rotation_scale_sigma),
            ("slip_rate_per_100m", self.slip_rate_per_100m),
            ("slip_length_min_m", self.slip_length_min_m),
            ("slip_magnitude_min", self.slip_magnitude_min),
        ];
        for (field, value) in non_negative {
            if !(value.is_finite() && value >= 0.0) {
                return Err(EvalError::InvalidParams {
                    field,
                    reason: format!("{value} must be finite and non-negative"),
                });
            }
        }
        if !(self.slip_length_max_m >= self.slip_length_min_m && self.slip_length_max_m.is_finite())
        {
            return Err(EvalError::InvalidParams {
                field: "slip_length_max_m",
                reason: "must be finite and at least slip_length_min_m".to_owned(),
            });
        }
        if !(self.slip_magnitude_max >= self.slip_magnitude_min && self.slip_magnitude_max < 1.0) {
            return Err(EvalError::InvalidParams {
                field: "slip_magnitude_max",
                reason: "must lie in [slip_magnitude_min, 1)".to_owned(),
            });
        }
        Ok(())
    }
}

/// One wheel-slip event of a noisy log.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SlipEvent {
    /// First scan index whose increment to the next scan is scaled.
    pub from_scan: usize,
    /// Last scan index (inclusive) whose increment to the next scan is scaled.
    pub to_scan: usize,
    /// Wheel travel from the start of the log where it starts (m).
    pub start_travel_m: f64,
    /// Its length in wheel travel (m).
    pub length_m: f64,
    /// What it corrupts.
    pub kind: SlipKind,
    /// Reported over true motion while it lasts.
    pub factor: f64,
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
    /// The slip events, in order.
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
pub fn scan_poses(log: &LaserLog) -> Result<Vec<Se2>, EvalError> {
    log.scans
        .iter()
        .enumerate()
        .map(|(scan, record)| {
            record
                .odom_from_robot
                .ok_or(EvalError::MissingPose { scan })
        })
        .collect()
}

/// A uniform sample in `[lo, hi]`.
fn uniform<R: Rng + ?Sized>(rng: &mut R, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.random::<f64>()
}

/// An exponential sample with the given mean.
fn exponential<R: Rng + ?Sized>(rng: &mut R, mean: f64) -> f64 {
    // 1 − u in (0, 1], so the logarithm is finite.
    -mean * (1.0 - rng.random::<f64>()).ln()
}

/// Replaces the odometry of a corrected log by a seeded, drifting simulation of wheel odometry
/// (module doc: the model; [`NoisyLog::log`]: what changes in the log).
///
/// Fails if the profile is invalid or a scan has no pose. A log with fewer than two scans is
/// returned with its poses unchanged.
pub fn add_odometry_noise(
    log: &LaserLog,
    profile: &OdometryNoiseProfile,
    seed: u64,
) -> Result<NoisyLog, EvalError> {
    profile.validate()?;
    let corrected = scan_poses(log)?;
    let mut rng = seeded(seed);
    let translation_scale = 1.0 + profile.translation_scale_sigma * gaussian(&mut rng);
    let rotation_scale = 1.0 + profile.rotation_scale_sigma * gaussian(&mut rng);

    // 1. The true increments and the wheel travel at the start of each.
    let increments: Vec<Se2> = corrected.windows(2).map(|w| w[0].between(&w[1])).collect();
    let travel_m: Vec<f64> = increments
        .iter()
        .map(|u| u.translation().norm() + HALF_TRACK_M * u.theta_rad.abs())
        .collect();
    let total_travel_m: f64 = travel_m.iter().sum();

    // 2. Slip events over wheel travel (a Poisson process; events do not overlap).
    let mut events: Vec<(f64, f64, SlipKind, f64)> = Vec::new();
    if profile.slip_rate_per_100m > 0.0 {
        let mean_gap_m = 100.0 / profile.slip_rate_per_100m;
        let mut start_m = exponential(&mut rng, mean_gap_m);
        while start_m < total_travel_m {
            let length_m = uniform(
                &mut rng,
                profile.slip_length_min_m,
                profile.slip_length_max_m,
            );
            let magnitude = uniform(
                &mut rng,
                profile.slip_magnitude_min,
                profile.slip_magnitude_max,
            );
            let factor = if rng.random::<bool>() {
                1.0 + magnitude
            } else {
                1.0 - magnitude
            };
            let kind = if rng.random::<bool>() {
                SlipKind::Translation
            } else {
                SlipKind::Rotation
            };
            events.push((start_m, length_m, kind, factor));
            start_m += length_m + exponential(&mut rng, mean_gap_m);
        }
    }

    // 3. Corrupt and chain the increments.
    let mut noisy = Vec::with_capacity(corrected.len());
    let mut slips: Vec<SlipEvent> = Vec::with_capacity(events.len());
    if let Some(first) = corrected.first() {
        noisy.push(*first);
    }
    let mut pose = corrected.first().copied().unwrap_or_else(Se2::identity);
    let (mut travelled_m, mut event_index) = (0.0, 0);
    for (k, (u, wheel_m)) in increments.iter().zip(&travel_m).enumerate() {
        while event_index < events.len()
            && events[event_index].0 + events[event_index].1 <= travelled_m
        {
            event_index += 1;
        }
        let (mut slip_t, mut slip_r) = (1.0, 1.0);
        if let Some(&(start_m, length_m, kind, factor)) = events
            .get(event_index)
            .filter(|event| event.0 <= travelled_m)
        {
            match kind {
                SlipKind::Translation => slip_t = factor,
                SlipKind::Rotation => slip_r = factor,
            }
            match slips.last_mut() {
                Some(last) if last.start_travel_m == start_m => last.to_scan = k,
                _ => slips.push(SlipEvent {
                    from_scan: k,
                    to_scan: k,
                    start_travel_m: start_m,
                    length_m,
                    kind,
                    factor,
                }),
            }
        }
        let d = u.translation().norm();
        let a = u.theta_rad.abs();
        let sigma_t = profile.translation_sigma_per_sqrt_m * d.sqrt();
        let sigma_r = (profile.rotation_sigma_per_sqrt_rad.powi(2) * a
            + profile.rotation_sigma_per_sqrt_m.powi(2) * d)
            .sqrt();
        // Always draw, so the random stream does not depend on which increments are zero.
        let (nx, ny, nr) = (
            gaussian(&mut rng) * sigma_t,
            gaussian(&mut rng) * sigma_t,
            gaussian(&mut rng) * sigma_r,
        );
        let scale_t = translation_scale * slip_t;
        let noisy_u = Se2::new(
            u.x_m * scale_t + nx,
            u.y_m * scale_t + ny,
            u.theta_rad * rotation_scale * slip_r + nr,
        );
        pose = pose.compose(&noisy_u);
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
        translation_scale,
        rotation_scale,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;
    use mapmerge_scan::{LaserScan, ScanRecord};

    /// A log whose scans follow a figure of loops, one pose every ~0.3 m.
    pub(crate) fn looping_log(n: usize) -> LaserLog {
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
        let end_error = |profile: &OdometryNoiseProfile| {
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
        let profile = OdometryNoiseProfile {
            slip_rate_per_100m: 10.0,
            ..OdometryNoiseProfile::zero()
        };
        let noisy = add_odometry_noise(&log, &profile, 5).unwrap();
        assert!(noisy.slips.len() > 3);
        let truth = scan_poses(&log).unwrap();
        let poses = noisy.odometry_poses();
        for slip in &noisy.slips {
            let k = slip.from_scan;
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
        let bad = OdometryNoiseProfile {
            slip_magnitude_max: 1.5,
            ..OdometryNoiseProfile::default()
        };
        assert!(bad.validate().is_err());
        let mut log = looping_log(3);
        log.scans[1].odom_from_robot = None;
        assert_eq!(
            add_odometry_noise(&log, &OdometryNoiseProfile::default(), 0),
            Err(EvalError::MissingPose { scan: 1 })
        );
    }
}
