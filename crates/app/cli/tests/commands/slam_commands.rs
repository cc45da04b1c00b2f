//! Integration tests of `mapmerge slam`: the simulated session the repository carries, a
//! public corrected log with added odometry noise (scored against its own poses), bad input.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common::{ok_json, p, run, scratch, testdata};

#[test]
fn slam_on_the_simulated_session_writes_graph_map_picture_and_trajectory() {
    let dir = scratch("slam-sim");
    let log = testdata("sim/office-aliased/session_0.log.xz");
    let report = ok_json(&["slam", p(&log), "-o", p(&dir), "--json"]);
    assert_eq!(report["scans"], 1201, "{report}");
    let front_end = &report["front_end"];
    assert!(front_end["keyframes"].as_u64().unwrap() > 100, "{report}");
    assert!(front_end["local_loops"].as_u64().unwrap() > 0, "{report}");
    for file in [
        "graph.g2o",
        "map.yaml",
        "map.pgm",
        "map.png",
        "trajectory.tum",
    ] {
        assert!(dir.join(file).is_file(), "{file} missing");
    }
    // One pose per scan, line k = scan k, stamped with the scan's time; close to the truth.
    let trajectory = mapmerge_io::read_tum_planar(&dir.join("trajectory.tum")).unwrap();
    assert_eq!(trajectory.len(), 1201);
    let truth = testdata("sim/office-aliased/session_0.truth.tum");
    let ate = ok_json(&[
        "eval",
        "ate",
        "--trajectory",
        p(&dir.join("trajectory.tum")),
        "--reference",
        p(&truth),
        "--json",
    ]);
    let rms = ate["ate"]["rms_m"].as_f64().unwrap();
    assert!(rms < 0.1, "ATE {rms} m: {ate}");
    // The graph reads back with the keyframes as vertices.
    let graph = mapmerge_io::read_graph(&dir.join("graph.g2o")).unwrap();
    assert_eq!(
        graph.graph.num_vertices() as u64,
        front_end["keyframes"].as_u64().unwrap()
    );
}

#[test]
fn slam_with_odometry_noise_scores_against_the_corrected_log() {
    let Some(log) = mapmerge_testkit::shared_data("carmen/freiburg-101-corrected.log.xz") else {
        return;
    };
    let dir = scratch("slam-fr101");
    let report = ok_json(&[
        "slam",
        p(&log),
        "-o",
        p(&dir),
        "--odometry-noise",
        "default",
        "--seed",
        "0",
        "--json",
    ]);
    let ours = report["score"]["ate"]["rms_m"].as_f64().unwrap();
    let odometry = report["odometry_score"]["ate"]["rms_m"].as_f64().unwrap();
    assert!(ours < 0.08, "{report}");
    assert!(ours * 10.0 < odometry, "{report}");
    assert!(report["score"]["relations"]["count"].as_u64().unwrap() > 100);
}

#[test]
fn slam_refuses_bad_input_with_exit_code_2() {
    let dir = scratch("slam-bad");
    let missing = dir.join("missing.log");
    let out = run(&["slam", p(&missing), "-o", p(&dir)]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("missing.log"));
    let empty = dir.join("empty.log");
    std::fs::write(&empty, "# nothing\n").unwrap();
    let out = run(&["slam", p(&empty), "-o", p(&dir)]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no laser scans"));
    let log = testdata("sim/office-aliased/session_0.log.xz");
    let out = run(&["slam", p(&log), "-o", p(&dir), "--odometry-noise", "gentle"]);
    assert_eq!(out.status.code(), Some(2));
}

/// Issue 67: the same config out of range is refused alike by slam, atlas and a store run:
/// exit code 2, the config file and the field's path named, nothing written.
#[test]
fn a_config_out_of_range_is_refused_alike_by_every_command() {
    let dir = scratch("config-range");
    let config = dir.join("bad.json");
    std::fs::write(&config, r#"{"decisions": {"probation_m": -5}}"#).unwrap();
    let log = testdata("sim/office-aliased/session_0.log.xz");
    let out_dir = dir.join("out");
    let store = dir.join("site.db");
    for args in [
        vec!["slam", p(&log), "-o", p(&out_dir), "--config", p(&config)],
        vec![
            "atlas",
            p(&log),
            "-o",
            p(&out_dir),
            "--no-pictures",
            "--config",
            p(&config),
        ],
        vec![
            "atlas",
            p(&log),
            "-o",
            p(&out_dir),
            "--store",
            p(&store),
            "--no-pictures",
            "--config",
            p(&config),
        ],
    ] {
        let out = run(&args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains("bad.json"), "{stderr}");
        assert!(stderr.contains("`decisions.probation_m` = -5"), "{stderr}");
        assert!(!out_dir.join("graph.g2o").exists() && !store.exists());
    }
}

/// Issue 67: an output the command cannot write is refused before any work, with exit code 2
/// and the path: a file where a folder goes, a folder where a file goes, a folder under a file.
#[test]
fn outputs_that_cannot_be_written_are_refused_before_the_work() {
    let dir = scratch("outputs-bad");
    let file = dir.join("a-file");
    std::fs::write(&file, "not a folder").unwrap();
    let log = testdata("sim/office-aliased/session_0.log.xz");
    let graph = testdata("sim_manhattan_500.g2o");
    let under_file = file.join("out");
    for args in [
        vec!["slam", p(&log), "-o", p(&file)],
        vec!["slam", p(&log), "-o", p(&under_file)],
        vec!["atlas", p(&log), "-o", p(&file), "--no-pictures"],
        vec!["optimize", p(&graph), "-o", p(&dir)],
        vec!["optimize", p(&graph), "-o", p(&under_file)],
    ] {
        let out = run(&args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(
            stderr.contains("a-file") || stderr.contains("outputs-bad"),
            "{stderr}"
        );
        // Refused at once: no graph, map or trajectory was written anywhere.
        assert!(!dir.join("graph.g2o").exists() && !dir.join("trajectory.tum").exists());
    }
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "not a folder");
}
