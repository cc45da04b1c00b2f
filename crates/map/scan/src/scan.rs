//! One planar laser sweep.

use mapmerge_geometry::{LieGroup, Se2};
use serde::{Deserialize, Serialize};

use crate::Point2;

/// One sweep of a planar range finder: `ranges_m.len()` beams, beam `i` at
/// `angle_min_rad + i · angle_increment_rad` counter-clockwise from the sensor's x axis.
///
/// A reading at or beyond `range_max_m` means "no return" (CARMEN and ROS both report the
/// maximum value); readings at or below `range_min_m`, and NaN, are invalid.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LaserScan {
    /// Angle of the first beam (rad, sensor frame).
    pub angle_min_rad: f64,
    /// Angle between consecutive beams (rad, may be negative for clockwise scanners).
    pub angle_increment_rad: f64,
    /// Readings at or below this are invalid (m).
    pub range_min_m: f32,
    /// Readings at or above this carry no return (m).
    pub range_max_m: f32,
    /// One reading per beam (m).
    pub ranges_m: Vec<f32>,
    /// Mounting pose of the sensor on the robot (`robot_from_sensor`).
    pub robot_from_sensor: Se2,
}

/// Which beams count as obstacle returns (everything in the sensor frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BeamFilter {
    /// Shortest accepted reading (m); the scan's own `range_min_m` also applies.
    pub min_range_m: f32,
    /// Longest accepted reading (m); the scan's own `range_max_m` also applies.
    pub max_range_m: f32,
    /// Beams outside `[min_angle_rad, max_angle_rad]` (sensor frame) are dropped.
    pub min_angle_rad: f64,
    /// See `min_angle_rad`.
    pub max_angle_rad: f64,
}

impl Default for BeamFilter {
    /// Accept every valid reading.
    fn default() -> Self {
        Self {
            min_range_m: 0.0,
            max_range_m: f32::INFINITY,
            min_angle_rad: f64::NEG_INFINITY,
            max_angle_rad: f64::INFINITY,
        }
    }
}

impl LaserScan {
    /// A scan whose beams spread evenly from `first_angle_rad` to `last_angle_rad` (both
    /// inclusive), mounted at the robot's origin, with `range_min_m = 0`.
    pub fn new(
        first_angle_rad: f64,
        last_angle_rad: f64,
        range_max_m: f32,
        ranges_m: Vec<f32>,
    ) -> Self {
        let gaps = ranges_m.len().saturating_sub(1).max(1) as f64;
        Self {
            angle_min_rad: first_angle_rad,
            angle_increment_rad: (last_angle_rad - first_angle_rad) / gaps,
            range_min_m: 0.0,
            range_max_m,
            ranges_m,
            robot_from_sensor: Se2::identity(),
        }
    }

    /// Number of beams.
    pub fn len(&self) -> usize {
        self.ranges_m.len()
    }

    /// True when the scan has no beams.
    pub fn is_empty(&self) -> bool {
        self.ranges_m.is_empty()
    }

    /// Angle of beam `index` in the sensor frame (rad).
    pub fn beam_angle_rad(&self, index: usize) -> f64 {
        self.angle_min_rad + index as f64 * self.angle_increment_rad
    }

    /// True when `range_m` is an obstacle return of this sensor (finite, above the minimum,
    /// below the maximum).
    pub fn is_return(&self, range_m: f32) -> bool {
        range_m.is_finite() && range_m > self.range_min_m && range_m < self.range_max_m
    }

    /// `(beam angle, range)` of every beam, valid or not, in the sensor frame.
    pub fn beams(&self) -> impl ExactSizeIterator<Item = (f64, f32)> + '_ {
        self.ranges_m
            .iter()
            .enumerate()
            .map(|(index, &range_m)| (self.beam_angle_rad(index), range_m))
    }

    /// Obstacle returns that pass `filter`, as points in the sensor frame, in beam order.
    pub fn points_in_sensor(&self, filter: &BeamFilter) -> Vec<Point2> {
        self.beams()
            .filter(|&(angle_rad, range_m)| self.passes(filter, angle_rad, range_m))
            .map(|(angle_rad, range_m)| polar_to_point(angle_rad, range_m))
            .collect()
    }

    /// Obstacle returns that pass `filter`, as points in the robot frame, in beam order.
    pub fn points_in_robot(&self, filter: &BeamFilter) -> Vec<Point2> {
        let mut points = self.points_in_sensor(filter);
        transform_in_place(&self.robot_from_sensor, &mut points);
        points
    }

    /// True when beam `(angle_rad, range_m)` is a return accepted by `filter`.
    pub fn passes(&self, filter: &BeamFilter, angle_rad: f64, range_m: f32) -> bool {
        self.is_return(range_m)
            && range_m >= filter.min_range_m
            && range_m <= filter.max_range_m
            && angle_rad >= filter.min_angle_rad
            && angle_rad <= filter.max_angle_rad
    }
}

/// The point at `range_m` along direction `angle_rad`.
pub(crate) fn polar_to_point(angle_rad: f64, range_m: f32) -> Point2 {
    let (sin, cos) = angle_rad.sin_cos();
    Point2::new(f64::from(range_m) * cos, f64::from(range_m) * sin)
}

pub(crate) fn transform_in_place(a_from_b: &Se2, points: &mut [Point2]) {
    let rotation = a_from_b.rotation_matrix();
    let translation = a_from_b.translation();
    for p in points {
        *p = rotation * *p + translation;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    #[test]
    fn beams_spread_evenly_and_max_range_is_no_return() {
        let scan = LaserScan::new(-FRAC_PI_2, FRAC_PI_2, 80.0, vec![1.0; 181]);
        assert!((scan.angle_increment_rad - 1f64.to_radians()).abs() < 1e-15);
        assert!((scan.beam_angle_rad(180) - FRAC_PI_2).abs() < 1e-12);
        assert!(scan.is_return(79.9) && !scan.is_return(80.0) && !scan.is_return(f32::NAN));
        assert!(!scan.is_return(0.0));
    }

    #[test]
    fn filter_and_sensor_offset() {
        let mut scan = LaserScan::new(-FRAC_PI_2, FRAC_PI_2, 30.0, vec![1.0, 5.0, 2.0]);
        scan.robot_from_sensor = Se2::new(0.5, 0.0, 0.0);
        let filter = BeamFilter {
            max_range_m: 4.0,
            min_angle_rad: -0.1,
            ..BeamFilter::default()
        };
        let points = scan.points_in_robot(&filter);
        assert_eq!(points.len(), 1);
        assert!((points[0] - Point2::new(0.5, 2.0)).norm() < 1e-12);
    }
}
