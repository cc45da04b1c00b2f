//! Integration tests of `mapmerge eval make-merge-cases`, `mapmerge eval invalid-merge` and
//! `mapmerge eval calibrate`: the case and result formats, bad case files (exit code 2 naming
//! the line), cases made from intel with both labels, the detectors telling them apart, and
//! leave-one-log-out calibration.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeSet;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::common::{ok_json, p, run, scratch};
use serde_json::Value;

const CASE_FIELDS: [&str; 10] = [
    "id",
    "log",
    "first",
    "second",
    "merge_at",
    "merge_transform",
    "odometry_noise",
    "seed",
    "label",
    "kind",
];

fn intel() -> Option<PathBuf> {
    mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz")
}

fn json_lines(path: &Path) -> Vec<Value> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

/// A CARMEN log of `scans` FLASER scans driving along x in a 4 m wide corridor.
fn tiny_log(dir: &Path, scans: usize) -> PathBuf {
    let mut text = String::new();
    for k in 0..scans {
        let x = 0.2 * k as f64;
        let ranges: Vec<String> = (0..180)
            .map(|b| {
                let angle = (f64::from(b) - 90.0).to_radians();
                let r = if angle.sin().abs() > 1e-3 {
                    (2.0 / angle.sin().abs()).min(20.0)
                } else {
                    20.0
                };
                format!("{r:.3}")
            })
            .collect();
        let _ = writeln!(
            text,
            "FLASER 180 {} {x} 0 0 {x} 0 0 {} host {}",
            ranges.join(" "),
            k,
            k
        );
    }
    let path = dir.join("tiny.log");
    std::fs::write(&path, text).unwrap();
    path
}

fn case_line(
    log: &Path,
    id: &str,
    first: [usize; 2],
    second: [usize; 2],
    merge_at: usize,
) -> String {
    serde_json::json!({
        "id": id, "log": p(log), "first": first, "second": second, "merge_at": merge_at,
        "merge_transform": [1.0, 0.0, 0.0], "odometry_noise": null, "seed": 0, "label": "valid"
    })
    .to_string()
}

/// `mapmerge eval make-merge-cases --log LOG --corrected LOG -o OUT EXTRA… --json` (a
/// corrected log is its own reference).
fn make_cases(log: &Path, out: &Path, extra: &[&str]) -> Value {
    let mut args = vec![
        "eval",
        "make-merge-cases",
        "--log",
        p(log),
        "--corrected",
        p(log),
        "-o",
        p(out),
        "--json",
    ];
    args.extend_from_slice(extra);
    ok_json(&args)
}

/// The arguments `eval invalid-merge --cases CASES -o RESULTS EXTRA…`.
fn invalid_merge_args<'a>(cases: &'a Path, results: &'a Path, extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec![
        "eval",
        "invalid-merge",
        "--cases",
        p(cases),
        "-o",
        p(results),
    ];
    args.extend_from_slice(extra);
    args
}

/// `mapmerge eval invalid-merge --cases CASES -o RESULTS --methods METHODS EXTRA… --json`.
fn evaluate(cases: &Path, results: &Path, methods: &str, extra: &[&str]) -> Value {
    let mut args = invalid_merge_args(cases, results, &["--methods", methods, "--json"]);
    args.extend_from_slice(extra);
    ok_json(&args)
}

fn expect_bad(args: &[&str], needle: &str) {
    let out = run(args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
    assert!(stderr.contains(needle), "{stderr} lacks {needle}");
}

#[test]
fn bad_case_files_exit_2_naming_the_file_and_line() {
    let dir = scratch("invalid-merge-bad");
    let log = tiny_log(&dir, 20);
    let good = case_line(&log, "a", [0, 4], [5, 19], 8);
    let results = dir.join("r.jsonl");
    let bad = |name: &str, text: String| {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path
    };
    let json = bad("json.jsonl", format!("{good}\n{{\"id\": \"b\", \"log\"\n"));
    expect_bad(
        &invalid_merge_args(&json, &results, &[]),
        "json.jsonl:2: not a merge case",
    );
    let range = bad(
        "range.jsonl",
        format!("{good}\n\n{}\n", case_line(&log, "b", [0, 4], [5, 25], 8)),
    );
    expect_bad(
        &invalid_merge_args(&range, &results, &[]),
        "range.jsonl:3: second [5, 25] is beyond the 20 scans",
    );
    let outside = bad("outside.jsonl", case_line(&log, "c", [0, 4], [5, 19], 3));
    expect_bad(
        &invalid_merge_args(&outside, &results, &[]),
        "outside.jsonl:1: merge_at 3 is not a scan of second [5, 19]",
    );
    let order = bad("order.jsonl", case_line(&log, "d", [4, 0], [5, 19], 8));
    expect_bad(
        &invalid_merge_args(&order, &results, &[]),
        "order.jsonl:1: first [4, 0] ends before it starts",
    );
    for (flag, value) in [("--segment-length-m", "0"), ("--valid-at", "somewhere")] {
        let out = run(&[
            "eval",
            "make-merge-cases",
            "--log",
            p(&log),
            "--corrected",
            p(&log),
            "-o",
            p(&dir.join("c.jsonl")),
            flag,
            value,
        ]);
        assert_eq!(out.status.code(), Some(2), "{flag} {value}");
    }
    let ok = bad("ok.jsonl", format!("{good}\n"));
    expect_bad(
        &invalid_merge_args(&ok, &results, &["--methods", "psychic"]),
        "unknown method `psychic`",
    );
    // A case it did not generate, on a log of that format, runs.
    let report = evaluate(&ok, &results, "histogram", &[]);
    assert_eq!(report["cases"], 1);
    let lines = json_lines(&results);
    assert_eq!(lines.len(), 1);
    assert_eq!(lines[0]["id"], "a");
    assert_eq!(lines[0]["method"], "histogram");
    // Detector parameters with an unknown field are bad input.
    let params = dir.join("params.json");
    std::fs::write(&params, r#"{"change_detection": {"recent_scanz": 5}}"#).unwrap();
    expect_bad(
        &invalid_merge_args(&ok, &results, &["--detector-params", p(&params)]),
        "bad detector parameters",
    );
    // So are engine parameters with an unknown field.
    let engine = dir.join("engine.json");
    std::fs::write(
        &engine,
        r#"{"atlas": {"merge": {"overlap": {"local_loopz": true}}}}"#,
    )
    .unwrap();
    expect_bad(
        &invalid_merge_args(&ok, &results, &["--engine-config", p(&engine)]),
        "local_loopz",
    );
    // A known one runs.
    std::fs::write(
        &engine,
        r#"{"atlas": {"merge": {"overlap": {"local_loops": false}}}}"#,
    )
    .unwrap();
    let report = evaluate(&ok, &results, "histogram", &["--engine-config", p(&engine)]);
    assert_eq!(report["cases"], 1);
}

#[test]
fn intel_cases_have_both_labels_and_the_detectors_tell_them_apart() {
    let Some(intel) = intel() else {
        return;
    };
    let dir = scratch("invalid-merge-intel");
    let cases = dir.join("cases.jsonl");
    let make = |out: &Path| make_cases(&intel, out, &["--seed", "4", "--max-pairs", "8"]);
    let report = make(&cases);
    assert!(report["segments"].as_u64().unwrap() >= 20, "{report}");
    // Deterministic for a seed.
    let again = dir.join("again.jsonl");
    make(&again);
    assert_eq!(
        std::fs::read(&cases).unwrap(),
        std::fs::read(&again).unwrap()
    );
    let lines = json_lines(&cases);
    let mut labels = BTreeSet::new();
    for case in &lines {
        let keys: BTreeSet<&str> = case
            .as_object()
            .unwrap()
            .keys()
            .map(String::as_str)
            .collect();
        assert_eq!(keys, CASE_FIELDS.into_iter().collect(), "{case}");
        assert_eq!(case["odometry_noise"], "default");
        assert_eq!(case["seed"], 4);
        let [s, e] = [&case["second"][0], &case["second"][1]].map(|v| v.as_u64().unwrap());
        let at = case["merge_at"].as_u64().unwrap();
        assert!(s <= at && at <= e, "{case}");
        labels.insert(case["label"].as_str().unwrap().to_owned());
    }
    assert_eq!(
        labels,
        ["invalid", "valid"]
            .map(str::to_owned)
            .into_iter()
            .collect()
    );
    let results = dir.join("results.jsonl");
    let methods = ["change_detection", "gridmap"];
    let report = evaluate(&cases, &results, &methods.join(","), &[]);
    assert_eq!(report["cases"].as_u64().unwrap(), lines.len() as u64);
    let results = json_lines(&results);
    assert_eq!(results.len(), lines.len() * methods.len());
    let (mut valid, mut invalid) = (Vec::new(), Vec::new());
    for r in &results {
        for field in [
            "id",
            "method",
            "max_invalidity",
            "ms_per_vertex",
            "vertices",
        ] {
            assert!(r.get(field).is_some(), "{r} lacks {field}");
        }
        let ratio = r["max_invalidity"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&ratio), "{r}");
        assert!(r["vertices"].as_u64().unwrap() > 0, "{r}");
        match r["label"].as_str() {
            Some("valid") => valid.push(ratio),
            Some("invalid") => invalid.push(ratio),
            _ => panic!("{r}"),
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert!(
        mean(&valid) < mean(&invalid),
        "valid {valid:?} vs invalid {invalid:?}"
    );
}

/// `--place-kind` adds, per pair, a `place` case (careless place recognition over the whole
/// first segment, its transform the case, no merge place) and leaves the other cases as
/// they were.
#[test]
fn the_place_kind_adds_wrong_places_and_changes_nothing_else() {
    let Some(intel) = intel() else {
        return;
    };
    let dir = scratch("invalid-merge-place-kind");
    let (plain, with_place) = (dir.join("plain.jsonl"), dir.join("place.jsonl"));
    let args = [
        "--valid-at",
        "merge-place",
        "--segment-length-m",
        "30",
        "--max-pairs",
        "3",
    ];
    make_cases(&intel, &plain, &args);
    let mut more = args.to_vec();
    more.push("--place-kind");
    let report = make_cases(&intel, &with_place, &more);
    let (plain, with_place) = (json_lines(&plain), json_lines(&with_place));
    let (places, others): (Vec<_>, Vec<_>) =
        with_place.into_iter().partition(|c| c["kind"] == "place");
    assert_eq!(others, plain);
    assert!(!places.is_empty() && places.len() <= 3, "{places:?}");
    assert_eq!(report["invalid_place"], places.len());
    for case in &places {
        assert_eq!(case["label"], "invalid", "{case}");
        assert!(case.get("merge_place").is_none_or(Value::is_null), "{case}");
        assert!(case["id"].as_str().unwrap().ends_with("/place"), "{case}");
    }
}

/// The merge-place protocol: merges defined at the merge place, 30 m segments, the log's own
/// odometry; every case carries its merge place and kind, the invalid kinds are there, and the
/// summary reports AUC per kind.
#[test]
fn merge_place_cases_carry_their_place_and_kind_and_are_scored_per_kind() {
    let Some(intel) = intel() else {
        return;
    };
    let dir = scratch("invalid-merge-merge-place");
    let cases = dir.join("cases.jsonl");
    let report = make_cases(
        &intel,
        &cases,
        &[
            "--valid-at",
            "merge-place",
            "--segment-length-m",
            "30",
            "--odometry-noise",
            "null",
            "--max-pairs",
            "3",
        ],
    );
    assert_eq!(report["valid"], 3, "{report}");
    assert_eq!(report["invalid_rotation"], 3, "{report}");
    let lines = json_lines(&cases);
    let mut kinds = BTreeSet::new();
    for case in &lines {
        let place = &case["merge_place"];
        let first_scan = place["first_scan"].as_u64().unwrap();
        let [s, e] = [&case["first"][0], &case["first"][1]].map(|v| v.as_u64().unwrap());
        assert!(s <= first_scan && first_scan <= e, "{case}");
        assert_eq!(place["relative"].as_array().unwrap().len(), 3, "{case}");
        assert_eq!(case["odometry_noise"], Value::Null);
        let kind = case["kind"].as_str().unwrap().to_owned();
        let label = if kind == "valid" { "valid" } else { "invalid" };
        assert_eq!(case["label"], label, "{case}");
        assert!(case["id"].as_str().unwrap().ends_with(&kind), "{case}");
        kinds.insert(kind);
    }
    for kind in ["valid", "rotation", "shift"] {
        assert!(kinds.contains(kind), "{kinds:?}");
    }
    let results_path = dir.join("results.jsonl");
    let results = results_path.clone();
    let pictures = dir.join("pictures");
    let trace = dir.join("trace.jsonl");
    let report = evaluate(
        &cases,
        &results,
        "change_detection",
        &["--pictures", p(&pictures), "--trace", p(&trace)],
    );
    // Every vertex's ratio with what it rests on: a nonzero ratio needs change detection's
    // 100 classified points.
    let trace = json_lines(&trace);
    assert!(!trace.is_empty());
    for line in &trace {
        let support = line["support"].as_u64().unwrap();
        if line["invalidity"].as_f64().unwrap() > 0.0 {
            assert!(support >= 100, "{line}");
        }
        // Below the minimum the ratio is no evidence: unsupported, not valid.
        let supported = if support >= 100 {
            "supported"
        } else {
            "unsupported"
        };
        assert_eq!(line["evidence"], supported, "{line}");
        // The forced merge's edge at least joins the epochs.
        assert!(line["cross_edges"].as_u64().unwrap() >= 1, "{line}");
        // Valid cases carry the newest keyframe's misalignment against the log's poses.
        if line["id"].as_str().unwrap().ends_with("valid") {
            let error = &line["local_error"];
            assert!(error["m"].as_f64().unwrap() < 1.0, "{line}");
            assert!(error["deg"].as_f64().unwrap() < 10.0, "{line}");
        } else {
            assert!(line.get("local_error").is_none(), "{line}");
        }
    }
    for case in &lines {
        let stem = case["id"].as_str().unwrap().replace('/', "_");
        for which in ["first", "peak"] {
            let png = pictures.join(format!("{stem}-{which}.png"));
            assert!(png.metadata().unwrap().len() > 1000, "{}", png.display());
        }
    }
    let row = &report["summary"][0];
    let by_kind = row["auc_by_kind"].as_object().unwrap();
    for kind in kinds.iter().filter(|k| *k != "valid") {
        let auc = by_kind[kind.as_str()].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&auc), "{row}");
    }
    // Valid merges exact at the merge place read lower than turned ones.
    let results = json_lines(&results);
    for r in &results {
        let supported = r["supported_vertices"].as_u64().unwrap();
        assert!(supported <= r["vertices"].as_u64().unwrap(), "{r}");
    }
    let of = |kind: &str| -> f64 {
        let v: Vec<f64> = results
            .iter()
            .filter(|r| r["kind"] == kind)
            .map(|r| r["max_invalidity"].as_f64().unwrap())
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    assert!(of("valid") < of("rotation"), "{results:?}");
    // Detector parameters are used: a minimum no window reaches leaves every vertex
    // unsupported (and every ratio 0).
    let params = dir.join("params.json");
    std::fs::write(
        &params,
        r#"{"change_detection": {"min_classified_points": 1000000000}}"#,
    )
    .unwrap();
    evaluate(
        &cases,
        &results_path,
        "change_detection",
        &["--detector-params", p(&params)],
    );
    for r in json_lines(&results_path) {
        assert_eq!(r["supported_vertices"], 0, "{r}");
        assert_eq!(r["max_invalidity"], 0.0, "{r}");
    }
}

/// A results file of two detectors on `logs` logs, 12 valid and 12 invalid cases each:
/// `change_detection` separates the labels (with some overlap), `gridmap` is noise, and a
/// few invalid cases are unsupported (0, never supported) in both.
fn synthetic_results(path: &Path, logs: usize) {
    let mut text = String::new();
    for log in 0..logs {
        for k in 0..24 {
            let invalid = k >= 12;
            let noise = ((log * 31 + k * 17) % 23) as f64 / 23.0;
            let unsupported = invalid && k % 6 == 0;
            let cd = if unsupported {
                0.0
            } else if invalid {
                0.3 + 0.6 * noise
            } else {
                0.4 * noise
            };
            let gm = if unsupported { 0.0 } else { noise };
            for (method, ratio) in [("change_detection", cd), ("gridmap", gm)] {
                let line = serde_json::json!({
                    "id": format!("log{log}/c{k}"),
                    "method": method,
                    "max_invalidity": ratio,
                    "ms_per_vertex": 0.1,
                    "vertices": 10,
                    "label": if invalid { "invalid" } else { "valid" },
                    "kind": if invalid { "shift" } else { "valid" },
                    "log": format!("data/log{log}-corrected.log"),
                    "supported_vertices": if unsupported { 0 } else { 10 },
                });
                let _ = writeln!(text, "{line}");
            }
        }
    }
    std::fs::write(path, text).unwrap();
}

/// `eval calibrate` of change detection and gridmap on `results` with `extra` arguments:
/// its JSON report and the model it wrote to `model`.
fn calibrate_model(results: &Path, extra: &[&str], model: &Path) -> (Value, Value) {
    let mut args = vec![
        "eval",
        "calibrate",
        "--results",
        p(results),
        "--features",
        "change_detection,gridmap",
        "-o",
        p(model),
        "--json",
    ];
    args.extend_from_slice(extra);
    let report = ok_json(&args);
    let text = std::fs::read_to_string(model).unwrap();
    (report, serde_json::from_str(&text).unwrap())
}

#[test]
fn calibrate_fits_on_the_other_logs_and_writes_the_model() {
    let dir = scratch("invalid-merge-calibrate");
    let results = dir.join("results.jsonl");
    synthetic_results(&results, 4);
    let model = dir.join("model.json");
    let report = dir.join("calibrate.md");
    let out = ok_json(&[
        "eval",
        "calibrate",
        "--results",
        p(&results),
        "--features",
        "change_detection,gridmap",
        "-o",
        p(&model),
        "--report",
        p(&report),
        "--json",
    ]);
    assert_eq!(out["cases"], 96, "{out}");
    let logs = out["logs"].as_array().unwrap();
    assert_eq!(logs.len(), 4);
    for row in logs {
        assert_eq!(row["valid"], 12);
        assert_eq!(row["eligible"], true);
        let singles = row["singles"].as_array().unwrap();
        assert_eq!(singles.len(), 2, "{row}");
        let cd = singles
            .iter()
            .find(|h| h["method"] == "change_detection")
            .unwrap();
        // Held out, change detection still separates; unsupported cases were invalid in
        // the other logs, so calibration scores them above the valid ones (raw: at 0).
        assert!(cd["auc"].as_f64().unwrap() > 0.9, "{row}");
        assert!(
            cd["auc"].as_f64().unwrap() >= cd["raw_auc"].as_f64().unwrap(),
            "{row}"
        );
        assert_eq!(row["best_single"][0], "change_detection", "{row}");
        assert!(row["learned"]["auc"].as_f64().unwrap() > 0.85, "{row}");
        // The in-sample figure (fitted on every log) beside the held-out one.
        assert!(
            row["learned_in_sample_auc"].as_f64().unwrap() > 0.85,
            "{row}"
        );
    }
    let fitted: Value = serde_json::from_str(&std::fs::read_to_string(&model).unwrap()).unwrap();
    assert_eq!(
        fitted["methods"],
        serde_json::json!(["change_detection", "gridmap"])
    );
    let weights = fitted["ratio_weights"].as_array().unwrap();
    assert!(weights[0].as_f64().unwrap() > weights[1].as_f64().unwrap().abs());
    // The logistic takes the ratios' logit by default; `identity` writes no transform.
    assert_eq!(fitted["ratio_transform"], "logit", "{fitted}");
    let (_, plain) = calibrate_model(
        &results,
        &["--ratio-transform", "identity"],
        &dir.join("identity.json"),
    );
    assert!(plain.get("ratio_transform").is_none(), "{plain}");
    assert_ne!(plain["ratio_weights"], fitted["ratio_weights"]);
    assert!(std::fs::read_to_string(&report)
        .unwrap()
        .contains("| log |"));
    // A false-alarm budget moves the written model's threshold; a share outside [0, 1) is
    // bad input.
    let (_, budgeted) = calibrate_model(
        &results,
        &["--alpha", "1", "--false-alarm-budget", "0"],
        &dir.join("budgeted.json"),
    );
    assert_ne!(budgeted["threshold"], 0.5, "{budgeted}");
    expect_bad(
        &[
            "eval",
            "calibrate",
            "--results",
            p(&results),
            "--false-alarm-budget",
            "1.5",
        ],
        "--false-alarm-budget",
    );
    // The forest on the same features: held out it separates too, and its model file holds
    // the trees (and no weights); it reads back as the same model.
    let (forest, fitted) = calibrate_model(
        &results,
        &["--model", "forest", "--trees", "40"],
        &dir.join("forest.json"),
    );
    for row in forest["logs"].as_array().unwrap() {
        assert!(row["learned"]["auc"].as_f64().unwrap() > 0.85, "{row}");
    }
    let fitted: mapmerge_verify::LearnedModel = serde_json::from_value(fitted).unwrap();
    assert_eq!(fitted.forest.as_ref().map(|f| f.trees.len()), Some(40));
    assert!(fitted.ratio_weights.is_empty());
    expect_bad(
        &[
            "eval",
            "calibrate",
            "--results",
            p(&results),
            "--model",
            "forest",
            "--trees",
            "0",
        ],
        "--trees 0",
    );
    // A feature the results lack, and a broken line, are bad input naming what is wrong.
    expect_bad(
        &[
            "eval",
            "calibrate",
            "--results",
            p(&results),
            "--features",
            "dm",
        ],
        "feature `dm`",
    );
    let broken = dir.join("broken.jsonl");
    std::fs::write(&broken, "{\"id\": 1}\n").unwrap();
    expect_bad(
        &["eval", "calibrate", "--results", p(&broken)],
        "broken.jsonl:1",
    );
}
