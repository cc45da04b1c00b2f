//! `mapmerge ros2` against an independent DDS: Cyclone DDS's Python binding publishes a public
//! log in real time (or robots' maps) with ROS 2's topic and type names
//! (`scripts/ros2_peer.py`), and what it hears back is judged against the offline commands on
//! the same data. `MAPMERGE_ROS2_PYTHON` names a Python with `cyclonedds` and
//! `mcap-ros2-support` (`.ci/run` makes one); without it the tests skip, except under
//! `CI=true`.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::AtomicBool;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::ClassThresholds;
use mapmerge_lab::live_judge::grid_agreement;
use mapmerge_ros2::{
    run_merge_node, run_slam_node, Delivery, MergeNodeOptions, RobotState, SlamNodeOptions,
};

fn peer_script() -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../scripts/ros2_peer.py"
    ))
}

fn python() -> Option<PathBuf> {
    mapmerge_testkit::tool_from_env(
        "MAPMERGE_ROS2_PYTHON",
        "a Python with cyclonedds and mcap-ros2-support",
    )
}

/// A DDS domain of this test process alone (tests of one run use `offset` apart).
fn domain(offset: u16) -> u16 {
    100 + (std::process::id() % 50) as u16 * 2 + offset
}

fn run_peer(python: &Path, domain: u16, args: &[&str]) -> std::process::Child {
    Command::new(python)
        .arg(peer_script())
        .arg("--domain")
        .arg(domain.to_string())
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap()
}

/// The first 600 scans of intel with seeded noisy odometry, as a bag: played live by the
/// peer to the node with a store, and mapped offline by `slam` (the bag read back, so both
/// see the same messages). The session is committed when the node stops.
#[test]
fn the_live_map_agrees_with_the_offline_slam_map_of_the_same_bag() {
    let Some(python) = python() else { return };
    let Some(path) = mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let mut log = mapmerge_io::read_carmen(&path).unwrap();
    log.scans.truncate(600);
    let noisy = mapmerge_lab::slam_judge::noisy_session(&log, "default", 1).unwrap();
    let bag = dir.path().join("intel-600.mcap");
    mapmerge_rosbag::write_bag(&bag, &noisy.log, &Default::default()).unwrap();

    let offline_log = mapmerge_jobs::read_session_log(&bag).unwrap();
    let run = mapmerge_jobs::slam_log(&bag, &offline_log, Default::default(), |_| {}).unwrap();
    let (offline, _) = mapmerge_jobs::build_grid(
        &offline_log,
        &run.trajectory,
        0.05,
        &Default::default(),
        || {},
    )
    .unwrap();

    let domain = domain(0);
    let options = SlamNodeOptions {
        domain,
        delivery: Delivery::Reliable,
        quiet_s: Some(2.0),
        duration_s: Some(600.0),
        map_period_s: 2.0,
        store: Some(dir.path().join("site.mapmerge")),
        ..Default::default()
    };
    let stop = AtomicBool::new(false);
    let (map_yaml, peer_report) = (dir.path().join("live.yaml"), dir.path().join("peer.json"));
    let peer = run_peer(
        &python,
        domain,
        &[
            "play",
            bag.to_str().unwrap(),
            "--rate",
            "4",
            "--map-out",
            map_yaml.to_str().unwrap(),
            "--report",
            peer_report.to_str().unwrap(),
        ],
    );
    let mut said = Vec::new();
    let (report, node_map) =
        run_slam_node(&options, &stop, |line| said.push(line.to_owned())).unwrap();
    let output = peer.wait_with_output().unwrap();
    assert!(
        output.status.success(),
        "peer: {}\nnode: {said:?} {report:?}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert_eq!(report.scans_heard, 600, "{report:?}");
    assert_eq!(report.scans_mapped, 600, "{report:?}");
    // The session was committed to the store at the end.
    let versions = mapmerge_jobs::open_store(&dir.path().join("site.mapmerge"))
        .unwrap()
        .versions()
        .unwrap();
    assert_eq!(versions.len(), 1, "{report:?}");
    assert_eq!(
        report.committed.as_ref().map(|c| c.version.version),
        Some(versions[0].version)
    );
    let peer: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&peer_report).unwrap()).unwrap();
    assert_eq!(peer["poses_received"], 600, "{peer}");

    let live = mapmerge_io::read_ros_map(&map_yaml)
        .unwrap()
        .to_grid()
        .unwrap();
    let agreement = grid_agreement(&live, &offline, &ClassThresholds::default()).unwrap();
    eprintln!(
        "live /map against offline slam: {agreement:?}; pose latency {:?}; peer's p99 {:?} ms",
        report.pose_latency,
        peer["latency_ms"]
            .as_array()
            .map(|l| l[(l.len() * 99).div_ceil(100).max(1) - 1].clone())
    );
    let node_agreement =
        grid_agreement(&node_map.unwrap(), &offline, &ClassThresholds::default()).unwrap();
    eprintln!("the node's own last map against offline slam: {node_agreement:?}");
    assert!(agreement.fraction >= 0.99, "{agreement:?}: {report:?}");
    assert!(node_agreement.fraction >= 0.99, "{node_agreement:?}");
}

/// Three robots' maps: a building map, its copy turned by 37°, moved and at twice the cell
/// size (as `grid-merge`'s own test), and another building. The node, hearing them as
/// `/robot1/map`, `/robot2/map` and `/robot3/map`, must place robot2 where `grid-merge` of the
/// two files does, and say why robot3 is not merged.
#[test]
fn robots_merged_live_give_grid_merges_transform_and_say_why_not() {
    let Some(python) = python() else { return };
    let (Some(yaml), Some(other_building)) = (
        mapmerge_testkit::shared_data("gridmaps/intel-bwi/intel.yaml"),
        mapmerge_testkit::shared_data("gridmaps/utexas-gdc-1s/1s.yaml"),
    ) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let a = mapmerge_io::read_ros_map(&yaml).unwrap().to_grid().unwrap();
    let b_yaml = dir.path().join("b.yaml");
    let b =
        mapmerge_lab::live_judge::turned_copy(&a, &Se2::new(3.2, -1.7, 37f64.to_radians()), 2.0)
            .unwrap();
    mapmerge_io::write_ros_map(
        &b_yaml,
        &mapmerge_io::RosMap::from_grid(
            &b,
            mapmerge_io::MapMode::Trinary,
            &ClassThresholds::default(),
        ),
    )
    .unwrap();
    let offline = mapmerge_jobs::grid_merge(&yaml, &b_yaml, &Default::default(), 0, None).unwrap();
    assert!(offline.report.accepted, "{:?}", offline.report);
    let expected = offline.report.transform.unwrap();

    let domain = domain(1);
    let (map_yaml, peer_report) = (dir.path().join("merged.yaml"), dir.path().join("peer.json"));
    let peer = run_peer(
        &python,
        domain,
        &[
            "maps",
            &format!("robot1={}", yaml.display()),
            &format!("robot2={}", b_yaml.display()),
            &format!("robot3={}", other_building.display()),
            "--seconds",
            "40",
            "--map-out",
            map_yaml.to_str().unwrap(),
            "--report",
            peer_report.to_str().unwrap(),
        ],
    );
    let options = MergeNodeOptions {
        domain,
        duration_s: Some(35.0),
        ..Default::default()
    };
    let stop = AtomicBool::new(false);
    let mut said = Vec::new();
    let report = run_merge_node(&options, &stop, |line| said.push(line.to_owned())).unwrap();
    let output = peer.wait_with_output().unwrap();
    assert!(
        output.status.success(),
        "peer: {}\nnode: {said:?}",
        String::from_utf8_lossy(&output.stderr)
    );
    let robot2 = report.robots.iter().find(|r| r.robot == "robot2").unwrap();
    assert_eq!(robot2.state, RobotState::Merged, "{said:?}");
    let live = robot2.transform.unwrap();
    let error =
        Se2::new(expected.x, expected.y, expected.yaw).between(&Se2::new(live.x, live.y, live.yaw));
    eprintln!("live robot2 {live:?}, grid-merge {expected:?}, error {error:?}");
    assert!(error.translation().norm() <= 0.05, "{error:?}");
    assert!(error.theta_rad.abs() <= 1f64.to_radians(), "{error:?}");
    // robot3 maps another building: not merged, and the report says why.
    let robot3 = report.robots.iter().find(|r| r.robot == "robot3").unwrap();
    assert_eq!(robot3.state, RobotState::NotMerged, "{said:?}");
    let reason = robot3.reason.as_deref().unwrap();
    assert!(reason.starts_with("against robot"), "{reason}");
    assert!(
        said.iter()
            .any(|line| line.starts_with("robot robot3: not merged")),
        "{said:?}"
    );
    // What the peer heard: the merged map, and each robot's state as events.
    let peer: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&peer_report).unwrap()).unwrap();
    assert!(
        peer["events"]
            .as_array()
            .unwrap()
            .iter()
            .any(|e| e["robot"]["state"] == "merged"),
        "{peer}"
    );
    let merged = mapmerge_io::read_ros_map(&map_yaml).unwrap();
    assert!(merged.width >= a.geometry().width, "{peer}");
}
