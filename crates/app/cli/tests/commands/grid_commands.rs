//! Integration tests of `mapmerge grid` and `mapmerge render` on the public logs.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use std::path::Path;

use crate::common::{ok_json, p, run, scratch};
use mapmerge_grid::{CellClass, ClassThresholds};

/// Spread (m) of the occupied cells of a map between the 1st and 99th percentile, x and y.
fn occupied_extent_m(yaml: &Path) -> (f64, f64) {
    let grid = mapmerge_io::read_ros_map(yaml).unwrap().to_grid().unwrap();
    let thresholds = ClassThresholds::default();
    let (mut xs, mut ys): (Vec<f64>, Vec<f64>) = grid
        .cells()
        .filter(|&(_, _, l)| thresholds.classify(l) == CellClass::Occupied)
        .map(|(_, c, _)| (c.x, c.y))
        .unzip();
    xs.sort_by(f64::total_cmp);
    ys.sort_by(f64::total_cmp);
    let spread = |v: &[f64]| v[v.len() * 99 / 100] - v[v.len() / 100];
    (spread(&xs), spread(&ys))
}

#[test]
fn intel_grid_has_the_lab_s_size_and_writes_map_and_picture() {
    let Some(log) = mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz") else {
        return;
    };
    let dir = scratch("intel-grid");
    let yaml = dir.join("intel.yaml");
    let png = dir.join("intel.png");
    let report = ok_json(&[
        "grid",
        "--log",
        p(&log),
        "--resolution",
        "0.05",
        "-o",
        p(&yaml),
        "--png",
        p(&png),
        "--json",
    ]);
    assert_eq!(report["scans"], 910);
    assert!(
        report["occupied_cells"].as_u64().unwrap() > 10_000,
        "{report}"
    );
    // The Intel Research Lab is about 29 m × 29 m.
    let (x, y) = occupied_extent_m(&yaml);
    assert!(
        (27.0..31.0).contains(&x) && (27.0..31.0).contains(&y),
        "{x} × {y} m"
    );
    assert!(dir.join("intel.pgm").exists());
    assert_eq!(&std::fs::read(&png).unwrap()[1..4], b"PNG");
    // Render the written map again with the corrected trajectory and a classes style.
    let tum = dir.join("intel.tum");
    let log_data = mapmerge_io::read_carmen(&log).unwrap();
    let poses: Vec<(f64, mapmerge_geometry::Se2)> = log_data
        .scans
        .iter()
        .enumerate()
        .map(|(k, s)| (k as f64, s.odom_from_robot.unwrap()))
        .collect();
    mapmerge_io::write_tum_planar(&tum, &poses).unwrap();
    let out = dir.join("render.png");
    let rendered = ok_json(&[
        "render",
        "--map",
        p(&yaml),
        "--trajectory",
        p(&tum),
        "--classes",
        "--scale",
        "2",
        "-o",
        p(&out),
        "--json",
    ]);
    assert!(rendered["width_px"].as_u64().unwrap() >= 2 * report["width"].as_u64().unwrap());
    // The same grid from the log with the TUM poses (one per scan, by order).
    let again = ok_json(&[
        "grid",
        "--log",
        p(&log),
        "--poses",
        p(&tum),
        "-o",
        p(&dir.join("again.yaml")),
        "--json",
    ]);
    assert_eq!(again["occupied_cells"], report["occupied_cells"]);
}

#[test]
fn every_public_log_builds_a_grid() {
    let Some(dir) = mapmerge_testkit::shared_data("carmen") else {
        return;
    };
    let out = scratch("all-logs");
    let mut logs: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().ends_with(".log.xz"))
        .collect();
    logs.push(dir.join("robot-mapping-course/csail.log.xz"));
    logs.sort();
    assert_eq!(logs.len(), 14);
    for log in logs {
        let yaml = out.join(format!(
            "{}.yaml",
            log.file_stem().unwrap().to_string_lossy()
        ));
        let report = ok_json(&[
            "grid",
            "--log",
            p(&log),
            "--resolution",
            "0.1",
            "-o",
            p(&yaml),
            "--json",
        ]);
        let occupied = report["occupied_cells"].as_u64().unwrap();
        let free = report["free_cells"].as_u64().unwrap();
        eprintln!("{}: occupied {occupied}, free {free}", log.display());
        assert!(
            occupied > 500 && free > 3 * occupied,
            "{}: {report}",
            log.display()
        );
    }
}

#[test]
fn bad_inputs_exit_with_code_2_and_name_the_file() {
    let dir = scratch("grid-bad");
    let missing = dir.join("missing.log");
    let out = run(&["grid", "--log", p(&missing), "-o", p(&dir.join("m.yaml"))]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("missing.log"));

    let log = dir.join("two.log");
    std::fs::write(&log, "ODOM 0 0 0 0 0 0 1 h 1\nFLASER 3 1 1 1 0 0 0 0 0 0 1 h 1\nFLASER 3 1 1 1 0.1 0 0 0.1 0 0 2 h 2\n").unwrap();
    let tum = dir.join("one.tum");
    std::fs::write(&tum, "0 0 0 0 0 0 0 1\n").unwrap();
    let out = run(&[
        "grid",
        "--log",
        p(&log),
        "--poses",
        p(&tum),
        "-o",
        p(&dir.join("m.yaml")),
    ]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("one.tum: 1 poses for the 2 scans"),
        "{stderr}"
    );

    let out = run(&[
        "grid",
        "--log",
        p(&log),
        "--resolution",
        "0",
        "-o",
        p(&dir.join("m.yaml")),
    ]);
    assert_eq!(out.status.code(), Some(2));
    let broken = dir.join("broken.log");
    std::fs::write(&broken, "FLASER 3 1 1\n").unwrap();
    let out = run(&["render", "--log", p(&broken), "-o", p(&dir.join("x.png"))]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("broken.log:1:"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn render_draws_pose_graphs_and_refuses_3d_ones() {
    let dir = scratch("render-graph");
    let out = dir.join("graph.png");
    let graph = common::testdata("sim_manhattan_500.g2o");
    let report = ok_json(&[
        "render",
        "--graph",
        p(&graph),
        "--resolution",
        "0.2",
        "-o",
        p(&out),
        "--json",
    ]);
    assert_eq!(report["graphs"], 1);
    assert!(
        report["width_px"].as_u64().unwrap() > 50 && report["height_px"].as_u64().unwrap() > 50,
        "{report}"
    );
    assert_eq!(&std::fs::read(&out).unwrap()[1..4], b"PNG");
    let spatial = dir.join("tiny3d.g2o");
    std::fs::write(
        &spatial,
        "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\n",
    )
    .unwrap();
    let refused = run(&["render", "--graph", p(&spatial), "-o", p(&out)]);
    assert_eq!(refused.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("only 2D graphs"));
}
