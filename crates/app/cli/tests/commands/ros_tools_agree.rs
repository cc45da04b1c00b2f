//! Results the field's tools agree with.
//! - evo (`evo_ape tum --align`) reports the ATE `mapmerge eval ate` reports on the TUM files
//!   `mapmerge slam` writes, within 1 mm, on every public log, and the whole-map error the
//!   lab reports for the merged maps `mapmerge atlas` writes (`maps/<map>/`). `MAPMERGE_EVO_APE` names the
//!   `evo_ape` to run (`.ci/run` installs evo); without it the test skips, except under CI.
//! - Maps load by ROS map_server's rules: `scripts/map_server_load.py`, written to the
//!   map_server documentation with Python's standard library, classifies every cell of the maps
//!   `mapmerge grid` writes as mapmerge does, and classifies a ROS map (and its `negate`, path
//!   variants) as mapmerge's reader does.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::common::{ok_json, p, scratch};

use mapmerge_testkit::PUBLIC_LOGS as LOGS;

/// The `rmse` line of `evo_ape`'s statistics (printed with six decimals).
fn evo_rmse_m(reference: &Path, estimate: &Path, evo: &Path) -> f64 {
    let out = Command::new(evo)
        .args(["tum", p(reference), p(estimate), "--align", "--no_warnings"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "evo_ape failed: {text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    text.lines()
        .find_map(|line| {
            line.trim()
                .strip_prefix("rmse")
                .map(|v| v.trim().parse().unwrap())
        })
        .unwrap_or_else(|| panic!("no rmse in evo's output:\n{text}"))
}

#[test]
fn evo_reports_the_ate_mapmerge_reports_on_every_public_log() {
    let Some(evo) =
        mapmerge_testkit::tool_from_env("MAPMERGE_EVO_APE", "the evo_ape of a Python with evo")
    else {
        return;
    };
    let Some(data) = mapmerge_testkit::shared_data_dir() else {
        return;
    };
    let dir = scratch("evo");
    for name in LOGS {
        let log = data.join(format!("carmen/{name}-corrected.log.xz"));
        let out = dir.join(name);
        let slam = ok_json(&[
            "slam",
            p(&log),
            "--odometry-noise",
            "default",
            "--seed",
            "1",
            "-o",
            p(&out),
            "--json",
        ]);
        let (estimate, reference) = (out.join("trajectory.tum"), out.join("reference.tum"));
        let ours = ok_json(&[
            "eval",
            "ate",
            "--trajectory",
            p(&estimate),
            "--reference",
            p(&reference),
            "--json",
        ]);
        let ours_m = ours["ate"]["rms_m"].as_f64().unwrap();
        assert!(
            (ours_m - slam["score"]["ate"]["rms_m"].as_f64().unwrap()).abs() < 1e-12,
            "{name}"
        );
        let theirs_m = evo_rmse_m(&reference, &estimate, &evo);
        assert!(
            (ours_m - theirs_m).abs() < 1e-3,
            "{name}: mapmerge {ours_m} m, evo {theirs_m} m"
        );
    }
}

#[test]
fn evo_reports_the_whole_map_error_the_lab_reports_on_a_merged_map() {
    let Some(evo) =
        mapmerge_testkit::tool_from_env("MAPMERGE_EVO_APE", "the evo_ape of a Python with evo")
    else {
        return;
    };
    let Some(log) = mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz") else {
        return;
    };
    let dir = scratch("evo-atlas");
    let report = crate::atlas_commands::noisy_atlas_seed_1(&log, &dir);
    let maps = report["from_trajectories"]["maps"].as_array().unwrap();
    // Seed 1's kidnapped robot ends with its epochs merged into one map.
    assert!(
        maps.iter()
            .any(|m| m["segments"].as_array().unwrap().len() > 1),
        "{maps:?}"
    );
    for map in maps {
        let Some(ours_m) = map["whole_ate_m"].as_f64() else {
            continue;
        };
        let folder = dir.join("maps").join(map["map"].as_str().unwrap());
        let theirs_m = evo_rmse_m(
            &folder.join("reference.tum"),
            &folder.join("trajectory.tum"),
            &evo,
        );
        assert!(
            (ours_m - theirs_m).abs() < 1e-3,
            "{map}: mapmerge {ours_m} m, evo {theirs_m} m"
        );
    }
}

/// `scripts/map_server_load.py MAP.yaml` → its JSON.
fn map_server_load(yaml: &Path) -> serde_json::Value {
    let script = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../scripts/map_server_load.py"
    ));
    let out = Command::new("python3")
        .arg(script)
        .arg(yaml)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn maps_mapmerge_writes_load_as_map_server_loads_them() {
    let Some(data) = mapmerge_testkit::shared_data_dir() else {
        return;
    };
    let dir = scratch("map-server-write");
    for (name, extra) in [("intel", None), ("aces", Some("12")), ("fhw", None)] {
        let yaml = dir.join(format!("{name}.yaml"));
        let log = data.join(format!("carmen/{name}-corrected.log.xz"));
        let mut args = vec!["grid", "--log", p(&log), "-o", p(&yaml), "--json"];
        if let Some(range) = extra {
            args.extend(["--max-range", range]);
        }
        let ours = ok_json(&args);
        let ros = map_server_load(&yaml);
        for (a, b) in [
            ("occupied_cells", "occupied"),
            ("free_cells", "free"),
            ("unknown_cells", "unknown"),
            ("width", "width"),
            ("height", "height"),
        ] {
            assert_eq!(ours[a], ros[b], "{name}: {a}");
        }
        assert_eq!(ros["other"], 0);
        assert_eq!(ours["resolution_m"], ros["resolution"]);
        assert_eq!(ours["origin_m"][0], ros["origin"][0]);
        assert_eq!(ours["origin_m"][1], ros["origin"][1]);
    }
}

/// Cells of a map as mapmerge reads it: (occupied, free, unknown).
fn mapmerge_classes(yaml: &Path) -> (usize, usize, usize) {
    let map = mapmerge_io::read_ros_map(yaml).unwrap();
    let grid = map.to_grid().unwrap();
    let values = grid.log_odds();
    let occupied = values.iter().filter(|&&v| v > 0.0).count();
    let free = values.iter().filter(|&&v| v < 0.0).count();
    (occupied, free, values.len() - occupied - free)
}

#[test]
fn ros_maps_read_as_map_server_reads_them_with_negate_and_image_paths() {
    let Some(data) = mapmerge_testkit::shared_data_dir() else {
        return;
    };
    let original = data.join("gridmaps/intel-bwi/intel.yaml");
    let image = data.join("gridmaps/intel-bwi/intel.pgm");
    let text = std::fs::read_to_string(&original).unwrap();
    let dir = scratch("map-server-read");
    std::fs::create_dir_all(dir.join("images")).unwrap();
    std::fs::copy(&image, dir.join("images/intel.pgm")).unwrap();
    let variants = [
        // As published (thresholds 0.2 / 0.05, image beside the YAML).
        (
            "as-published.yaml",
            text.replace("image: intel.pgm", &format!("image: {}", image.display())),
        ),
        // Relative to the YAML's folder, in a subfolder.
        (
            "relative.yaml",
            text.replace("image: intel.pgm", "image: images/intel.pgm"),
        ),
        // negate: white is occupied.
        (
            "negated.yaml",
            text.replace("image: intel.pgm", "image: images/intel.pgm")
                .replace("negate: 0", "negate: 1"),
        ),
        // map_saver's thresholds.
        (
            "saver.yaml",
            text.replace("image: intel.pgm", "image: images/intel.pgm")
                .replace("occupied_thresh: 0.2", "occupied_thresh: 0.65")
                .replace("free_thresh: 0.05", "free_thresh: 0.196"),
        ),
    ];
    let mut seen = Vec::new();
    for (name, yaml_text) in variants {
        let yaml = dir.join(name);
        std::fs::write(&yaml, yaml_text).unwrap();
        let ros = map_server_load(&yaml);
        let (occupied, free, unknown) = mapmerge_classes(&yaml);
        assert_eq!(ros["occupied"], occupied, "{name}");
        assert_eq!(ros["free"], free, "{name}");
        assert_eq!(ros["unknown"], unknown, "{name}");
        seen.push((occupied, free));
    }
    // The variants differ where they should: negate swaps, thresholds move cells.
    assert_eq!(seen[0], seen[1]);
    assert_ne!(seen[1], seen[2]);
    assert_ne!(seen[1], seen[3]);
}
