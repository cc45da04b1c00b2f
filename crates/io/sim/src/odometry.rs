//! Wheel odometry: the robot's true motion, step by step, with a per-session calibration error,
//! random noise whose variance grows with the motion (the odometry motion model of Thrun,
//! Burgard & Fox, *Probabilistic Robotics*, Sec. 5.4, in density form so that it does not
//! depend on the step length), and wheel-slip events during which the wheels over- or
//! under-report translation or rotation by a factor.

use mapmerge_geometry::{LieGroup, Se2};
use nalgebra::Vector3;
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::rng::{exponential, gaussian, uniform, SimRng};
use crate::SimError;

/// Noise of the wheel odometry.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OdometryNoiseParams {
    /// Random translation error per square root of distance driven (m/√m) (default: 0.02:
    /// after 100 m the along-track error has a standard deviation of 0.2 m).
    pub translation_sigma_per_sqrt_m: f64,
    /// Random heading error per square root of angle turned (rad/√rad) (default: 0.02).
    pub rotation_sigma_per_sqrt_rad: f64,
    /// Random heading error per square root of distance driven (rad/√m) (default: 0.005:
    /// 0.05 rad ≈ 3° after 100 m straight).
    pub rotation_sigma_per_sqrt_m: f64,
    /// Standard deviation of the per-session translation scale error (default: 0.005, i.e.
    /// wheel radii off by about 0.5 %). A systematic error that makes the drift grow linearly.
    pub translation_scale_sigma: f64,
    /// Standard deviation of the per-session rotation scale error (default: 0.005, i.e. the
    /// wheel base off by about 0.5 %).
    pub rotation_scale_sigma: f64,
    /// Mean number of wheel-slip events per minute of robot time (default: 0.5). Events start
    /// as a Poisson process.
    pub slip_rate_per_min: f64,
    /// Shortest slip event (s) (default: 1.0).
    pub slip_duration_min_secs: f64,
    /// Longest slip event (s) (default: 3.0).
    pub slip_duration_max_secs: f64,
    /// Smallest relative error of a slip event (default: 0.3): the factor is `1 ± m` with `m`
    /// uniform in `[slip_magnitude_min, slip_magnitude_max]`, over- or under-reporting with
    /// equal probability.
    pub slip_magnitude_min: f64,
    /// Largest relative error of a slip event (default: 0.6).
    pub slip_magnitude_max: f64,
}

impl Default for OdometryNoiseParams {
    fn default() -> Self {
        Self {
            translation_sigma_per_sqrt_m: 0.02,
            rotation_sigma_per_sqrt_rad: 0.02,
            rotation_sigma_per_sqrt_m: 0.005,
            translation_scale_sigma: 0.005,
            rotation_scale_sigma: 0.005,
            slip_rate_per_min: 0.5,
            slip_duration_min_secs: 1.0,
            slip_duration_max_secs: 3.0,
            slip_magnitude_min: 0.3,
            slip_magnitude_max: 0.6,
        }
    }
}

impl OdometryNoiseParams {
    /// Noise-free odometry: no random error, no scale error, no slips.
    pub fn perfect() -> Self {
        Self {
            translation_sigma_per_sqrt_m: 0.0,
            rotation_sigma_per_sqrt_rad: 0.0,
            rotation_sigma_per_sqrt_m: 0.0,
            translation_scale_sigma: 0.0,
            rotation_scale_sigma: 0.0,
            slip_rate_per_min: 0.0,
            ..Self::default()
        }
    }

    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), SimError> {
        let non_negative = [
            (
                "odometry.translation_sigma_per_sqrt_m",
                self.translation_sigma_per_sqrt_m,
            ),
            (
                "odometry.rotation_sigma_per_sqrt_rad",
                self.rotation_sigma_per_sqrt_rad,
            ),
            (
                "odometry.rotation_sigma_per_sqrt_m",
                self.rotation_sigma_per_sqrt_m,
            ),
            (
                "odometry.translation_scale_sigma",
                self.translation_scale_sigma,
            ),
            ("odometry.rotation_scale_sigma", self.rotation_scale_sigma),
            ("odometry.slip_rate_per_min", self.slip_rate_per_min),
            (
                "odometry.slip_duration_min_secs",
                self.slip_duration_min_secs,
            ),
            ("odometry.slip_magnitude_min", self.slip_magnitude_min),
        ];
        for (field, value) in non_negative {
            if !(value.is_finite() && value >= 0.0) {
                return Err(SimError::InvalidParams {
                    field,
                    reason: "must be finite and non-negative".to_owned(),
                });
            }
        }
        if !(self.slip_duration_max_secs >= self.slip_duration_min_secs
            && self.slip_duration_max_secs.is_finite())
        {
            return Err(SimError::InvalidParams {
                field: "odometry.slip_duration_max_secs",
                reason: "must be at least slip_duration_min_secs".to_owned(),
            });
        }
        if !(self.slip_magnitude_max >= self.slip_magnitude_min && self.slip_magnitude_max < 1.0) {
            return Err(SimError::InvalidParams {
                field: "odometry.slip_magnitude_max",
                reason: "must lie in [slip_magnitude_min, 1)".to_owned(),
            });
        }
        Ok(())
    }
}

/// What a slip event corrupts (shared with the odometry noise of corrected logs, `mapmerge-eval`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SlipKind {
    /// The reported translation (distance) is the true one times the factor.
    Translation,
    /// The reported turn is the true one times the factor.
    Rotation,
}

/// A wheel-slip event.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SlipEvent {
    /// When it starts (s, log time).
    pub start_secs: f64,
    /// When it ends (s, log time).
    pub end_secs: f64,
    /// What it corrupts.
    pub kind: SlipKind,
    /// Reported over true motion while it lasts (below 1: under-reporting).
    pub factor: f64,
}

/// Slip events over `[0, duration_secs)` (session time, from 0).
pub(crate) fn schedule_slips(
    rng: &mut SimRng,
    params: &OdometryNoiseParams,
    duration_secs: f64,
) -> Vec<SlipEvent> {
    let mut events = Vec::new();
    if params.slip_rate_per_min <= 0.0 {
        return events;
    }
    let mean_gap_secs = 60.0 / params.slip_rate_per_min;
    let mut t = exponential(rng, mean_gap_secs);
    while t < duration_secs {
        let length = uniform(
            rng,
            params.slip_duration_min_secs,
            params.slip_duration_max_secs,
        );
        let magnitude = uniform(rng, params.slip_magnitude_min, params.slip_magnitude_max);
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
        events.push(SlipEvent {
            start_secs: t,
            end_secs: (t + length).min(duration_secs),
            kind,
            factor,
        });
        // Events do not overlap: the next one starts after this one ends.
        t += length + exponential(rng, mean_gap_secs);
    }
    events
}

/// Odometry from the true per-step motion `(distance_m, turn_rad)` of steps `step_secs` long:
/// the odometry pose before every step and after the last one (starting at identity), and the
/// reported `(velocity_m_per_s, turn_rate_rad_per_s)` of every step.
pub(crate) fn integrate_odometry(
    rng: &mut SimRng,
    params: &OdometryNoiseParams,
    slips: &[SlipEvent],
    true_steps: &[(f64, f64)],
    step_secs: f64,
) -> (Vec<Se2>, Vec<(f64, f64)>) {
    let translation_scale = 1.0 + params.translation_scale_sigma * gaussian(rng);
    let rotation_scale = 1.0 + params.rotation_scale_sigma * gaussian(rng);
    let mut poses = Vec::with_capacity(true_steps.len() + 1);
    let mut rates = Vec::with_capacity(true_steps.len());
    let mut pose = Se2::new(0.0, 0.0, 0.0);
    poses.push(pose);
    let mut slip_index = 0;
    for (step, &(distance_m, turn_rad)) in true_steps.iter().enumerate() {
        let t = step as f64 * step_secs;
        while slip_index < slips.len() && slips[slip_index].end_secs <= t {
            slip_index += 1;
        }
        let (mut slip_translation, mut slip_rotation) = (1.0, 1.0);
        if let Some(slip) = slips.get(slip_index).filter(|s| s.start_secs <= t) {
            match slip.kind {
                SlipKind::Translation => slip_translation = slip.factor,
                SlipKind::Rotation => slip_rotation = slip.factor,
            }
        }
        let (d, a) = (distance_m.abs(), turn_rad.abs());
        let sigma_translation = params.translation_sigma_per_sqrt_m * d.sqrt();
        let sigma_rotation = (params.rotation_sigma_per_sqrt_rad.powi(2) * a
            + params.rotation_sigma_per_sqrt_m.powi(2) * d)
            .sqrt();
        let noise_translation = if sigma_translation > 0.0 {
            sigma_translation * gaussian(rng)
        } else {
            0.0
        };
        let noise_rotation = if sigma_rotation > 0.0 {
            sigma_rotation * gaussian(rng)
        } else {
            0.0
        };
        let reported_distance =
            distance_m * translation_scale * slip_translation + noise_translation;
        let reported_turn = turn_rad * rotation_scale * slip_rotation + noise_rotation;
        pose = pose.compose(&Se2::exp(&Vector3::new(
            reported_distance,
            0.0,
            reported_turn,
        )));
        poses.push(pose);
        rates.push((reported_distance / step_secs, reported_turn / step_secs));
    }
    (poses, rates)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::seeded;

    #[test]
    fn perfect_odometry_follows_the_true_motion() {
        let steps = vec![(0.01, 0.002); 500];
        let (poses, rates) = integrate_odometry(
            &mut seeded(1),
            &OdometryNoiseParams::perfect(),
            &[],
            &steps,
            0.01,
        );
        let mut truth = Se2::new(0.0, 0.0, 0.0);
        for &(d, a) in &steps {
            truth = truth.compose(&Se2::exp(&Vector3::new(d, 0.0, a)));
        }
        let last = poses.last().unwrap();
        assert!(
            (last.x_m - truth.x_m).abs() < 1e-12
                && (last.theta_rad - truth.theta_rad).abs() < 1e-12
        );
        assert!((rates[0].0 - 1.0).abs() < 1e-12);
    }

    #[test]
    fn slips_follow_the_rate_and_scale_the_motion() {
        let params = OdometryNoiseParams {
            slip_rate_per_min: 2.0,
            ..OdometryNoiseParams::perfect()
        };
        let slips = schedule_slips(&mut seeded(4), &params, 3600.0);
        // About 2 per minute minus the time spent slipping: 120 · 60 / 62 ≈ 116 expected.
        assert!((80..160).contains(&slips.len()), "{} slips", slips.len());
        for pair in slips.windows(2) {
            assert!(pair[0].end_secs <= pair[1].start_secs);
        }
        let slip = slips[0];
        let steps = vec![(0.01, 0.01); 360_000];
        let (_, rates) = integrate_odometry(&mut seeded(1), &params, &slips, &steps, 0.01);
        let inside = ((slip.start_secs + slip.end_secs) * 0.5 / 0.01) as usize;
        let expected = match slip.kind {
            SlipKind::Translation => (slip.factor, 1.0),
            SlipKind::Rotation => (1.0, slip.factor),
        };
        assert!(
            (rates[inside].0 - expected.0).abs() < 1e-9
                && (rates[inside].1 - expected.1).abs() < 1e-9
        );
    }
}
