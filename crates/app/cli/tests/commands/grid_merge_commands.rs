//! Integration tests of `mapmerge grid-merge` and `mapmerge eval grid-merge`: real building
//! maps (one merged with a turned, coarser copy of itself whose transform is known), a pair
//! with no acceptable hypothesis (exit code 3), malformed map files (exit code 2), and
//! Andersone's experiment on a short run.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;

use crate::common::{ok_json, p, run, scratch};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{ClassThresholds, GridGeometry, Point2};
use mapmerge_io::{MapMode, RosMap};

/// Writes `map` (YAML + PGM) to `dir/name.yaml`.
fn write_map(dir: &Path, name: &str, map: &RosMap) -> std::path::PathBuf {
    let yaml = dir.join(format!("{name}.yaml"));
    mapmerge_io::write_ros_map(&yaml, map).unwrap();
    yaml
}

#[test]
fn a_turned_coarser_copy_of_a_building_map_is_found_where_it_was_put() {
    let Some(yaml) = mapmerge_testkit::shared_data("gridmaps/intel-bwi/intel.yaml") else {
        return;
    };
    let dir = scratch("grid-merge-known");
    let a = mapmerge_io::read_ros_map(&yaml).unwrap().to_grid().unwrap();
    // B: A's content in a frame turned by 37° and moved, at twice A's cell size.
    let a_from_b = Se2::new(3.2, -1.7, 37f64.to_radians());
    let b = mapmerge_lab::live_judge::turned_copy(&a, &a_from_b, 2.0).unwrap();
    let resolution_m = b.resolution_m();
    let b_yaml = write_map(
        &dir,
        "b",
        &RosMap::from_grid(&b, MapMode::Trinary, &ClassThresholds::default()),
    );
    let merged = dir.join("merged.yaml");
    let report = ok_json(&[
        "grid-merge",
        p(&yaml),
        p(&b_yaml),
        "-o",
        p(&merged),
        "--json",
    ]);
    assert_eq!(report["accepted"], true, "{report}");
    let t = &report["transform"];
    let found = Se2::new(
        t["x"].as_f64().unwrap(),
        t["y"].as_f64().unwrap(),
        t["yaw"].as_f64().unwrap(),
    );
    let error = a_from_b.between(&found);
    assert!(
        error.translation().norm() <= 2.0 * resolution_m,
        "{error:?}: {report}"
    );
    assert!(error.theta_rad.abs() <= 1f64.to_radians(), "{report}");
    for key in ["acceptance", "sm", "dm", "seconds"] {
        assert!(report[key].is_number(), "{key}: {report}");
    }
    assert!(report["hypotheses"].is_array());
    // The merged map is in A's frame and resolution; the picture shows both.
    let merged_map = mapmerge_io::read_ros_map(&merged).unwrap();
    assert_eq!(merged_map.resolution_m, a.resolution_m());
    assert!(dir.join("merged.png").is_file());
}

#[test]
fn maps_of_two_different_floors_are_not_merged_and_say_why() {
    let (Some(a), Some(b)) = (
        mapmerge_testkit::shared_data("gridmaps/utexas-gdc-1n/1n.yaml"),
        mapmerge_testkit::shared_data("gridmaps/utexas-gdc-1s/1s.yaml"),
    ) else {
        return;
    };
    let dir = scratch("grid-merge-refused");
    let merged = dir.join("merged.yaml");
    let out = run(&["grid-merge", p(&a), p(&b), "-o", p(&merged), "--json"]);
    assert_eq!(out.status.code(), Some(3), "{out:?}");
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["accepted"], false);
    assert!(
        report["reason"].as_str().unwrap().contains("not accepted"),
        "{report}"
    );
    assert!(!merged.exists());
}

#[test]
fn malformed_map_files_are_bad_input_naming_the_file() {
    let dir = scratch("grid-merge-malformed");
    let good = RosMap::from_grid(
        &mapmerge_grid::OccupancyGrid::from_log_odds(
            GridGeometry {
                resolution_m: 0.1,
                origin_m: Point2::zeros(),
                width: 4,
                height: 4,
            },
            vec![3.0; 16],
        )
        .unwrap(),
        MapMode::Trinary,
        &ClassThresholds::default(),
    );
    let good_yaml = write_map(&dir, "good", &good);
    let no_image = dir.join("no-image.yaml");
    std::fs::write(&no_image, "resolution: 0.05\norigin: [0, 0, 0]\n").unwrap();
    let bad_pgm = dir.join("bad-pgm.yaml");
    std::fs::write(
        &bad_pgm,
        "image: bad.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
    )
    .unwrap();
    std::fs::write(dir.join("bad.pgm"), b"P5\n10 10\n255\nshort").unwrap();
    for bad in [&no_image, &bad_pgm, &dir.join("missing.yaml")] {
        let out = run(&[
            "grid-merge",
            p(&good_yaml),
            p(bad),
            "-o",
            p(&dir.join("m.yaml")),
        ]);
        assert_eq!(out.status.code(), Some(2), "{bad:?}: {out:?}");
        let stderr = String::from_utf8_lossy(&out.stderr);
        let name = bad.file_name().unwrap().to_string_lossy();
        let pgm_named = stderr.contains("bad.pgm");
        assert!(stderr.contains(&*name) || pgm_named, "{stderr}");
    }
}

#[test]
fn the_experiment_reports_tables_and_separation_per_resolution_combination() {
    let Some(log) = mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz") else {
        return;
    };
    let dir = scratch("eval-grid-merge");
    let md = dir.join("tables.md");
    let report = ok_json(&[
        "eval",
        "grid-merge",
        p(&log),
        "--merges",
        "3",
        "-o",
        p(&md),
        "--json",
    ]);
    let combinations = report["logs"][0]["combinations"].as_array().unwrap();
    assert_eq!(combinations.len(), 3);
    for c in combinations {
        let cases = c["cases"].as_array().unwrap();
        let wrong: Vec<_> = cases.iter().filter(|k| k["wrong"] == true).collect();
        let correct: Vec<_> = cases.iter().filter(|k| k["wrong"] == false).collect();
        assert_eq!((wrong.len(), correct.len()), (3, 3), "{c}");
        // Wrong merges are far from the truth, correct ones close, and 2M sees the difference.
        let mean_dm = |set: &[&serde_json::Value]| {
            set.iter()
                .map(|k| k["multi_map"]["end"]["dm_cells"].as_f64().unwrap())
                .sum::<f64>()
                / set.len() as f64
        };
        assert!(mean_dm(&wrong) > 2.0 * mean_dm(&correct), "{c}");
    }
    let tables = std::fs::read_to_string(&md).unwrap();
    assert!(
        tables.contains("Initial SM") && tables.contains("AUC"),
        "{tables}"
    );
}
