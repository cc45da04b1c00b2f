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

    /// `now_from_then` when `other` holds the same vertices and all of them moved together,
    /// i.e. `now_from_then · pose_then` is within the tolerances of every pose now (a
    /// re-optimisation that shifted the merged epochs as a whole): what was built from the
    /// snapshot still holds in the frame `now_from_then` maps it to. `None` otherwise.
    pub(crate) fn rigid_motion(
        &self,
        other: &[DetectorScan],
        translation_m: f64,
        rotation_rad: f64,
    ) -> Option<Se2> {
        if !self.same_vertices(other) || self.poses.is_empty() {
            return None;
        }
        // Least squares in 2D: the mean turn, then the translation between the centroids.
        let n = self.poses.len() as f64;
        let (mut sin, mut cos) = (0.0, 0.0);
        let (mut then_c, mut now_c) = (Point2::zeros(), Point2::zeros());
        for ((_, then), s) in self.poses.iter().zip(other) {
            let now = &s.map_from_robot;
            if !(then.is_finite() && now.is_finite()) {
                return None;
            }
            let turn = wrap_angle_rad(now.theta_rad - then.theta_rad);
            sin += turn.sin();
            cos += turn.cos();
            then_c += then.translation() / n;
            now_c += now.translation() / n;
        }
        let theta = sin.atan2(cos);
        let rotated = Se2::new(0.0, 0.0, theta).transform_point(&then_c);
        let now_from_then = Se2::new(now_c.x - rotated.x, now_c.y - rotated.y, theta);
        self.poses
            .iter()
            .zip(other)
            .all(|((_, then), s)| {
                !moved(
                    &now_from_then.compose(then),
                    &s.map_from_robot,
                    translation_m,
                    rotation_rad,
                )
            })
            .then_some(now_from_then)
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

/// Holoch's two kinds of evidence joined by a noisy-or, `1 − (1 − a)(1 − b)`: either alone can
/// flag a merge, both together flag it more surely (see [`crate::CombinedDetector`]).
pub(crate) fn noisy_or(a: f64, b: f64) -> f64 {
    unit(1.0 - (1.0 - unit(a)) * (1.0 - unit(b)))
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use proptest::prelude::*;

    use super::*;

    fn scans(poses: &[Se2]) -> Vec<DetectorScan> {
        poses
            .iter()
            .enumerate()
            .map(|(i, p)| DetectorScan {
                node: NodeId(i as u64),
                epoch: 1,
                map_from_robot: *p,
                points_in_robot: Arc::from(Vec::new()),
            })
            .collect()
    }

    proptest! {
        /// Poses moved together give back the motion; one pose moved apart gives none.
        #[test]
        fn rigid_motion_finds_a_shift_of_the_whole_and_refuses_a_deformation(
            x in -20.0f64..20.0, y in -20.0f64..20.0, theta in -3.1f64..3.1,
            poses in proptest::collection::vec((-30.0f64..30.0, -30.0f64..30.0, -3.1f64..3.1), 2..12),
        ) {
            let then: Vec<Se2> = poses.iter().map(|&(a, b, c)| Se2::new(a, b, c)).collect();
            let snapshot = OtherSnapshot::new(&scans(&then));
            let motion = Se2::new(x, y, theta);
            let now: Vec<Se2> = then.iter().map(|p| motion.compose(p)).collect();
            let found = snapshot.rigid_motion(&scans(&now), 0.01, 0.001).unwrap();
            prop_assert!((found.translation() - motion.translation()).norm() < 1e-6);
            prop_assert!(wrap_angle_rad(found.theta_rad - motion.theta_rad).abs() < 1e-9);
            let mut bent = now.clone();
            bent[0] = bent[0].compose(&Se2::new(0.5, 0.0, 0.0));
            prop_assert!(snapshot.rigid_motion(&scans(&bent), 0.01, 0.001).is_none());
            prop_assert!(snapshot.rigid_motion(&scans(&now[1..]), 0.01, 0.001).is_none());
        }
    }

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
