//! Wheel odometry noise: the one model of the workspace, for the simulator's sessions and for
//! corrected logs (`add_odometry_noise`, in `noisy_log.rs`).
//!
//! The model is the odometry motion model of Thrun, Burgard & Fox, *Probabilistic Robotics*,
//! Sec. 5.4, in density form, so that it does not depend on how finely the motion is cut. An
//! increment with translation `(dx, dy)`, length `d = |(dx, dy)|` and turn `dθ` (`a = |dθ|`) is
//! reported as
//!
//! - translation: `(dx, dy) · s_t · slip_t + n_t`, `n_t ~ N(0, σ_t² d)` per axis, with
//!   `σ_t = translation_sigma_per_sqrt_m`;
//! - rotation: `dθ · s_r · slip_r + n_r`, `n_r ~ N(0, σ_ra² a + σ_rd² d)` with
//!   `σ_ra = rotation_sigma_per_sqrt_rad`, `σ_rd = rotation_sigma_per_sqrt_m`;
//! - `s_t = 1 + translation_scale_sigma · N(0, 1)`, `s_r = 1 + rotation_scale_sigma · N(0, 1)`:
//!   one systematic calibration error (wheel radius, wheel base) per session or log;
//! - `slip_t`, `slip_r`: 1, except inside wheel-slip events, which scale either the translation
//!   or the rotation by `1 ± m`, `m` uniform in `[slip_magnitude_min, slip_magnitude_max]`
//!   (over- or under-reporting, equally likely).
//!
//! Variances grow linearly with distance and angle (standard deviations with their square
//! roots), so the noise accumulated over a stretch does not depend on how many steps or scans it
//! was cut into.
//!
//! Slip events start as a Poisson process and do not overlap. What they are scheduled over is
//! the one difference between the two uses ([`SlipSchedule`]): robot *time* for a simulated
//! session, *wheel travel* for a corrected log, whose stamps cannot be trusted.
//!
//! Each use also keeps the random draws it always made ([`Draws`]), so that a seed still gives
//! every data set and noisy log it gave before the two were one model.

use mapmerge_geometry::{LieGroup, Se2};
use nalgebra::{Vector2, Vector3};
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::noisy_log::OdometryNoiseProfile;
use crate::rng::{exponential, gaussian, uniform, uniform_drawn};
use crate::SimError;

/// Noise of the wheel odometry (the module doc gives the model). Presets: the simulator's
/// `OdometryNoiseParams::default()` and [`perfect`](Self::perfect), slips over robot time;
/// corrected logs' [`OdometryNoiseProfile`] (`default`, `harsh`, `none`), slips over wheel
/// travel.
///
/// Serialised flat, the schedule's three fields named by its clock (`slip_rate_per_min`,
/// `slip_duration_min_secs`, `slip_duration_max_secs` or `slip_rate_per_100m`,
/// `slip_length_min_m`, `slip_length_max_m`); missing fields take the simulator's defaults, or a
/// corrected log's `default` profile when the schedule's fields are those of wheel travel.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "OdometryNoiseFields", into = "OdometryNoiseFields")]
pub struct OdometryNoiseParams {
    /// Random translation error per square root of distance driven (m/√m), along track in the
    /// simulator and per axis in a corrected log (simulator: 0.02, i.e. 0.2 m after 100 m;
    /// corrected logs: 0.03, harsh 0.08).
    pub translation_sigma_per_sqrt_m: f64,
    /// Random heading error per square root of angle turned (rad/√rad) (simulator: 0.02;
    /// corrected logs: 0.03, i.e. about 4.3° per full turn on the spot; harsh 0.08).
    pub rotation_sigma_per_sqrt_rad: f64,
    /// Random heading error per square root of distance driven (rad/√m) (simulator: 0.005,
    /// i.e. 0.05 rad ≈ 3° after 100 m straight; corrected logs: 0.01; harsh 0.03).
    pub rotation_sigma_per_sqrt_m: f64,
    /// Standard deviation of the per-session (per-log) translation scale error (0.005, i.e.
    /// wheel radii off by about 0.5 %; harsh 0.02). Systematic: the drift it causes grows
    /// linearly.
    pub translation_scale_sigma: f64,
    /// Standard deviation of the per-session (per-log) rotation scale error (0.005, i.e. the
    /// wheel base off by about 0.5 %; harsh 0.02). It acts on the signed turn, so a run that
    /// circles one way drifts.
    pub rotation_scale_sigma: f64,
    /// When slip events happen and how long they last.
    pub slip_schedule: SlipSchedule,
    /// Smallest relative error of a slip event: the factor is `1 ± m` with `m` uniform in
    /// `[slip_magnitude_min, slip_magnitude_max]` (simulator: 0.3; corrected logs: 0.2, harsh
    /// 0.3).
    pub slip_magnitude_min: f64,
    /// Largest relative error of a slip event, below 1 (simulator: 0.6; corrected logs: 0.5,
    /// harsh 0.7).
    pub slip_magnitude_max: f64,
}

/// When slip events happen: a Poisson process over a clock, each event lasting a uniform
/// length of that clock; events do not overlap.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SlipSchedule {
    /// Over robot time: the simulator's sessions.
    ByTime {
        /// Mean number of events per minute of robot time (simulator: 0.5).
        rate_per_min: f64,
        /// Shortest event (s) (simulator: 1.0).
        duration_min_secs: f64,
        /// Longest event (s) (simulator: 3.0).
        duration_max_secs: f64,
    },
    /// Over wheel travel `d + 0.25 m · a` (the distance a wheel of a robot with a 0.5 m track
    /// rolls; turning on the spot slips too): corrected logs, whose stamps are often broken. An
    /// event scales every increment that starts inside it.
    ByTravel {
        /// Mean number of events per 100 m of wheel travel (corrected logs: 1, harsh 4).
        rate_per_100m: f64,
        /// Shortest event, in wheel travel (m) (corrected logs: 0.5).
        length_min_m: f64,
        /// Longest event, in wheel travel (m) (corrected logs: 2.0, harsh 3.0).
        length_max_m: f64,
    },
}

impl Default for OdometryNoiseParams {
    /// The simulator's wheel odometry.
    fn default() -> Self {
        Self {
            translation_sigma_per_sqrt_m: 0.02,
            rotation_sigma_per_sqrt_rad: 0.02,
            rotation_sigma_per_sqrt_m: 0.005,
            translation_scale_sigma: 0.005,
            rotation_scale_sigma: 0.005,
            slip_schedule: SlipSchedule::by_time(0.5),
            slip_magnitude_min: 0.3,
            slip_magnitude_max: 0.6,
        }
    }
}

impl SlipSchedule {
    /// `rate_per_min` events per minute of robot time, of the simulator's 1–3 s.
    pub fn by_time(rate_per_min: f64) -> Self {
        Self::ByTime {
            rate_per_min,
            duration_min_secs: 1.0,
            duration_max_secs: 3.0,
        }
    }
}

impl OdometryNoiseParams {
    /// Noise-free odometry over robot time: no random error, no scale error, no slips.
    pub fn perfect() -> Self {
        Self {
            translation_sigma_per_sqrt_m: 0.0,
            rotation_sigma_per_sqrt_rad: 0.0,
            rotation_sigma_per_sqrt_m: 0.0,
            translation_scale_sigma: 0.0,
            rotation_scale_sigma: 0.0,
            slip_schedule: SlipSchedule::by_time(0.0),
            ..Self::default()
        }
    }

    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), SimError> {
        let (rate, length_min, length_max) = match self.slip_schedule {
            SlipSchedule::ByTime {
                rate_per_min,
                duration_min_secs,
                duration_max_secs,
            } => (
                ("odometry.slip_rate_per_min", rate_per_min),
                ("odometry.slip_duration_min_secs", duration_min_secs),
                ("odometry.slip_duration_max_secs", duration_max_secs),
            ),
            SlipSchedule::ByTravel {
                rate_per_100m,
                length_min_m,
                length_max_m,
            } => (
                ("odometry.slip_rate_per_100m", rate_per_100m),
                ("odometry.slip_length_min_m", length_min_m),
                ("odometry.slip_length_max_m", length_max_m),
            ),
        };
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
            rate,
            length_min,
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
        if !(length_max.1 >= length_min.1 && length_max.1.is_finite()) {
            return Err(SimError::InvalidParams {
                field: length_max.0,
                reason: format!(
                    "must be finite and at least {}",
                    length_min.0.trim_start_matches("odometry.")
                ),
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

/// What a slip event corrupts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SlipKind {
    /// The reported translation (distance) is the true one times the factor.
    Translation,
    /// The reported turn is the true one times the factor.
    Rotation,
}

/// A wheel-slip event: while it lasts, the odometry reports the true translation or turn
/// times `factor`. Serialised flat: `start_secs`, `end_secs` (or the wheel-travel fields),
/// `kind`, `factor`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SlipEvent {
    /// When it happens, on its schedule's clock.
    #[serde(flatten)]
    pub span: SlipSpan,
    /// What it corrupts.
    pub kind: SlipKind,
    /// Reported over true motion while it lasts (below 1: under-reporting).
    pub factor: f64,
}

/// When a slip event happens, on the clock of its [`SlipSchedule`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum SlipSpan {
    /// On robot time (a simulated session).
    Time {
        /// When it starts (s, log time).
        start_secs: f64,
        /// When it ends (s, log time; at the latest the session's end).
        end_secs: f64,
    },
    /// On wheel travel (a corrected log), with the scans whose increments it scaled.
    Travel {
        /// Wheel travel from the start of the log where it starts (m).
        start_m: f64,
        /// Wheel travel where it ends (m).
        end_m: f64,
        /// First scan whose increment to the next scan it scaled.
        from_scan: usize,
        /// Last scan (inclusive) whose increment to the next scan it scaled.
        to_scan: usize,
    },
}

impl SlipSpan {
    /// Where it starts (s or m, by its clock).
    pub fn start(&self) -> f64 {
        match *self {
            Self::Time { start_secs, .. } => start_secs,
            Self::Travel { start_m, .. } => start_m,
        }
    }

    /// Where it ends (s or m, by its clock).
    pub fn end(&self) -> f64 {
        match *self {
            Self::Time { end_secs, .. } => end_secs,
            Self::Travel { end_m, .. } => end_m,
        }
    }
}

/// A scheduled slip event on its clock (robot time from the session's start, or wheel travel
/// from the log's start), before it becomes a [`SlipEvent`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Slip {
    pub(crate) start: f64,
    pub(crate) end: f64,
    pub(crate) kind: SlipKind,
    pub(crate) factor: f64,
}

/// Which of the model's two uses draws, and so which random numbers it draws: the model is the
/// same, but each use keeps the stream it always had, so a seed reproduces every simulated data
/// set and every noisy log.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Draws {
    /// A simulated session (wheel steps along track, `dy = 0`): calibration after the slip
    /// schedule; a slip's uniform draws are skipped when their range is empty; a step draws
    /// one gaussian for its translation and one for its rotation, each only when that σ is
    /// positive; the translation is scaled by `s_t`, then by the slip.
    Simulated,
    /// A corrected log (full `(dx, dy, dθ)` increments): calibration before the slip schedule;
    /// every uniform is drawn; an increment always draws three gaussians (x, y, θ), so the
    /// stream does not depend on which increments are zero; the translation is scaled by
    /// `s_t · slip`.
    CorrectedLog,
}

/// Slip events over `[0, horizon)` of their clock, `mean_gap` apart on average (exponential
/// gaps, counted from the end of the previous event), lengths uniform in
/// `[length_min, length_max]`. Ends are not clipped to the horizon.
fn poisson_slips<R: Rng + ?Sized>(
    rng: &mut R,
    params: &OdometryNoiseParams,
    (length_min, length_max): (f64, f64),
    mean_gap: f64,
    horizon: f64,
    draws: Draws,
) -> Vec<Slip> {
    let sample = |rng: &mut R, lo: f64, hi: f64| match draws {
        Draws::Simulated => uniform(rng, lo, hi),
        Draws::CorrectedLog => uniform_drawn(rng, lo, hi),
    };
    let mut slips = Vec::new();
    let mut start = exponential(rng, mean_gap);
    while start < horizon {
        let length = sample(rng, length_min, length_max);
        let magnitude = sample(rng, params.slip_magnitude_min, params.slip_magnitude_max);
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
        slips.push(Slip {
            start,
            end: start + length,
            kind,
            factor,
        });
        // Events do not overlap: the next one starts after this one ends.
        start += length + exponential(rng, mean_gap);
    }
    slips
}

/// The slip events of a simulated session over `[0, duration_secs)` of robot time (ends
/// clipped to `duration_secs`). Requires [`SlipSchedule::ByTime`] (none otherwise).
pub(crate) fn schedule_slips_by_time<R: Rng + ?Sized>(
    rng: &mut R,
    params: &OdometryNoiseParams,
    duration_secs: f64,
) -> Vec<Slip> {
    let SlipSchedule::ByTime {
        rate_per_min,
        duration_min_secs,
        duration_max_secs,
    } = params.slip_schedule
    else {
        return Vec::new();
    };
    if rate_per_min <= 0.0 {
        return Vec::new();
    }
    let mut slips = poisson_slips(
        rng,
        params,
        (duration_min_secs, duration_max_secs),
        60.0 / rate_per_min,
        duration_secs,
        Draws::Simulated,
    );
    for slip in &mut slips {
        slip.end = slip.end.min(duration_secs);
    }
    slips
}

/// The slip events of a corrected log over `[0, total_travel_m)` of wheel travel. Requires
/// [`SlipSchedule::ByTravel`] (none otherwise).
pub(crate) fn schedule_slips_by_travel<R: Rng + ?Sized>(
    rng: &mut R,
    params: &OdometryNoiseParams,
    total_travel_m: f64,
) -> Vec<Slip> {
    let SlipSchedule::ByTravel {
        rate_per_100m,
        length_min_m,
        length_max_m,
    } = params.slip_schedule
    else {
        return Vec::new();
    };
    if rate_per_100m <= 0.0 {
        return Vec::new();
    }
    poisson_slips(
        rng,
        params,
        (length_min_m, length_max_m),
        100.0 / rate_per_100m,
        total_travel_m,
        Draws::CorrectedLog,
    )
}

/// The slip event in force at increasing positions of its clock.
pub(crate) struct SlipCursor<'a> {
    slips: &'a [Slip],
    next: usize,
}

impl<'a> SlipCursor<'a> {
    /// A cursor at the start of `slips` (in order, not overlapping).
    pub(crate) fn new(slips: &'a [Slip]) -> Self {
        Self { slips, next: 0 }
    }

    /// The event in force at `position` (no smaller than at the previous call): the first one
    /// that has not ended, if it has started.
    pub(crate) fn at(&mut self, position: f64) -> Option<&'a Slip> {
        while self.next < self.slips.len() && self.slips[self.next].end <= position {
            self.next += 1;
        }
        self.slips.get(self.next).filter(|s| s.start <= position)
    }
}

/// The model of one session or log: its parameters and its drawn calibration error.
pub(crate) struct SessionNoise<'a> {
    params: &'a OdometryNoiseParams,
    draws: Draws,
    /// `s_t`.
    pub(crate) translation_scale: f64,
    /// `s_r`.
    pub(crate) rotation_scale: f64,
}

impl<'a> SessionNoise<'a> {
    /// Draws the calibration error (`s_t`, then `s_r`).
    pub(crate) fn draw<R: Rng + ?Sized>(
        rng: &mut R,
        params: &'a OdometryNoiseParams,
        draws: Draws,
    ) -> Self {
        let translation_scale = 1.0 + params.translation_scale_sigma * gaussian(rng);
        let rotation_scale = 1.0 + params.rotation_scale_sigma * gaussian(rng);
        Self {
            params,
            draws,
            translation_scale,
            rotation_scale,
        }
    }

    /// The increment `(dx, dy, dθ)` as the wheel odometry reports it, inside `slip` if any
    /// (Thrun et al., Sec. 5.4, density form; the module doc). [`Draws::Simulated`] takes
    /// along-track steps (`dy = 0`) and reports `dy = 0`.
    pub(crate) fn corrupt<R: Rng + ?Sized>(
        &self,
        rng: &mut R,
        slip: Option<&Slip>,
        (dx, dy, dtheta): (f64, f64, f64),
    ) -> (f64, f64, f64) {
        let p = self.params;
        let (mut slip_t, mut slip_r) = (1.0, 1.0);
        if let Some(slip) = slip {
            match slip.kind {
                SlipKind::Translation => slip_t = slip.factor,
                SlipKind::Rotation => slip_r = slip.factor,
            }
        }
        let d = match self.draws {
            Draws::Simulated => dx.abs(),
            Draws::CorrectedLog => Vector2::new(dx, dy).norm(),
        };
        let a = dtheta.abs();
        let sigma_t = p.translation_sigma_per_sqrt_m * d.sqrt();
        let sigma_r = (p.rotation_sigma_per_sqrt_rad.powi(2) * a
            + p.rotation_sigma_per_sqrt_m.powi(2) * d)
            .sqrt();
        let (reported_dx, reported_dy, noise_r) = match self.draws {
            Draws::Simulated => {
                let noise_t = if sigma_t > 0.0 {
                    sigma_t * gaussian(rng)
                } else {
                    0.0
                };
                let noise_r = if sigma_r > 0.0 {
                    sigma_r * gaussian(rng)
                } else {
                    0.0
                };
                (dx * self.translation_scale * slip_t + noise_t, 0.0, noise_r)
            }
            Draws::CorrectedLog => {
                let (nx, ny, nr) = (
                    gaussian(rng) * sigma_t,
                    gaussian(rng) * sigma_t,
                    gaussian(rng) * sigma_r,
                );
                let scale_t = self.translation_scale * slip_t;
                (dx * scale_t + nx, dy * scale_t + ny, nr)
            }
        };
        (
            reported_dx,
            reported_dy,
            dtheta * self.rotation_scale * slip_r + noise_r,
        )
    }
}

/// A simulated session's odometry from the true per-step motion `(distance_m, turn_rad)` of
/// steps `step_secs` long, inside `slips` (from [`schedule_slips_by_time`]): the odometry pose
/// before every step and after the last one (starting at identity), and the reported
/// `(velocity_m_per_s, turn_rate_rad_per_s)` of every step.
pub(crate) fn integrate_odometry<R: Rng + ?Sized>(
    rng: &mut R,
    params: &OdometryNoiseParams,
    slips: &[Slip],
    true_steps: &[(f64, f64)],
    step_secs: f64,
) -> (Vec<Se2>, Vec<(f64, f64)>) {
    let noise = SessionNoise::draw(rng, params, Draws::Simulated);
    let mut in_force = SlipCursor::new(slips);
    let mut poses = Vec::with_capacity(true_steps.len() + 1);
    let mut rates = Vec::with_capacity(true_steps.len());
    let mut pose = Se2::new(0.0, 0.0, 0.0);
    poses.push(pose);
    for (step, &(distance_m, turn_rad)) in true_steps.iter().enumerate() {
        let slip = in_force.at(step as f64 * step_secs);
        let (reported_distance, _, reported_turn) =
            noise.corrupt(rng, slip, (distance_m, 0.0, turn_rad));
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

/// The serialised form of [`OdometryNoiseParams`]: flat, the slip schedule's fields named by
/// its clock, so that the simulator's parameters read and write as they always have.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
struct OdometryNoiseFields {
    translation_sigma_per_sqrt_m: Option<f64>,
    rotation_sigma_per_sqrt_rad: Option<f64>,
    rotation_sigma_per_sqrt_m: Option<f64>,
    translation_scale_sigma: Option<f64>,
    rotation_scale_sigma: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    slip_rate_per_min: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    slip_duration_min_secs: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    slip_duration_max_secs: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    slip_rate_per_100m: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    slip_length_min_m: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    slip_length_max_m: Option<f64>,
    slip_magnitude_min: Option<f64>,
    slip_magnitude_max: Option<f64>,
}

impl TryFrom<OdometryNoiseFields> for OdometryNoiseParams {
    type Error = String;

    fn try_from(f: OdometryNoiseFields) -> Result<Self, String> {
        let by_time = [
            f.slip_rate_per_min,
            f.slip_duration_min_secs,
            f.slip_duration_max_secs,
        ]
        .iter()
        .any(Option::is_some);
        let by_travel = [
            f.slip_rate_per_100m,
            f.slip_length_min_m,
            f.slip_length_max_m,
        ]
        .iter()
        .any(Option::is_some);
        if by_time && by_travel {
            return Err("slips are scheduled over robot time (slip_rate_per_min, \
                 slip_duration_min_secs, slip_duration_max_secs) or over wheel travel \
                 (slip_rate_per_100m, slip_length_min_m, slip_length_max_m), not both"
                .to_owned());
        }
        let base = if by_travel {
            OdometryNoiseProfile::default()
        } else {
            Self::default()
        };
        let slip_schedule = match base.slip_schedule {
            SlipSchedule::ByTime {
                rate_per_min,
                duration_min_secs,
                duration_max_secs,
            } => SlipSchedule::ByTime {
                rate_per_min: f.slip_rate_per_min.unwrap_or(rate_per_min),
                duration_min_secs: f.slip_duration_min_secs.unwrap_or(duration_min_secs),
                duration_max_secs: f.slip_duration_max_secs.unwrap_or(duration_max_secs),
            },
            SlipSchedule::ByTravel {
                rate_per_100m,
                length_min_m,
                length_max_m,
            } => SlipSchedule::ByTravel {
                rate_per_100m: f.slip_rate_per_100m.unwrap_or(rate_per_100m),
                length_min_m: f.slip_length_min_m.unwrap_or(length_min_m),
                length_max_m: f.slip_length_max_m.unwrap_or(length_max_m),
            },
        };
        Ok(Self {
            translation_sigma_per_sqrt_m: f
                .translation_sigma_per_sqrt_m
                .unwrap_or(base.translation_sigma_per_sqrt_m),
            rotation_sigma_per_sqrt_rad: f
                .rotation_sigma_per_sqrt_rad
                .unwrap_or(base.rotation_sigma_per_sqrt_rad),
            rotation_sigma_per_sqrt_m: f
                .rotation_sigma_per_sqrt_m
                .unwrap_or(base.rotation_sigma_per_sqrt_m),
            translation_scale_sigma: f
                .translation_scale_sigma
                .unwrap_or(base.translation_scale_sigma),
            rotation_scale_sigma: f.rotation_scale_sigma.unwrap_or(base.rotation_scale_sigma),
            slip_schedule,
            slip_magnitude_min: f.slip_magnitude_min.unwrap_or(base.slip_magnitude_min),
            slip_magnitude_max: f.slip_magnitude_max.unwrap_or(base.slip_magnitude_max),
        })
    }
}

impl From<OdometryNoiseParams> for OdometryNoiseFields {
    fn from(p: OdometryNoiseParams) -> Self {
        let mut fields = Self {
            translation_sigma_per_sqrt_m: Some(p.translation_sigma_per_sqrt_m),
            rotation_sigma_per_sqrt_rad: Some(p.rotation_sigma_per_sqrt_rad),
            rotation_sigma_per_sqrt_m: Some(p.rotation_sigma_per_sqrt_m),
            translation_scale_sigma: Some(p.translation_scale_sigma),
            rotation_scale_sigma: Some(p.rotation_scale_sigma),
            slip_magnitude_min: Some(p.slip_magnitude_min),
            slip_magnitude_max: Some(p.slip_magnitude_max),
            ..Self::default()
        };
        match p.slip_schedule {
            SlipSchedule::ByTime {
                rate_per_min,
                duration_min_secs,
                duration_max_secs,
            } => {
                fields.slip_rate_per_min = Some(rate_per_min);
                fields.slip_duration_min_secs = Some(duration_min_secs);
                fields.slip_duration_max_secs = Some(duration_max_secs);
            }
            SlipSchedule::ByTravel {
                rate_per_100m,
                length_min_m,
                length_max_m,
            } => {
                fields.slip_rate_per_100m = Some(rate_per_100m);
                fields.slip_length_min_m = Some(length_min_m);
                fields.slip_length_max_m = Some(length_max_m);
            }
        }
        fields
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
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
            slip_schedule: SlipSchedule::by_time(2.0),
            ..OdometryNoiseParams::perfect()
        };
        let slips = schedule_slips_by_time(&mut seeded(4), &params, 3600.0);
        // About 2 per minute minus the time spent slipping: 120 · 60 / 62 ≈ 116 expected.
        assert!((80..160).contains(&slips.len()), "{} slips", slips.len());
        for pair in slips.windows(2) {
            assert!(pair[0].end <= pair[1].start);
        }
        let slip = slips[0];
        let steps = vec![(0.01, 0.01); 360_000];
        let (_, rates) = integrate_odometry(&mut seeded(1), &params, &slips, &steps, 0.01);
        let inside = ((slip.start + slip.end) * 0.5 / 0.01) as usize;
        let expected = match slip.kind {
            SlipKind::Translation => (slip.factor, 1.0),
            SlipKind::Rotation => (1.0, slip.factor),
        };
        assert!(
            (rates[inside].0 - expected.0).abs() < 1e-9
                && (rates[inside].1 - expected.1).abs() < 1e-9
        );
    }

    #[test]
    fn the_two_schedules_draw_the_same_process_on_their_own_clocks() {
        // Equal mean gaps (60 / 0.6 min vs 100 / 1 per 100 m: 100 s and 100 m) and ranges:
        // the same events, on different clocks, as long as no range is empty.
        let by_time = OdometryNoiseParams {
            slip_schedule: SlipSchedule::ByTime {
                rate_per_min: 0.6,
                duration_min_secs: 0.5,
                duration_max_secs: 2.0,
            },
            ..OdometryNoiseParams::default()
        };
        let by_travel = OdometryNoiseParams {
            slip_schedule: SlipSchedule::ByTravel {
                rate_per_100m: 1.0,
                length_min_m: 0.5,
                length_max_m: 2.0,
            },
            ..OdometryNoiseParams::default()
        };
        let a = schedule_slips_by_time(&mut seeded(9), &by_time, 5000.0);
        let b = schedule_slips_by_travel(&mut seeded(9), &by_travel, 5000.0);
        assert!(a.len() > 20);
        assert_eq!(a.len(), b.len());
        for (a, b) in a.iter().zip(&b) {
            assert!((a.start - b.start).abs() < 1e-9 && (a.end - b.end).abs() < 1e-9);
            assert_eq!((a.kind, a.factor), (b.kind, b.factor));
        }
        // Each schedule needs its own clock.
        assert!(schedule_slips_by_time(&mut seeded(9), &by_travel, 5000.0).is_empty());
        assert!(schedule_slips_by_travel(&mut seeded(9), &by_time, 5000.0).is_empty());
    }

    #[test]
    fn an_empty_range_is_drawn_only_for_corrected_logs() {
        let params = OdometryNoiseParams {
            slip_schedule: SlipSchedule::ByTime {
                rate_per_min: 6.0,
                duration_min_secs: 1.0,
                duration_max_secs: 1.0,
            },
            slip_magnitude_min: 0.4,
            slip_magnitude_max: 0.4,
            ..OdometryNoiseParams::perfect()
        };
        let run = |draws| poisson_slips(&mut seeded(2), &params, (1.0, 1.0), 10.0, 600.0, draws);
        let (skipped, drawn) = (run(Draws::Simulated), run(Draws::CorrectedLog));
        // The same first start; then two more draws per event part the streams.
        assert_eq!(skipped[0].start, drawn[0].start);
        assert_ne!(skipped, drawn);
    }

    #[test]
    fn a_simulated_step_draws_only_for_positive_sigmas_and_a_log_increment_always() {
        let params = OdometryNoiseParams {
            translation_sigma_per_sqrt_m: 0.1,
            ..OdometryNoiseParams::perfect()
        };
        let mut rng = seeded(3);
        let simulated = SessionNoise::draw(&mut rng, &params, Draws::Simulated);
        // Turning on the spot: σ_t = σ_r = 0, nothing drawn.
        let before = rng.clone();
        assert_eq!(
            simulated.corrupt(&mut rng, None, (0.0, 0.0, 0.5)),
            (0.0, 0.0, 0.5)
        );
        assert_eq!(rng, before);
        let logged = SessionNoise::draw(&mut rng, &params, Draws::CorrectedLog);
        let mut three = rng.clone();
        logged.corrupt(&mut rng, None, (0.0, 0.0, 0.5));
        for _ in 0..3 {
            gaussian(&mut three);
        }
        assert_eq!(rng, three);
    }

    #[test]
    fn params_serialise_flat_by_their_clock() {
        let json = serde_json::to_string(&OdometryNoiseParams::default()).unwrap();
        assert_eq!(
            json,
            r#"{"translation_sigma_per_sqrt_m":0.02,"rotation_sigma_per_sqrt_rad":0.02,"rotation_sigma_per_sqrt_m":0.005,"translation_scale_sigma":0.005,"rotation_scale_sigma":0.005,"slip_rate_per_min":0.5,"slip_duration_min_secs":1.0,"slip_duration_max_secs":3.0,"slip_magnitude_min":0.3,"slip_magnitude_max":0.6}"#
        );
        for params in [
            OdometryNoiseParams::default(),
            OdometryNoiseParams::perfect(),
            OdometryNoiseProfile::harsh(),
        ] {
            let json = serde_json::to_string(&params).unwrap();
            assert_eq!(
                serde_json::from_str::<OdometryNoiseParams>(&json).unwrap(),
                params
            );
        }
        let partial: OdometryNoiseParams =
            serde_json::from_str(r#"{"slip_rate_per_100m": 2.0}"#).unwrap();
        assert_eq!(
            partial.slip_schedule,
            SlipSchedule::ByTravel {
                rate_per_100m: 2.0,
                length_min_m: 0.5,
                length_max_m: 2.0
            }
        );
        assert_eq!(partial.translation_sigma_per_sqrt_m, 0.03);
        let partial: OdometryNoiseParams =
            serde_json::from_str(r#"{"slip_rate_per_min": 2.0}"#).unwrap();
        assert_eq!(partial.slip_schedule, SlipSchedule::by_time(2.0));
        assert!(serde_json::from_str::<OdometryNoiseParams>(
            r#"{"slip_rate_per_min": 2.0, "slip_length_max_m": 1.0}"#
        )
        .is_err());
        assert!(serde_json::from_str::<OdometryNoiseParams>(r#"{"slip_rate": 2.0}"#).is_err());
    }

    #[test]
    fn slip_events_serialise_flat() {
        let event = SlipEvent {
            span: SlipSpan::Time {
                start_secs: 1.5,
                end_secs: 2.25,
            },
            kind: SlipKind::Rotation,
            factor: 0.7,
        };
        let json = serde_json::to_string(&event).unwrap();
        assert_eq!(
            json,
            r#"{"start_secs":1.5,"end_secs":2.25,"kind":"rotation","factor":0.7}"#
        );
        assert_eq!(serde_json::from_str::<SlipEvent>(&json).unwrap(), event);
        let event = SlipEvent {
            span: SlipSpan::Travel {
                start_m: 3.0,
                end_m: 4.5,
                from_scan: 7,
                to_scan: 9,
            },
            ..event
        };
        let json = serde_json::to_string(&event).unwrap();
        assert_eq!(serde_json::from_str::<SlipEvent>(&json).unwrap(), event);
    }
}
