//! The front-end on the Intel log with the default odometry noise: scan-to-map matching must
//! remove most of the odometry's drift (loop closing, which removes the rest, comes next).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_eval::{absolute_trajectory_error, add_odometry_noise, OdometryNoiseProfile};
use mapmerge_geometry::Se2;
use mapmerge_slam::{FrontEnd, FrontEndParams};

#[test]
fn scan_to_map_odometry_on_intel_beats_the_noisy_odometry() {
    let Some(path) = mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz") else {
        return;
    };
    let corrected_log = mapmerge_io::read_carmen(&path).unwrap();
    let corrected: Vec<Se2> = corrected_log
        .scans
        .iter()
        .map(|s| s.odom_from_robot.unwrap())
        .collect();
    let noisy = add_odometry_noise(&corrected_log, &OdometryNoiseProfile::default(), 0).unwrap();
    let mut front_end = FrontEnd::new(FrontEndParams::default()).unwrap();
    let started = std::time::Instant::now();
    for record in &noisy.log.scans {
        front_end
            .add_scan(&record.odom_from_robot.unwrap(), &record.scan)
            .unwrap();
    }
    let per_scan_ms = started.elapsed().as_secs_f64() * 1e3 / corrected.len() as f64;
    let estimate: Vec<Se2> = front_end
        .anchors()
        .trajectory(front_end.graph())
        .into_iter()
        .map(Option::unwrap)
        .collect();
    let odometry: Vec<Se2> = noisy
        .log
        .scans
        .iter()
        .map(|s| s.odom_from_robot.unwrap())
        .collect();
    let ate = absolute_trajectory_error(&corrected, &estimate, true).unwrap();
    let ate_odometry = absolute_trajectory_error(&corrected, &odometry, true).unwrap();
    let info = front_end.info();
    eprintln!(
        "intel default noise: front-end ATE {:.3} m, odometry ATE {:.3} m; {} keyframes, {} matched, {} odometry-only; {:.2} ms/scan",
        ate.rms_m, ate_odometry.rms_m, info.keyframes, info.matched, info.odometry_only, per_scan_ms
    );
    assert_eq!(estimate.len(), corrected.len());
    assert!(
        ate.rms_m < 0.5 * ate_odometry.rms_m,
        "{} vs {}",
        ate.rms_m,
        ate_odometry.rms_m
    );
}
