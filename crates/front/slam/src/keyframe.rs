//! When a scan becomes a keyframe (a pose-graph node with its own local map).

use mapmerge_geometry::Se2;
use mapmerge_params::{Checker, Real, Validate};
use serde::{Deserialize, Serialize};

/// A scan becomes a keyframe when the robot moved or turned enough since the last keyframe, or
/// after too many scans without one (distance / angle / count, as Cartographer's motion filter).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct KeyframePolicy {
    /// Distance since the last keyframe (m).
    pub min_translation_m: f64,
    /// Rotation since the last keyframe (rad).
    pub min_rotation_rad: f64,
    /// Scans since the last keyframe.
    pub max_scans_between: usize,
}

impl Default for KeyframePolicy {
    /// 0.25 m, 10°, 50 scans.
    fn default() -> Self {
        Self {
            min_translation_m: 0.25,
            min_rotation_rad: 10f64.to_radians(),
            max_scans_between: 50,
        }
    }
}

impl Validate for KeyframePolicy {
    fn check(&self, check: &mut Checker) {
        check
            .real(
                "min_translation_m",
                self.min_translation_m,
                Real::non_negative(),
            )
            .real(
                "min_rotation_rad",
                self.min_rotation_rad,
                Real::non_negative(),
            )
            .size("max_scans_between", self.max_scans_between, 1, 1_000_000);
    }
}

impl KeyframePolicy {
    /// True when a scan at `last_keyframe_from_robot`, `scans_since` scans after the last
    /// keyframe, should become a keyframe.
    pub fn is_keyframe(&self, last_keyframe_from_robot: &Se2, scans_since: usize) -> bool {
        let moved = last_keyframe_from_robot.translation().norm() >= self.min_translation_m;
        let turned = last_keyframe_from_robot.theta_rad.abs() >= self.min_rotation_rad;
        moved || turned || scans_since >= self.max_scans_between
    }
}
