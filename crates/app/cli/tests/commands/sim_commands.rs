//! Integration tests of `mapmerge sim`: the checked-in data set, determinism, and a grid built
//! from a simulated log that lands on the simulated world's walls.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;

use crate::common::{ok_json, p, run, scratch, testdata};
use mapmerge_grid::{CellClass, ClassThresholds};

/// The arguments that made `testdata/sim/office-aliased` (see README.md).
const TESTDATA_ARGS: [&str; 10] = [
    "--world",
    "office-aliased",
    "--sessions",
    "3",
    "--seed",
    "12",
    "--duration",
    "120",
    "--compress",
    "--no-pictures",
];

/// Asserts two data-set folders hold the same data (logs compared after parsing, since xz
/// bytes may differ between library versions).
fn assert_same_dataset(a: &Path, b: &Path) {
    for k in 0..3 {
        let log = format!("session_{k}.log.xz");
        assert_eq!(
            mapmerge_io::read_carmen(&a.join(&log)).unwrap(),
            mapmerge_io::read_carmen(&b.join(&log)).unwrap(),
            "{log}"
        );
        let truth = format!("session_{k}.truth.tum");
        assert_eq!(
            std::fs::read(a.join(&truth)).unwrap(),
            std::fs::read(b.join(&truth)).unwrap(),
            "{truth}"
        );
    }
    for yaml in ["world.yaml", "session_1.world.yaml", "session_2.world.yaml"] {
        let (ma, mb) = (
            mapmerge_io::read_ros_map(&a.join(yaml)).unwrap(),
            mapmerge_io::read_ros_map(&b.join(yaml)).unwrap(),
        );
        assert_eq!(ma.pixels, mb.pixels, "{yaml}");
    }
    assert_eq!(
        std::fs::read_to_string(a.join("dataset.json")).unwrap(),
        std::fs::read_to_string(b.join("dataset.json")).unwrap()
    );
}

#[test]
fn checked_in_sim_testdata_is_what_sim_writes() {
    let dir = scratch("sim-testdata");
    let mut args = vec!["sim"];
    args.extend(TESTDATA_ARGS);
    args.extend(["-o", p(&dir), "--json"]);
    let report = ok_json(&args);
    assert_eq!(
        (report["sessions"].as_u64(), report["scans"].as_u64()),
        (Some(3), Some(3603))
    );
    assert_same_dataset(&testdata("sim/office-aliased"), &dir);
}

#[test]
fn sim_is_deterministic_and_refuses_unknown_worlds() {
    let (a, b, c) = (scratch("sim-a"), scratch("sim-b"), scratch("sim-c"));
    for (seed, dir) in [("3", &a), ("3", &b), ("4", &c)] {
        ok_json(&[
            "sim",
            "--world",
            "corridor-loop",
            "--sessions",
            "2",
            "--duration",
            "20",
            "--seed",
            seed,
            "-o",
            p(dir),
            "--json",
        ]);
    }
    for name in [
        "session_0.log",
        "session_1.truth.tum",
        "world.pgm",
        "dataset.json",
        "session_0.png",
    ] {
        assert_eq!(
            std::fs::read(a.join(name)).unwrap(),
            std::fs::read(b.join(name)).unwrap(),
            "{name}"
        );
    }
    assert_ne!(
        std::fs::read(a.join("session_0.log")).unwrap(),
        std::fs::read(c.join("session_0.log")).unwrap()
    );

    let out = run(&["sim", "--world", "castle", "-o", p(&a)]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("castle") && stderr.contains("office-aliased"),
        "{stderr}"
    );
}

#[test]
fn a_grid_from_the_simulated_log_and_true_poses_lands_on_the_world_s_walls() {
    let data = testdata("sim/office-aliased");
    let dir = scratch("sim-grid");
    let yaml = dir.join("map.yaml");
    ok_json(&[
        "grid",
        "--log",
        p(&data.join("session_0.log.xz")),
        "--poses",
        p(&data.join("session_0.truth.tum")),
        "-o",
        p(&yaml),
        "--png",
        p(&dir.join("map.png")),
        "--json",
    ]);
    let thresholds = ClassThresholds::default();
    let built = mapmerge_io::read_ros_map(&yaml).unwrap().to_grid().unwrap();
    let world = mapmerge_io::read_ros_map(&data.join("world.yaml"))
        .unwrap()
        .to_grid()
        .unwrap();
    // Walls of the true world, grown by one cell (5 cm) for the lidar's 1.5 cm noise.
    let walls = world.mask(CellClass::Occupied, &thresholds).dilate(1);
    let occupied: Vec<_> = built
        .cells()
        .filter(|&(_, _, l)| thresholds.classify(l) == CellClass::Occupied)
        .collect();
    let on_walls = occupied
        .iter()
        .filter(|(_, centre, _)| walls.is_set(world.geometry().cell_of(centre)))
        .count();
    let fraction = on_walls as f64 / occupied.len() as f64;
    assert!(
        occupied.len() > 3000 && fraction > 0.98,
        "{on_walls} of {} occupied cells on the world's walls",
        occupied.len()
    );
    // And free space is free in the world.
    let free_in_world = world.mask(CellClass::Free, &thresholds).dilate(1);
    let free: Vec<_> = built
        .cells()
        .filter(|&(_, _, l)| thresholds.classify(l) == CellClass::Free)
        .collect();
    let agree = free
        .iter()
        .filter(|(_, centre, _)| free_in_world.is_set(world.geometry().cell_of(centre)))
        .count();
    assert!(
        agree as f64 > 0.99 * free.len() as f64,
        "{agree} of {} free cells free in the world",
        free.len()
    );
}

/// `--corrected-log`: every session's scans, in order, at the true poses of the TUM files,
/// stamps increasing across sessions.
#[test]
fn the_corrected_log_holds_every_scan_at_its_true_pose() {
    let dir = scratch("sim-corrected");
    ok_json(&[
        "sim",
        "--world",
        "office-aliased",
        "--sessions",
        "2",
        "--duration",
        "30",
        "--seed",
        "5",
        "--no-pictures",
        "--corrected-log",
        "-o",
        p(&dir),
        "--json",
    ]);
    let corrected = mapmerge_io::read_carmen(&dir.join("corrected.log")).unwrap();
    let mut truth = Vec::new();
    let mut scans = Vec::new();
    for k in 0..2 {
        let session = mapmerge_io::read_carmen(&dir.join(format!("session_{k}.log"))).unwrap();
        scans.extend(session.scans.into_iter().map(|r| r.scan.ranges_m));
        let tum = mapmerge_io::read_tum_planar(&dir.join(format!("session_{k}.truth.tum")));
        truth.extend(tum.unwrap().into_iter().map(|(_, pose)| pose));
    }
    assert_eq!(corrected.scans.len(), truth.len());
    for (k, record) in corrected.scans.iter().enumerate() {
        let pose = record.odom_from_robot.unwrap();
        let error = pose.translation() - truth[k].translation();
        assert!(error.norm() < 1e-3, "scan {k}: {pose:?} vs {:?}", truth[k]);
        assert_eq!(record.scan.ranges_m, scans[k], "scan {k}");
    }
    assert!(corrected
        .scans
        .windows(2)
        .all(|w| w[1].stamp_secs > w[0].stamp_secs));
    let dataset: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("dataset.json")).unwrap()).unwrap();
    assert_eq!(dataset["corrected_log"], "corrected.log");
}

#[test]
fn dataset_json_lists_the_doors_and_every_passing_of_one() {
    let dir = testdata("sim/office-aliased");
    let dataset: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("dataset.json")).unwrap()).unwrap();
    let doors = dataset["doors"].as_array().unwrap();
    assert!(!doors.is_empty());
    let ids: Vec<u64> = doors.iter().map(|d| d["id"].as_u64().unwrap()).collect();
    for door in doors {
        assert!(door["width_m"].as_f64().unwrap() > 0.5, "{door}");
    }
    // Each passing names a door, and the true pose at its scan lies within a door's width of
    // that door's centre (the robot moves about 8 cm a scan).
    let mut passings = 0;
    for session in dataset["sessions"].as_array().unwrap() {
        let truth =
            mapmerge_io::read_tum_planar(&dir.join(session["truth"].as_str().unwrap())).unwrap();
        for passing in session["door_passings"].as_array().unwrap() {
            let door_id = passing["door"].as_u64().unwrap();
            let door = &doors[ids.iter().position(|i| *i == door_id).unwrap()];
            let scan = passing["scan"].as_u64().unwrap() as usize;
            let pose = truth[scan].1;
            let distance = ((pose.x_m - door["x"].as_f64().unwrap()).powi(2)
                + (pose.y_m - door["y"].as_f64().unwrap()).powi(2))
            .sqrt();
            assert!(
                distance < door["width_m"].as_f64().unwrap(),
                "{passing}: {distance} m"
            );
            passings += 1;
        }
    }
    assert!(passings >= 3, "{passings} passings");
}

#[test]
fn eval_doors_scores_detection_against_the_simulators_doors() {
    let report = ok_json(&[
        "eval",
        "doors",
        "--worlds",
        "office",
        "--seeds",
        "1",
        "--sessions",
        "1",
        "--duration",
        "60",
        "--json",
    ]);
    let total = &report["total"];
    let (passings, detections, true_detections) = (
        total["passings"].as_u64().unwrap(),
        total["detections"].as_u64().unwrap(),
        total["true_detections"].as_u64().unwrap(),
    );
    assert!(passings > 0);
    assert!(true_detections <= detections.min(passings));
    assert!(report["precision"].as_f64().unwrap() >= 0.5, "{report}");
    assert!(report["recall"].as_f64().unwrap() >= 0.5, "{report}");
    let bad = run(&["eval", "doors", "--worlds", "no-such-world", "--seeds", "1"]);
    assert_eq!(bad.status.code(), Some(2), "an unknown world is bad input");
}
