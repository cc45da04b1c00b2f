//! SLAM (the engine with one epoch) on the simulated office session the repository carries (noisy odometry,
//! wheel slips, exact ground truth): runs without the shared data.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use mapmerge_engine::{run_slam, EngineParams};
use mapmerge_eval::absolute_trajectory_error;
use mapmerge_geometry::Se2;

fn testdata(name: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../testdata")).join(name)
}

#[test]
fn simulated_session_is_mapped_within_ten_centimetres() {
    let log = mapmerge_io::read_carmen(&testdata("sim/office-aliased/session_0.log.xz")).unwrap();
    let truth: Vec<Se2> =
        mapmerge_io::read_tum_planar(&testdata("sim/office-aliased/session_0.truth.tum"))
            .unwrap()
            .into_iter()
            .map(|(_, pose)| pose)
            .collect();
    let odometry: Vec<Se2> = log
        .scans
        .iter()
        .map(|s| s.odom_from_robot.unwrap())
        .collect();
    let run = run_slam(&log, EngineParams::default(), |_| {}).unwrap();
    let ate = absolute_trajectory_error(&truth, &run.trajectory, true).unwrap();
    let ate_odometry = absolute_trajectory_error(&truth, &odometry, true).unwrap();
    eprintln!(
        "simulated session 0: SLAM ATE {:.3} m, odometry {:.3} m, {:?}",
        ate.rms_m, ate_odometry.rms_m, run.info
    );
    assert!(ate.rms_m < 0.1, "{}", ate.rms_m);
    assert!(ate.rms_m * 5.0 < ate_odometry.rms_m);
    assert!(run.info.constraints.local_loops > 0);
    // Every scan hangs on a keyframe of the graph.
    assert_eq!(run.trajectory.len(), log.scans.len());
    assert_eq!(run.keyframe_scans.len(), run.graph.num_vertices());
}
