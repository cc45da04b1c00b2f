//! Integration tests of `mapmerge assemble` and `mapmerge eval assemble`: a public log split
//! into noisy segments assembles to the same groups in every arrival order, with loop edges
//! that agree with the truth `split` kept apart, one pose per scan and a picture per group;
//! bad input exits with code 2 and names the file.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

use crate::common::{ok_json, p, run, scratch};
use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};

/// A loop edge is true within this of `truth(from)⁻¹ · truth(to)` (m, deg).
const TRUE_EDGE_M: f64 = 0.5;
const TRUE_EDGE_DEG: f64 = 10.0;

/// Splits the intel log into 4 noisy segments under `dir/split`; the segment logs, sorted.
/// `None` (skipped with a message) without the shared data.
fn split_intel(dir: &Path) -> Option<Vec<PathBuf>> {
    let split = dir.join("split");
    let report = split_log("intel", 4, 1, &split)?;
    let mut segments: Vec<PathBuf> = report["segments"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| split.join(s["file"].as_str().unwrap()))
        .collect();
    segments.sort();
    assert_eq!(segments.len(), 4, "{report}");
    Some(segments)
}

/// Splits public log `name` into `segments` segments with seeded noisy odometry under `dir`;
/// `split`'s report, `None` (skipped with a message) without the shared data.
fn split_log(name: &str, segments: usize, seed: u64, dir: &Path) -> Option<serde_json::Value> {
    let log = mapmerge_testkit::shared_data(&format!("carmen/{name}-corrected.log.xz"))?;
    let (segments, seed) = (segments.to_string(), seed.to_string());
    Some(ok_json(&[
        "split",
        p(&log),
        "--segments",
        &segments,
        "--odometry-noise",
        "default",
        "--seed",
        &seed,
        "-o",
        p(dir),
        "--json",
    ]))
}

/// The file stem `split` gives a segment (`intel_00.log` → `intel_00`).
fn stem(path: &Path) -> String {
    path.file_name()
        .unwrap()
        .to_str()
        .unwrap()
        .trim_end_matches(".log")
        .to_owned()
}

/// The truth of `segment`: every scan's pose in the original log's frame.
fn truth(split: &Path, segment: &str) -> Vec<Se2> {
    mapmerge_io::read_tum_planar(&split.join("truth").join(format!("{segment}.tum")))
        .unwrap()
        .into_iter()
        .map(|(_, pose)| pose)
        .collect()
}

/// What one `assemble` run wrote, read back and checked for internal consistency.
struct Assembly {
    /// `groups.json` as written.
    groups: serde_json::Value,
    /// `loops.jsonl`, one value per line.
    loops: Vec<serde_json::Value>,
    /// The `--json` report.
    report: serde_json::Value,
}

/// Runs `assemble` on `segments` with `extra` arguments into `out` and checks the files
/// against each other, the report and the segment logs.
fn assemble(segments: &[PathBuf], out: &Path, extra: &[&str]) -> Assembly {
    let mut args = vec!["assemble"];
    args.extend(segments.iter().map(|s| p(s)));
    args.extend(["-o", p(out), "--json"]);
    args.extend(extra);
    let report = ok_json(&args);
    let groups: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("groups.json")).unwrap()).unwrap();
    let loops: Vec<serde_json::Value> = std::fs::read_to_string(out.join("loops.jsonl"))
        .unwrap()
        .lines()
        .map(|line| serde_json::from_str(line).unwrap())
        .collect();

    // Every segment in exactly one group.
    let mut grouped: Vec<String> = groups
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|g| g["segments"].as_array().unwrap().iter())
        .map(|s| s.as_str().unwrap().to_owned())
        .collect();
    grouped.sort();
    let mut names: Vec<String> = segments.iter().map(|s| stem(s)).collect();
    names.sort();
    assert_eq!(grouped, names, "{groups}");

    // One pose per scan of every segment's log.
    for segment in segments {
        let scans = mapmerge_io::read_carmen(segment).unwrap().scans.len();
        let poses_path = out.join("poses").join(format!("{}.tum", stem(segment)));
        let poses = mapmerge_io::read_tum_planar(&poses_path).unwrap();
        assert_eq!(poses.len(), scans, "{}", poses_path.display());
        assert!(poses.iter().all(|(_, pose)| pose.is_finite()));
    }

    // The report counts what the files hold.
    assert_eq!(report["segments"], segments.len(), "{report}");
    assert_eq!(report["loops"], loops.len(), "{report}");
    let group_reports = report["groups"].as_array().unwrap();
    assert_eq!(group_reports.len(), groups.as_array().unwrap().len());
    let mut loop_edges_in_groups = 0;
    for (g, (reported, written)) in group_reports
        .iter()
        .zip(groups.as_array().unwrap())
        .enumerate()
    {
        assert_eq!(reported["segments"], written["segments"], "group {g}");
        let scans: usize = reported["segments"]
            .as_array()
            .unwrap()
            .iter()
            .map(|name| {
                let log = segments
                    .iter()
                    .find(|s| stem(s) == name.as_str().unwrap())
                    .unwrap();
                mapmerge_io::read_carmen(log).unwrap().scans.len()
            })
            .sum();
        assert_eq!(reported["scans"], scans, "group {g}");
        assert_eq!(reported["numerical_failure"], false, "group {g}");
        loop_edges_in_groups += reported["loop_edges"].as_u64().unwrap() as usize;
        let picture = out.join(format!("group_{g:02}.png"));
        if extra.contains(&"--no-pictures") {
            assert!(reported["picture"].is_null());
            assert!(!picture.exists(), "{}", picture.display());
        } else {
            assert_eq!(reported["picture"], p(&picture));
            let bytes = std::fs::read(&picture).unwrap();
            assert!(
                bytes.starts_with(b"\x89PNG\r\n\x1a\n"),
                "{}",
                picture.display()
            );
        }
    }
    assert!(loop_edges_in_groups <= loops.len());
    assert!(!out
        .join(format!("group_{:02}.png", group_reports.len()))
        .exists());

    // Arrivals: every segment once.
    let mut arrived: Vec<String> = report["arrivals"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["segment"].as_str().unwrap().to_owned())
        .collect();
    arrived.sort();
    assert_eq!(arrived, names);
    Assembly {
        groups,
        loops,
        report,
    }
}

/// Every loop edge's transform against the truth: all within 0.5 m and 10°.
fn check_loops_against_truth(split: &Path, loops: &[serde_json::Value]) {
    for (k, edge) in loops.iter().enumerate() {
        let scan_truth = |end: &serde_json::Value| {
            let segment = end["segment"].as_str().unwrap();
            let scan = end["scan"].as_u64().unwrap() as usize;
            truth(split, segment)[scan]
        };
        let from_from_to_truth = scan_truth(&edge["from"]).between(&scan_truth(&edge["to"]));
        let t: Vec<f64> = edge["transform"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        assert_eq!(t.len(), 3, "{edge}");
        let error = from_from_to_truth.between(&Se2::new(t[0], t[1], t[2]));
        let (error_m, error_deg) = (
            error.translation().norm(),
            wrap_angle_rad(error.theta_rad).abs().to_degrees(),
        );
        assert!(
            error_m <= TRUE_EDGE_M && error_deg <= TRUE_EDGE_DEG,
            "edge {k} off by {error_m:.3} m, {error_deg:.2}°: {edge}"
        );
        assert!(edge["score"].as_f64().unwrap().is_finite(), "{edge}");
        assert_ne!(edge["from"]["segment"], edge["to"]["segment"], "{edge}");
    }
}

#[test]
fn intel_segments_assemble_to_the_same_groups_in_every_order_with_true_edges() {
    let dir = scratch("assemble-intel-orders");
    let Some(segments) = split_intel(&dir) else {
        return;
    };
    let split = dir.join("split");
    let given = assemble(&segments, &dir.join("given"), &[]);
    assert_eq!(given.report["order"], "given");
    // The intel segments overlap: a real assembly has edges to check.
    assert!(!given.loops.is_empty(), "no loop edges: {}", given.report);
    check_loops_against_truth(&split, &given.loops);
    let given_arrivals: Vec<serde_json::Value> = given.report["arrivals"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["segment"].clone())
        .collect();
    let mut orders_differ = false;
    for seed in 1..=3 {
        let seed_text = seed.to_string();
        let random = assemble(
            &segments,
            &dir.join(format!("random-{seed}")),
            &["--order", "random", "--seed", &seed_text, "--no-pictures"],
        );
        assert_eq!(random.report["order"], "random");
        assert_eq!(random.report["seed"], seed);
        assert_eq!(
            random.groups, given.groups,
            "seed {seed}: groups differ from the given order"
        );
        check_loops_against_truth(&split, &random.loops);
        let arrivals: Vec<serde_json::Value> = random.report["arrivals"]
            .as_array()
            .unwrap()
            .iter()
            .map(|a| a["segment"].clone())
            .collect();
        orders_differ |= arrivals != given_arrivals;
    }
    // Otherwise the invariance above would have tested nothing.
    assert!(orders_differ, "seeds 1..=3 all kept the given order");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn eval_assemble_on_intel_segments_is_precise_and_order_invariant() {
    let dir = scratch("assemble-intel-eval");
    if split_intel(&dir).is_none() {
        return;
    }
    let score = ok_json(&[
        "eval",
        "assemble",
        "--split",
        p(&dir.join("split")),
        "--orders",
        "2",
        "--json",
    ]);
    assert_eq!(score["segments"], 4, "{score}");
    assert!(score["loop_edges"].as_u64().unwrap() > 0, "{score}");
    assert_eq!(score["precision"].as_f64(), Some(1.0), "{score}");
    assert_eq!(score["true_edges"], score["loop_edges"], "{score}");
    assert_eq!(score["orders_tested"], 2, "{score}");
    assert_eq!(score["orders_same"], score["orders_tested"], "{score}");
    assert!(score["groups_correct"].is_boolean(), "{score}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn random_order_without_a_seed_uses_seed_zero() {
    let dir = scratch("assemble-no-seed");
    let Some(segments) = split_intel(&dir) else {
        return;
    };
    // Two segments, odometry trajectories: enough for the option handling.
    let two = &segments[..2];
    let fast = ["--trajectory", "odometry", "--no-pictures"];
    let unseeded = assemble(
        two,
        &dir.join("unseeded"),
        &[&["--order", "random"][..], &fast[..]].concat(),
    );
    assert_eq!(unseeded.report["order"], "random");
    assert_eq!(unseeded.report["seed"], 0);
    assert_eq!(unseeded.report["trajectory"], "odometry");
    let seeded = assemble(
        two,
        &dir.join("seed-0"),
        &[&["--order", "random", "--seed", "0"][..], &fast[..]].concat(),
    );
    assert_eq!(seeded.groups, unseeded.groups);
    assert_eq!(seeded.loops, unseeded.loops);
    assert_eq!(seeded.report["arrivals"].as_array().unwrap().len(), 2);
    let names = |a: &Assembly| -> Vec<serde_json::Value> {
        a.report["arrivals"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x["segment"].clone())
            .collect()
    };
    assert_eq!(names(&seeded), names(&unseeded));
    let _ = std::fs::remove_dir_all(&dir);
}

/// A CARMEN log of `scans` short scans along x, without shared data.
fn tiny_log(path: &Path, scans: usize) {
    let mut text = String::new();
    for k in 0..scans {
        let x_m = 0.1 * k as f64;
        text.push_str(&format!(
            "FLASER 3 1.5 2 2.5 {x_m} 0 0 {x_m} 0 0 {k}.0 host {k}.0\n"
        ));
    }
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).unwrap();
    }
    std::fs::write(path, text).unwrap();
}

#[test]
fn bad_segments_exit_with_code_2_and_name_the_file() {
    let dir = scratch("assemble-bad");
    let good = dir.join("good.log");
    tiny_log(&good, 5);
    let not_a_log = dir.join("notes.txt");
    std::fs::write(&not_a_log, "this is not a laser log\n").unwrap();
    let (first, second) = (dir.join("a/same.log"), dir.join("b/same.log"));
    tiny_log(&first, 5);
    tiny_log(&second, 5);
    let folder = dir.join("a");
    let missing = dir.join("missing.log");
    let cases: [(&str, Vec<&Path>, Vec<&Path>); 4] = [
        ("missing file", vec![&good, &missing], vec![&missing]),
        ("not a log", vec![&good, &not_a_log], vec![&not_a_log]),
        (
            "duplicate names",
            vec![&first, &second],
            vec![&first, &second],
        ),
        ("a folder", vec![&good, &folder], vec![&folder]),
    ];
    for (case, inputs, named) in cases {
        let out = dir.join(format!("out-{}", case.replace(' ', "-")));
        let mut args = vec!["assemble"];
        args.extend(inputs.iter().map(|i| p(i)));
        args.extend(["-o", p(&out), "--trajectory", "odometry", "--no-pictures"]);
        let result = run(&args);
        let stderr = String::from_utf8_lossy(&result.stderr);
        assert_eq!(result.status.code(), Some(2), "{case}: {stderr}");
        for file in named {
            assert!(stderr.contains(p(file)), "{case}: {stderr}");
        }
        // Nothing is written for input that is refused before the assembly.
        assert!(!out.exists(), "{case}: {} was written", out.display());
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Segments of two buildings that share no place, pooled in one assembly, are never joined: no
/// edge between the logs, no group mixing them, and each log's own overlaps are still found.
#[test]
fn pooled_segments_of_two_buildings_are_never_joined() {
    let dir = scratch("assemble-pool");
    let (seattle, orebro) = (dir.join("seattle"), dir.join("orebro"));
    if split_log("seattle", 3, 0, &seattle).is_none()
        || split_log("orebro", 3, 0, &orebro).is_none()
    {
        return;
    }
    let score = ok_json(&[
        "eval",
        "assemble",
        "--split",
        p(&seattle),
        "--split",
        p(&orebro),
        "--arrival-seed",
        "1",
        "--orders",
        "2",
        "--json",
    ]);
    assert_eq!(score["segments"], 6, "{score}");
    assert_eq!(score["cross_log_edges"], 0, "{score}");
    assert_eq!(score["mixed_groups"], 0, "{score}");
    assert_eq!(score["orders_same"], score["orders_tested"], "{score}");
    let per_split = score["per_split"].as_array().unwrap();
    assert_eq!(per_split.len(), 2, "{score}");
    for split in per_split {
        assert_eq!(split["segments"], 3, "{score}");
        assert!(split["loop_edges"].as_u64().unwrap() > 0, "{score}");
        assert_eq!(split["true_edges"], split["loop_edges"], "{score}");
    }
    // Every truth group lies within one log.
    for group in score["truth_groups"].as_array().unwrap() {
        let logs: std::collections::BTreeSet<&str> = group
            .as_array()
            .unwrap()
            .iter()
            .map(|name| name.as_str().unwrap().split('_').next().unwrap())
            .collect();
        assert_eq!(logs.len(), 1, "{score}");
    }
    // The same log twice: its segment names collide, which is bad input.
    let twice = run(&[
        "eval",
        "assemble",
        "--split",
        p(&seattle),
        "--split",
        p(&seattle),
        "--json",
    ]);
    assert_eq!(twice.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&twice.stderr).contains("seattle_00"),
        "{}",
        String::from_utf8_lossy(&twice.stderr)
    );
    let _ = std::fs::remove_dir_all(&dir);
}
