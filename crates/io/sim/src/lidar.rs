//! A planar lidar: one ray per beam against the world's segments ([`RayCaster`]), Gaussian
//! range noise, random dropouts, and the maximum range where nothing is hit (the CARMEN and
//! ROS convention for "no return").

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::LaserScan;
use rand::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::rng::{derive_seed, gaussian_pair, seeded, Stream};
use crate::{RayCaster, SimError, World};

/// The sensor: beams, range limits, noise and mounting.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LidarParams {
    /// Beams per scan (default: 360). More beams cost proportionally more time.
    pub beam_count: usize,
    /// Field of view (rad) centred on the sensor's x axis (default: 2π, a full turn; then
    /// beam `i` is at `−π + i·2π/n` and no direction is repeated; a smaller field of view puts
    /// the first and last beams on its edges).
    pub field_of_view_rad: f64,
    /// Shortest valid reading (m) (default: 0.05).
    pub range_min_m: f32,
    /// Maximum range (m) (default: 30). Beams that hit nothing closer read exactly this.
    pub range_max_m: f32,
    /// Standard deviation of the Gaussian range noise (m) (default: 0.015).
    pub range_sigma_m: f64,
    /// Readings are rounded to multiples of this (m) (default: 0.001, as SICK and Hokuyo
    /// scanners report millimetres; also keeps the logs short); 0 keeps full precision.
    pub range_resolution_m: f64,
    /// Probability that a beam returns nothing (reads the maximum range) (default: 0.0; real
    /// scanners lose a few beams on glass and black surfaces, 0.001–0.01).
    pub dropout_probability: f64,
    /// Mounting pose of the sensor on the robot (default: identity, at the robot's centre).
    pub robot_from_sensor: Se2,
}

/// Most beams a simulated scan has.
pub const MAX_BEAMS: usize = 100_000;

impl Default for LidarParams {
    fn default() -> Self {
        Self {
            beam_count: 360,
            field_of_view_rad: std::f64::consts::TAU,
            range_min_m: 0.05,
            range_max_m: 30.0,
            range_sigma_m: 0.015,
            range_resolution_m: 0.001,
            dropout_probability: 0.0,
            robot_from_sensor: Se2::new(0.0, 0.0, 0.0),
        }
    }
}

impl LidarParams {
    /// `(angle of the first beam, angle between beams)` in the sensor frame (rad).
    pub fn beam_angles_rad(&self) -> (f64, f64) {
        let n = self.beam_count.max(1) as f64;
        let fov = self.field_of_view_rad;
        if fov >= std::f64::consts::TAU - 1e-9 {
            (-std::f64::consts::PI, fov / n)
        } else {
            (-0.5 * fov, fov / (n - 1.0).max(1.0))
        }
    }

    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |field: &'static str, reason: &str| {
            Err(SimError::InvalidParams {
                field,
                reason: reason.to_owned(),
            })
        };
        if !(1..=MAX_BEAMS).contains(&self.beam_count) {
            return bad("lidar.beam_count", "must be in [1, 100000]");
        }
        if !(self.field_of_view_rad > 0.0 && self.field_of_view_rad <= std::f64::consts::TAU + 1e-9)
        {
            return bad("lidar.field_of_view_rad", "must lie in (0, 2π]");
        }
        if !(self.range_min_m >= 0.0
            && self.range_max_m > self.range_min_m
            && self.range_max_m.is_finite())
        {
            return bad(
                "lidar.range_max_m",
                "must be finite and above range_min_m ≥ 0",
            );
        }
        if !(self.range_sigma_m >= 0.0 && self.range_sigma_m.is_finite()) {
            return bad("lidar.range_sigma_m", "must be finite and non-negative");
        }
        if !(self.range_resolution_m >= 0.0 && self.range_resolution_m.is_finite()) {
            return bad(
                "lidar.range_resolution_m",
                "must be finite and non-negative",
            );
        }
        if !(0.0..=1.0).contains(&self.dropout_probability) {
            return bad("lidar.dropout_probability", "must lie in [0, 1]");
        }
        Ok(())
    }
}

/// A lidar in one world: its ray caster plus the beam directions, ready to take scans from
/// any pose (and from many threads).
#[derive(Clone, Debug)]
pub struct Lidar {
    caster: RayCaster,
    params: LidarParams,
    /// `(cos, sin)` of every beam's angle in the sensor frame.
    directions_in_sensor: Vec<(f64, f64)>,
}

impl Lidar {
    /// A lidar in `world`.
    pub fn new(world: &World, params: LidarParams) -> Result<Self, SimError> {
        Self::with_caster(RayCaster::new(world), params)
    }

    /// A lidar using an existing ray caster.
    pub fn with_caster(caster: RayCaster, params: LidarParams) -> Result<Self, SimError> {
        params.validate()?;
        let (first, step) = params.beam_angles_rad();
        let directions_in_sensor = (0..params.beam_count)
            .map(|i| {
                let (s, c) = (first + i as f64 * step).sin_cos();
                (c, s)
            })
            .collect();
        Ok(Self {
            caster,
            params,
            directions_in_sensor,
        })
    }

    /// The sensor's parameters.
    pub fn params(&self) -> &LidarParams {
        &self.params
    }

    /// One scan from the robot at `world_from_robot`; `noise_seed` fixes its noise and
    /// dropouts (the same seed gives the same scan).
    pub fn scan(&self, world_from_robot: &Se2, noise_seed: u64) -> LaserScan {
        let p = &self.params;
        let world_from_sensor = world_from_robot.compose(&p.robot_from_sensor);
        let (s, c) = world_from_sensor.theta_rad.sin_cos();
        let (ox, oy) = (world_from_sensor.x_m, world_from_sensor.y_m);
        let max_m = f64::from(p.range_max_m);
        let mut rng = seeded(noise_seed);
        let noisy = p.range_sigma_m > 0.0;
        let mut spare: Option<f64> = None;
        let ranges_m = self
            .directions_in_sensor
            .iter()
            .map(|&(dc, ds)| {
                let (dx, dy) = (c * dc - s * ds, s * dc + c * ds);
                let hit_m = self.caster.cast_direction(ox, oy, dx, dy, max_m);
                let noise = if noisy {
                    match spare.take() {
                        Some(n) => n,
                        None => {
                            let (a, b) = gaussian_pair(&mut rng);
                            spare = Some(b);
                            a
                        }
                    }
                } else {
                    0.0
                };
                let dropped =
                    p.dropout_probability > 0.0 && rng.random::<f64>() < p.dropout_probability;
                let mut range_m = hit_m + p.range_sigma_m * noise;
                if p.range_resolution_m > 0.0 {
                    range_m = (range_m / p.range_resolution_m).round() * p.range_resolution_m;
                }
                let range_m = range_m as f32;
                if dropped || !hit_m.is_finite() || range_m >= p.range_max_m {
                    p.range_max_m
                } else {
                    range_m.max(0.0)
                }
            })
            .collect();
        let (angle_min_rad, angle_increment_rad) = p.beam_angles_rad();
        LaserScan {
            angle_min_rad,
            angle_increment_rad,
            range_min_m: p.range_min_m,
            range_max_m: p.range_max_m,
            ranges_m,
            robot_from_sensor: p.robot_from_sensor,
        }
    }

    /// Scans from many poses, in parallel; scan `i`'s noise comes from a stream derived from
    /// `seed` and `i`, so the result does not depend on the number of threads.
    pub fn scans(&self, world_from_robot: &[Se2], seed: u64) -> Vec<LaserScan> {
        world_from_robot
            .par_iter()
            .enumerate()
            .map(|(i, pose)| self.scan(pose, derive_seed(seed, Stream::Lidar, i as u64)))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn full_turn_and_partial_field_of_view() {
        let full = LidarParams::default();
        let (first, step) = full.beam_angles_rad();
        assert!((first + std::f64::consts::PI).abs() < 1e-15);
        assert!((step - 1f64.to_radians()).abs() < 1e-15);
        let partial = LidarParams {
            beam_count: 181,
            field_of_view_rad: std::f64::consts::PI,
            ..LidarParams::default()
        };
        let (first, step) = partial.beam_angles_rad();
        assert!((first + 180.0 * step - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!(LidarParams {
            beam_count: 0,
            ..LidarParams::default()
        }
        .validate()
        .is_err());
    }
}
