//! The front-end on the Intel log with the default odometry noise: scan-to-map matching must
//! remove most of the odometry's drift (loop closing, which removes the rest, comes next).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_eval::{absolute_trajectory_error, add_odometry_noise, OdometryNoiseProfile};
use mapmerge_geometry::Se2;
use mapmerge_slam::{run_front_end, FrontEndParams};

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
    let run = run_front_end(&noisy.log, FrontEndParams::default()).unwrap();
    let ate = absolute_trajectory_error(&corrected, &run.trajectory, true).unwrap();
    let ate_odometry =
        absolute_trajectory_error(&corrected, &noisy.odometry_poses(), true).unwrap();
    eprintln!(
        "intel default noise: front-end ATE {:.3} m, odometry ATE {:.3} m; {:?}",
        ate.rms_m, ate_odometry.rms_m, run.info
    );
    assert_eq!(run.trajectory.len(), corrected.len());
    assert!(
        ate.rms_m < 0.5 * ate_odometry.rms_m,
        "{} vs {}",
        ate.rms_m,
        ate_odometry.rms_m
    );
}
