//! What the bag tests share: the public logs, and "the same session" as a bag can hold it.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_geometry::{LieGroup as _, Se2};
use mapmerge_scan::LaserLog;

pub use mapmerge_testkit::PUBLIC_LOGS as LOGS;

/// Largest difference (m, rad) between two poses.
fn pose_gap(a: &Se2, b: &Se2) -> f64 {
    let d = a.between(b);
    d.x_m.abs().max(d.y_m.abs()).max(d.theta_rad.abs())
}

/// Asserts that `back` is `original` as a bag can hold it: ranges, beam angles and poses bit
/// for bit, mounts to 1 mm (one `/tf_static` for all scans), stamps to the
/// microsecond unless they were rewritten.
pub fn assert_same_session(original: &LaserLog, back: &LaserLog, stamps_kept: bool, name: &str) {
    assert_eq!(original.scans.len(), back.scans.len(), "{name}: scan count");
    for (i, (a, b)) in original.scans.iter().zip(&back.scans).enumerate() {
        assert_eq!(a.scan.ranges_m, b.scan.ranges_m, "{name}: scan {i} ranges");
        assert_eq!(a.scan.range_max_m, b.scan.range_max_m, "{name}: scan {i}");
        assert_eq!(a.scan.range_min_m, b.scan.range_min_m, "{name}: scan {i}");
        // The reader recovers the angles from their float32 values (`angle_rad_of`).
        assert_eq!(
            a.scan.angle_min_rad, b.scan.angle_min_rad,
            "{name}: scan {i}"
        );
        assert_eq!(
            a.scan.angle_increment_rad, b.scan.angle_increment_rad,
            "{name}: scan {i}"
        );
        assert!(
            pose_gap(&a.scan.robot_from_sensor, &b.scan.robot_from_sensor) < 1e-3,
            "{name}: scan {i} mount"
        );
        match (&a.odom_from_robot, &b.odom_from_robot) {
            // `Quaternion::from_yaw` writes headings that read back bit for bit.
            (Some(p), Some(q)) => assert_eq!(p, q, "{name}: scan {i}"),
            (p, q) => assert_eq!(p.is_some(), q.is_some(), "{name}: scan {i} pose"),
        }
        if stamps_kept {
            assert!(
                (a.stamp_secs - b.stamp_secs).abs() < 1e-6,
                "{name}: scan {i} stamp"
            );
        }
    }
}
