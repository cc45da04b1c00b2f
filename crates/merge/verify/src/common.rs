//! Helpers shared by the detectors: the window of recent scans, pose tolerances, points in the
//! map frame, a fast `atan2`, the logistic.

use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_posegraph::NodeId;
use mapmerge_scan::Point2;

use crate::DetectorScan;

/// The `n` most recent scans of `current` (oldest first), i.e. its last `n`.
pub(crate) fn recent(current: &[DetectorScan], n: usize) -> &[DetectorScan] {
    current
        .get(current.len().saturating_sub(n)..)
        .unwrap_or(&[])
}

/// True when `a` and `b` differ by more than `translation_m` or `rotation_rad` (or either is
/// not finite): the cue to invalidate what was computed at `a` (Holoch et al., Sec. IV-A,
/// "the cache gets invalidated").
pub(crate) fn moved(a: &Se2, b: &Se2, translation_m: f64, rotation_rad: f64) -> bool {
    !(a.is_finite()
        && b.is_finite()
        && (a.translation() - b.translation()).norm() <= translation_m
        && wrap_angle_rad(a.theta_rad - b.theta_rad).abs() <= rotation_rad)
}

/// The finite points of `scan` in the map frame, appended to `out`.
pub(crate) fn extend_points_in_map(scan: &DetectorScan, out: &mut Vec<Point2>) {
    let map_from_robot = &scan.map_from_robot;
    if !map_from_robot.is_finite() {
        return;
    }
    let rotation = map_from_robot.rotation_matrix();
    let translation = map_from_robot.translation();
    out.extend(
        scan.points_in_robot
            .iter()
            .filter(|p| p.x.is_finite() && p.y.is_finite())
            .map(|p| rotation * p + translation),
    );
}

/// The nodes and poses of the other epochs' scans a detector prepared for (at its last
/// `on_merge`), to notice when the merged map changed under it.
#[derive(Clone, Debug, Default)]
pub(crate) struct OtherSnapshot {
    poses: Vec<(NodeId, Se2)>,
}

impl OtherSnapshot {
    pub(crate) fn new(other: &[DetectorScan]) -> Self {
        Self {
            poses: other.iter().map(|s| (s.node, s.map_from_robot)).collect(),
        }
    }

    /// True when `other` holds the same vertices in the same order.
    pub(crate) fn same_vertices(&self, other: &[DetectorScan]) -> bool {
        self.poses.len() == other.len()
            && self
                .poses
                .iter()
                .zip(other)
                .all(|((node, _), s)| *node == s.node)
    }

    /// True when `other` holds the same vertices and none moved beyond the tolerances.
    pub(crate) fn still_valid(
        &self,
        other: &[DetectorScan],
        translation_m: f64,
        rotation_rad: f64,
    ) -> bool {
        self.same_vertices(other)
            && self
                .poses
                .iter()
                .zip(other)
                .all(|((_, pose), s)| !moved(pose, &s.map_from_robot, translation_m, rotation_rad))
    }
}

/// `atan2(y, x)` to within 2e-5 rad, several times faster than `f64::atan2` (a minimax
/// polynomial on [0, 1] and octant reduction). Returns 0 at the origin and for NaN input.
#[inline]
pub(crate) fn fast_atan2(y: f64, x: f64) -> f64 {
    use std::f64::consts::{FRAC_PI_2, PI};
    let (ax, ay) = (x.abs(), y.abs());
    let (small, large) = if ax < ay { (ax, ay) } else { (ay, ax) };
    let a = small / large;
    if !(large > 0.0 && a.is_finite()) {
        return 0.0;
    }
    let s = a * a;
    let mut r = a
        * (0.999_977_26
            + s * (-0.332_623_47
                + s * (0.193_543_46
                    + s * (-0.116_432_87 + s * (0.052_653_32 - s * 0.011_721_20)))));
    if ay > ax {
        r = FRAC_PI_2 - r;
    }
    if x < 0.0 {
        r = PI - r;
    }
    if y < 0.0 {
        -r
    } else {
        r
    }
}

/// The logistic `1 / (1 + exp(−(x − center) / scale))`, a monotone map of ℝ into (0, 1);
/// NaN maps to 0.
pub(crate) fn logistic(x: f64, center: f64, scale: f64) -> f64 {
    let scale = if scale > 0.0 { scale } else { 1.0 };
    let v = 1.0 / (1.0 + (-(x - center) / scale).exp());
    if v.is_nan() {
        0.0
    } else {
        v
    }
}

/// `v` clamped into [0, 1], NaN to 0.
pub(crate) fn unit(v: f64) -> f64 {
    if v.is_nan() {
        0.0
    } else {
        v.clamp(0.0, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_atan2_matches_std() {
        for i in 0..3600 {
            let a = -std::f64::consts::PI + (i as f64 + 0.5) * std::f64::consts::TAU / 3600.0;
            let (y, x) = (a.sin() * 3.7, a.cos() * 3.7);
            assert!((fast_atan2(y, x) - y.atan2(x)).abs() < 2e-5, "{a}");
        }
        assert_eq!(fast_atan2(0.0, 0.0), 0.0);
        assert_eq!(fast_atan2(f64::NAN, 1.0), 0.0);
    }
}
