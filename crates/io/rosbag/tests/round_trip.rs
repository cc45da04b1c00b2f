//! Laser logs written as bags and read back: the same session, scan for scan.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::path::Path;

use common::{assert_same_session, LOGS};
use mapmerge_geometry::Se2;
use mapmerge_rosbag::{read_bag, write_bag, BagWriteParams, MountSource, TopicChoice};
use mapmerge_scan::{LaserLog, LaserScan, OdometryReading, ScanRecord};

fn round_trip(log: &LaserLog, name: &str, dir: &Path) {
    for extension in ["mcap", "db3"] {
        let path = dir.join(format!("{name}.{extension}"));
        let written = write_bag(&path, log, &BagWriteParams::default()).unwrap();
        let session = read_bag(&path, &TopicChoice::default()).unwrap();
        assert_eq!(session.info.scans_without_odometry, 0, "{name}");
        assert_same_session(log, &session.log, written.stamps_rewritten.is_none(), name);
        assert_eq!(session.info.scan_topic, "/scan");
        assert_eq!(session.info.odom_topic.as_deref(), Some("/odom"));
    }
}

#[test]
fn every_public_log_round_trips_through_mcap_and_db3() {
    let Some(dir) = mapmerge_testkit::shared_data_dir() else {
        return;
    };
    let out = tempfile::tempdir().unwrap();
    for name in LOGS {
        let log =
            mapmerge_io::read_carmen(&dir.join(format!("carmen/{name}-corrected.log.xz"))).unwrap();
        round_trip(&log, name, out.path());
    }
}

fn synthetic_log(scans: usize) -> LaserLog {
    let mut log = LaserLog::default();
    for k in 0..scans {
        let mut scan = LaserScan::new(
            -1.5,
            1.5,
            30.0,
            (0..31).map(|b| 1.0 + (k * b) as f32 * 0.01).collect(),
        );
        scan.robot_from_sensor = Se2::new(0.2, -0.05, 0.1);
        let pose = Se2::new(0.3 * k as f64, 0.1 * k as f64, 0.05 * k as f64);
        log.scans.push(ScanRecord {
            stamp_secs: 10.0 + 0.1 * k as f64,
            scan,
            odom_from_robot: Some(pose),
            source_tag: "FLASER".into(),
        });
    }
    log
}

#[test]
fn a_synthetic_log_round_trips_with_its_stamps_and_mount() {
    let out = tempfile::tempdir().unwrap();
    round_trip(&synthetic_log(20), "synthetic", out.path());
    let session = read_bag(&out.path().join("synthetic.mcap"), &TopicChoice::default()).unwrap();
    assert_eq!(session.info.mount_from, MountSource::TfStatic);
    assert_eq!(
        (
            session.info.laser_frame.as_str(),
            session.info.base_frame.as_str()
        ),
        ("laser", "base_link")
    );
}

#[test]
fn odometry_messages_pair_with_scans_by_interpolation() {
    // Scans without poses, odometry at other stamps: each scan gets the pose between.
    let mut log = synthetic_log(5);
    for record in &mut log.scans {
        record.odom_from_robot = None;
    }
    log.odometry = (0..12)
        .map(|k| OdometryReading {
            stamp_secs: 9.95 + 0.05 * k as f64,
            odom_from_robot: Se2::new(k as f64, 0.0, 0.0),
            velocity_m_per_s: 0.0,
            turn_rate_rad_per_s: 0.0,
        })
        .collect();
    let out = tempfile::tempdir().unwrap();
    let path = out.path().join("odom.db3");
    write_bag(&path, &log, &BagWriteParams::default()).unwrap();
    let session = read_bag(&path, &TopicChoice::default()).unwrap();
    // Scan k, at 10.0 + 0.1 k s, falls on odometry message 1 + 2k (at x = 1 + 2k m); stamps
    // in between would interpolate (the unit test of `pose_at`).
    let xs: Vec<f64> = session
        .log
        .scans
        .iter()
        .map(|r| r.odom_from_robot.unwrap().x_m)
        .collect();
    for (k, x) in xs.iter().enumerate() {
        assert!((x - (1 + 2 * k) as f64).abs() < 1e-6, "scan {k}: {x}");
    }
    // Odometry ending at 10.3 s: scan 4 (10.4 s) is 0.1 s past it, beyond the hold, left out.
    log.odometry.truncate(8);
    write_bag(&path, &log, &BagWriteParams::default()).unwrap();
    let session = read_bag(&path, &TopicChoice::default()).unwrap();
    assert_eq!(
        (session.log.scans.len(), session.info.scans_without_odometry),
        (4, 1)
    );
}

#[test]
fn bags_with_missing_topics_or_bad_files_are_errors_naming_the_file() {
    let out = tempfile::tempdir().unwrap();
    let path = out.path().join("x.mcap");
    write_bag(&path, &synthetic_log(3), &BagWriteParams::default()).unwrap();
    let err = read_bag(
        &path,
        &TopicChoice {
            scan_topic: Some("/laser".into()),
            odom_topic: None,
        },
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("x.mcap") && err.contains("no topic '/laser'"),
        "{err}"
    );
    // Truncated files: an error, never a panic.
    let bytes = std::fs::read(&path).unwrap();
    for cut in [0, 8, 100, bytes.len() / 2, bytes.len() - 1] {
        std::fs::write(&path, &bytes[..cut]).unwrap();
        assert!(
            read_bag(&path, &TopicChoice::default()).is_err(),
            "cut at {cut}"
        );
    }
    let err = read_bag(&out.path().join("absent.db3"), &TopicChoice::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("absent.db3"), "{err}");
}

#[test]
fn clouds_and_their_poses_round_trip_through_both_storages() {
    use mapmerge_geometry::{LieGroup as _, Se3};
    use nalgebra::{UnitQuaternion, Vector3};
    let poses: Vec<Se3> = (0..4)
        .map(|k| {
            Se3::new(
                UnitQuaternion::from_euler_angles(0.01 * k as f64, -0.02, 0.3 * k as f64),
                Vector3::new(k as f64, 0.5, 1.7),
            )
        })
        .collect();
    let clouds: Vec<Vec<Vector3<f64>>> = (0..4)
        .map(|k| {
            (0..50)
                .map(|i| Vector3::new(i as f64 * 0.25, k as f64 - 2.0, 0.125 * i as f64))
                .collect()
        })
        .collect();
    let out = tempfile::tempdir().unwrap();
    for extension in ["mcap", "db3"] {
        let path = out.path().join(format!("clouds.{extension}"));
        mapmerge_rosbag::write_cloud_bag(&path, &poses, &clouds, &BagWriteParams::default())
            .unwrap();
        let topics = mapmerge_rosbag::list_topics(&path).unwrap();
        assert!(
            topics
                .iter()
                .any(|t| t.name == "/points" && t.messages == 4),
            "{topics:?}"
        );
        let session = mapmerge_rosbag::read_cloud_session(&path, None, None).unwrap();
        assert_eq!(session.clouds.len(), 4);
        for (k, (pose, cloud)) in session
            .odom_from_sensor
            .iter()
            .zip(&session.clouds)
            .enumerate()
        {
            assert!(pose.between(&poses[k]).log().norm() < 1e-9, "pose {k}");
            assert_eq!(
                cloud.points, clouds[k],
                "cloud {k}: its values are float32-exact"
            );
        }
        // A laser reader refuses it, naming what is missing.
        let err = read_bag(&path, &TopicChoice::default())
            .unwrap_err()
            .to_string();
        assert!(err.contains("no sensor_msgs/msg/LaserScan topic"), "{err}");
    }
}
