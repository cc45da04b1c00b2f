//! Integration tests of `mapmerge eval …` (odometry noise, relations, ATE) on the public
//! corrected Intel log.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common::{ok_json, p, run, scratch};

fn intel() -> Option<std::path::PathBuf> {
    mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz")
}

#[test]
fn intel_noisy_odometry_drifts_and_harsh_drifts_more() {
    let Some(log) = intel() else {
        return;
    };
    let dir = scratch("eval-noise");
    let mut ate = Vec::new();
    for profile in ["default", "harsh"] {
        let noisy = dir.join(format!("intel-{profile}.log"));
        let report = ok_json(&[
            "eval",
            "add-noise",
            p(&log),
            "-o",
            p(&noisy),
            "--profile",
            profile,
            "--seed",
            "0",
            "--json",
        ]);
        assert_eq!(report["scans"], 910);
        let rms = report["odometry"]["ate"]["rms_m"].as_f64().unwrap();
        let relations = &report["odometry"]["relations"];
        assert!(relations["count"].as_u64().unwrap() > 1000, "{report}");
        assert!(relations["translation_mean_m"].as_f64().unwrap() > 0.1);
        // The written log has the same scans and the noisy poses; `eval ate` agrees.
        let written = mapmerge_io::read_carmen(&noisy).unwrap();
        let corrected = mapmerge_io::read_carmen(&log).unwrap();
        assert_eq!(written.scans.len(), 910);
        assert_eq!(written.odometry.len(), 910);
        assert_eq!(
            written.scans[500].scan.ranges_m,
            corrected.scans[500].scan.ranges_m
        );
        assert_ne!(
            written.scans[500].odom_from_robot,
            corrected.scans[500].odom_from_robot
        );
        let check = ok_json(&[
            "eval",
            "ate",
            "--trajectory",
            p(&noisy),
            "--reference",
            p(&log),
            "--json",
        ]);
        assert!((check["ate"]["rms_m"].as_f64().unwrap() - rms).abs() < 1e-9);
        assert_eq!(check["rpe"].as_array().unwrap().len(), 2);
        ate.push(rms);
    }
    assert!(ate[0] > 0.5, "default odometry ATE {} m", ate[0]);
    assert!(
        ate[1] > 1.5 * ate[0],
        "harsh {} m vs default {} m",
        ate[1],
        ate[0]
    );

    // Same seed, same file; another seed, another file.
    let again = dir.join("again.log");
    let other = dir.join("other.log");
    ok_json(&["eval", "add-noise", p(&log), "-o", p(&again), "--json"]);
    ok_json(&[
        "eval",
        "add-noise",
        p(&log),
        "-o",
        p(&other),
        "--seed",
        "1",
        "--json",
    ]);
    let first = std::fs::read(dir.join("intel-default.log")).unwrap();
    assert_eq!(first, std::fs::read(&again).unwrap());
    assert_ne!(first, std::fs::read(&other).unwrap());
}

#[test]
fn intel_relations_of_the_corrected_log_score_zero() {
    let Some(log) = intel() else {
        return;
    };
    let dir = scratch("eval-relations");
    let noisy = dir.join("noisy.log");
    ok_json(&["eval", "add-noise", p(&log), "-o", p(&noisy), "--json"]);
    let mut noisy_errors = Vec::new();
    for index_keyed in [false, true] {
        let relations = dir.join(format!("intel-{index_keyed}.relations"));
        let mut args = vec![
            "eval",
            "make-relations",
            p(&log),
            "-o",
            p(&relations),
            "--json",
        ];
        if index_keyed {
            args.push("--index-keyed");
        }
        let made = ok_json(&args);
        assert_eq!(made["relations"], 3000, "{made}");
        let text = std::fs::read_to_string(&relations).unwrap();
        assert_eq!(
            text.starts_with("# mapmerge relations keyed by scan index"),
            index_keyed
        );
        let truth = ok_json(&[
            "eval",
            "relations",
            "--log",
            p(&log),
            "--relations",
            p(&relations),
            "--json",
        ]);
        assert_eq!(truth["count"], 3000);
        assert!(
            truth["translation_mean_m"].as_f64().unwrap() < 1e-9,
            "{truth}"
        );
        assert!(
            truth["rotation_mean_deg"].as_f64().unwrap() < 1e-6,
            "{truth}"
        );
        let scored = ok_json(&[
            "eval",
            "relations",
            "--trajectory",
            p(&noisy),
            "--log",
            p(&log),
            "--relations",
            p(&relations),
            "--json",
        ]);
        noisy_errors.push(scored["translation_mean_m"].as_f64().unwrap());
    }
    // Both forms name the same pairs.
    assert!(noisy_errors[0] > 0.1);
    assert!(
        (noisy_errors[0] - noisy_errors[1]).abs() < 1e-9,
        "{noisy_errors:?}"
    );

    // A TUM trajectory (line k = scan k) scores like the log it came from.
    let poses: Vec<(f64, mapmerge_geometry::Se2)> = mapmerge_io::read_carmen(&log)
        .unwrap()
        .scans
        .iter()
        .enumerate()
        .map(|(k, r)| (k as f64, r.odom_from_robot.unwrap()))
        .collect();
    let tum = dir.join("intel.tum");
    mapmerge_io::write_tum_planar(&tum, &poses).unwrap();
    let from_tum = ok_json(&[
        "eval",
        "relations",
        "--trajectory",
        p(&tum),
        "--relations",
        p(&dir.join("intel-true.relations")),
        "--json",
    ]);
    assert!(from_tum["translation_mean_m"].as_f64().unwrap() < 1e-9);
}

#[test]
fn eval_bad_input_exits_with_code_2() {
    let dir = scratch("eval-bad");
    let relations = dir.join("bad.relations");
    std::fs::write(&relations, "# comment\n0 1 0.5 0 0 0 0\n").unwrap();
    let tum = dir.join("t.tum");
    std::fs::write(&tum, "0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n").unwrap();
    let out = run(&[
        "eval",
        "relations",
        "--trajectory",
        p(&tum),
        "--relations",
        p(&relations),
    ]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("bad.relations:2: expected 8 fields"),
        "{stderr}"
    );

    // Stamp-keyed relations without a log to map the stamps.
    std::fs::write(&relations, "0 1 0.5 0 0 0 0 0\n").unwrap();
    let out = run(&[
        "eval",
        "relations",
        "--trajectory",
        p(&tum),
        "--relations",
        p(&relations),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--log"));

    // Index out of range.
    std::fs::write(
        &relations,
        "# mapmerge relations keyed by scan index\n0 5 0.5 0 0 0 0 0\n",
    )
    .unwrap();
    let out = run(&[
        "eval",
        "relations",
        "--trajectory",
        p(&tum),
        "--relations",
        p(&relations),
    ]);
    assert_eq!(out.status.code(), Some(2));

    let out = run(&[
        "eval",
        "ate",
        "--trajectory",
        p(&tum),
        "--reference",
        "missing.tum",
    ]);
    assert_eq!(out.status.code(), Some(2));

    let Some(log) = intel() else {
        return;
    };
    let out = run(&[
        "eval",
        "add-noise",
        p(&log),
        "-o",
        p(&dir.join("x.log")),
        "--profile",
        "gentle",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("default, harsh, none"));
    // Orebro's stamps are all 0: only the index-keyed form can be written.
    if let Some(orebro) = mapmerge_testkit::shared_data("carmen/orebro-corrected.log.xz") {
        let out = run(&[
            "eval",
            "make-relations",
            p(&orebro),
            "-o",
            p(&dir.join("o.relations")),
        ]);
        assert_eq!(out.status.code(), Some(2));
        assert!(String::from_utf8_lossy(&out.stderr).contains("--index-keyed"));
    }
}
