//! Planar TUM trajectories: write → read keeps stamps and positions exactly and yaw to
//! rounding; malformed lines give exact messages.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_io::{
    format_tum, format_tum_planar, parse_tum_planar, read_carmen, read_tum_planar,
    write_tum_planar, AnyGraph, IoError,
};
use mapmerge_posegraph::{NodeId, PoseGraph2, Vertex};
use proptest::prelude::*;

#[track_caller]
fn assert_close(a: &[(f64, Se2)], b: &[(f64, Se2)]) {
    assert_eq!(a.len(), b.len());
    for ((ta, pa), (tb, pb)) in a.iter().zip(b) {
        assert_eq!((ta, pa.x_m, pa.y_m), (tb, pb.x_m, pb.y_m));
        assert!(pa.between(pb).theta_rad.abs() < 1e-14, "{pa:?} vs {pb:?}");
    }
}

#[test]
fn carmen_trajectory_round_trips_through_a_file() {
    let Some(path) = mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz") else {
        return;
    };
    let log = read_carmen(&path).unwrap();
    let poses: Vec<(f64, Se2)> = log
        .scans
        .iter()
        .map(|r| (r.stamp_secs, r.odom_from_robot.unwrap()))
        .collect();
    let dir = std::env::temp_dir().join(format!("mapmerge-io-tum-{}", std::process::id()));
    let out = dir.join("intel.tum.xz");
    write_tum_planar(&out, &poses).unwrap();
    let back = read_tum_planar(&out).unwrap();
    assert_close(&poses, &back);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn reads_what_format_tum_writes_and_general_rotations() {
    let mut g = PoseGraph2::new();
    let mut v = Vertex::new(Se2::new(1.0, 2.0, -2.5));
    v.meta.stamp_secs = Some(3.5);
    g.add_vertex(NodeId(4), v).unwrap();
    let text = format_tum(&AnyGraph::Planar(g)).unwrap();
    let back = parse_tum_planar(&text, "g.tum").unwrap();
    assert_close(&back, &[(3.5, Se2::new(1.0, 2.0, -2.5))]);
    // z and roll/pitch are dropped; yaw is kept (rotation by 90° about z, then tilted).
    let text = "# stamp x y z qx qy qz qw\n\n1 5 6 7 0 0 0.7071067811865476 0.7071067811865476\n\
                2 0 0 0 0.0998334 0 0 0.9950042\n";
    let poses = parse_tum_planar(text, "t.tum").unwrap();
    assert!((poses[0].1.theta_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
    assert_eq!((poses[0].1.x_m, poses[0].1.y_m), (5.0, 6.0));
    assert!(poses[1].1.theta_rad.abs() < 1e-12);
    assert!(parse_tum_planar("", "e.tum").unwrap().is_empty());
}

#[track_caller]
fn expect_error(text: &str, message: &str) {
    match parse_tum_planar(text, "bad.tum") {
        Err(err @ IoError::Parse { .. }) => assert_eq!(err.to_string(), message),
        other => panic!("expected {message:?}, got {other:?}"),
    }
}

#[test]
fn malformed_lines_give_file_line_reason() {
    expect_error(
        "1 0 0 0 0 0 0\n",
        "bad.tum:1: expected 8 fields (stamp x y z qx qy qz qw), found 7",
    );
    expect_error(
        "# h\n1 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1 9\n",
        "bad.tum:3: expected 8 fields (stamp x y z qx qy qz qw), found 9",
    );
    expect_error(
        "t 0 0 0 0 0 0 1\n",
        "bad.tum:1: field 1 `t` is not a number",
    );
    expect_error(
        "1 0 nan 0 0 0 0 1\n",
        "bad.tum:1: field 3 `nan` is not a finite number",
    );
    expect_error(
        "1 0 0 0 0 0 0 2\n",
        "bad.tum:1: quaternion (0, 0, 0, 2) has norm 2, too far from 1 to normalise",
    );
    expect_error(
        "1 0 0 0 0 0 0 0\n",
        "bad.tum:1: quaternion (0, 0, 0, 0) has norm 0, too far from 1 to normalise",
    );
}

#[test]
fn non_finite_poses_are_unwritable() {
    let err = format_tum_planar(&[(f64::NAN, Se2::identity())]).unwrap_err();
    assert_eq!(
        err.to_string(),
        "cannot write the data as TUM: pose 0 has a non-finite pose or stamp"
    );
}

proptest! {
    #[test]
    fn random_trajectories_round_trip(
        poses in prop::collection::vec(
            (0.0..1e9_f64, -1e4..1e4_f64, -1e4..1e4_f64, -3.2..3.2_f64), 0..30)
    ) {
        let poses: Vec<(f64, Se2)> =
            poses.into_iter().map(|(t, x, y, th)| (t, Se2::new(x, y, th))).collect();
        let text = format_tum_planar(&poses).unwrap();
        let back = parse_tum_planar(&text, "p.tum").unwrap();
        assert_close(&poses, &back);
    }
}
