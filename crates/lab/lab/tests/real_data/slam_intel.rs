//! SLAM (the engine with one epoch) end to end on real data: the Intel log with the default odometry noise.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_engine::{run_slam, EngineParams};
use mapmerge_eval::{absolute_trajectory_error, add_odometry_noise, OdometryNoiseProfile};
use mapmerge_geometry::{LieGroup, Se2};

#[test]
fn slam_on_intel_closes_loops_and_beats_the_noisy_odometry_tenfold() {
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
    let run = run_slam(&noisy.log, EngineParams::default(), |_| {}).unwrap();
    let ate = absolute_trajectory_error(&corrected, &run.trajectory, true).unwrap();
    let ate_odometry =
        absolute_trajectory_error(&corrected, &noisy.odometry_poses(), true).unwrap();
    eprintln!(
        "intel default noise: SLAM ATE {:.3} m, odometry ATE {:.3} m; {:?}",
        ate.rms_m, ate_odometry.rms_m, run.info
    );
    assert_eq!(run.trajectory.len(), corrected.len());
    assert!(ate.rms_m < 0.12, "{}", ate.rms_m);
    assert!(ate.rms_m * 10.0 < ate_odometry.rms_m);
    // Loops were closed, and every one is true by the rule: within 0.5 m and 10° of
    // the corrected relative pose.
    assert!(run.loops.len() > 100, "{}", run.loops.len());
    for record in &run.loops {
        let scan =
            |node: mapmerge_posegraph::NodeId| corrected[run.keyframe_scans[node.0 as usize]];
        let error = scan(record.from)
            .between(&scan(record.to))
            .between(&record.measurement);
        assert!(
            error.translation().norm() <= 0.5 && error.theta_rad.abs() <= 10f64.to_radians(),
            "{record:?}: {error:?}"
        );
    }
}
