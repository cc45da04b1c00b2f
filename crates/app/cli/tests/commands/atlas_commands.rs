//! Integration tests of `mapmerge atlas`: the simulated look-alike office (runs without
//! ../shared), a public log cut by a kidnap, and bad input.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common::{ok_json, p, run, scratch};

/// Every line of `events.jsonl` as JSON.
fn events(dir: &std::path::Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(dir.join("events.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

#[test]
fn the_simulated_office_runs_end_to_end_and_every_unmerge_undoes_earlier_merges() {
    let dir = scratch("atlas-sim");
    let report = ok_json(&[
        "atlas",
        "--sim",
        "office-aliased",
        "--sessions",
        "2",
        "--duration",
        "60",
        // A wrong conditional merge rejected and a correct full one (the default seed 12
        // merges nothing in 2 × 60 s since look-alike views that fit themselves elsewhere
        // count for nothing).
        "--seed",
        "1",
        "-o",
        p(&dir),
        "--merge-results",
        p(&dir.join("merges.jsonl")),
        "--json",
    ]);
    assert_eq!(report["sessions"], 2, "{report}");
    let events = events(&dir);
    assert_eq!(events[0]["event"], "epoch_started");
    // Epochs: one per session at least, one more per simulated kidnap.
    let started = events
        .iter()
        .filter(|e| e["event"] == "epoch_started")
        .count();
    assert!(started >= 2, "{report}");
    assert_eq!(report["epochs"].as_u64().unwrap() as usize, started);
    // An unmerge names merges that happened before it; scans and travel never go back.
    let mut merged = Vec::new();
    let mut last = (0, 0.0);
    for e in &events {
        let now = (e["scan"].as_u64().unwrap(), e["travel_m"].as_f64().unwrap());
        assert!(now.0 >= last.0 && now.1 >= last.1, "{e}");
        last = now;
        match e["event"].as_str().unwrap() {
            "merged" => merged.push(e["merge"].as_u64().unwrap()),
            "unmerged" => {
                for m in e["merges"].as_array().unwrap() {
                    assert!(merged.contains(&m.as_u64().unwrap()), "{e}");
                }
                assert!(e["reason"]["invalidity"].as_f64().unwrap() > 0.0, "{e}");
            }
            _ => {}
        }
    }
    // Every merge decision is judged against the simulator's truth, has a state, and is
    // pictured (before and after each conditional merge, full merge and unmerge).
    for m in report["merges"].as_array().unwrap() {
        assert!(m["correct"].is_boolean(), "{m}");
        // Its median merge edge's error against the truth, and the verdict follows it.
        let error = m["error_m_deg"].as_array().unwrap();
        let (error_m, error_deg) = (error[0].as_f64().unwrap(), error[1].as_f64().unwrap());
        if error_m > 0.5 || error_deg > 10.0 {
            assert_eq!(m["correct"], false, "{m}");
        }
        let state = m["state"].as_str().unwrap();
        assert!(
            ["conditional", "full", "rejected", "undone"].contains(&state),
            "{m}"
        );
        if state == "rejected" || state == "undone" {
            assert!(
                m["reason"].is_string() && m["undone_after_m"].is_number(),
                "{m}"
            );
        }
    }
    let conditional = events
        .iter()
        .filter(|e| e["event"] == "conditional_merge")
        .count();
    let pictures = report["pictures"].as_array().unwrap();
    assert_eq!(
        pictures.len(),
        2 * (merged.len() + conditional + report["unmerges"].as_array().unwrap().len())
    );
    for key in [
        "created",
        "merge",
        "recovery",
        "conditional",
        "full",
        "rejected_conditional",
        "expired",
    ] {
        assert!(report["hypotheses"][key].is_u64(), "{report}");
    }
    assert!(report["ambiguous_keyframes"].is_u64());
    let searched = &report["self_similarity"];
    assert!(
        searched["self_similar"].as_u64().unwrap() <= searched["views"].as_u64().unwrap(),
        "{searched}"
    );
    assert!(
        searched["joint_unique"].as_u64().unwrap() <= searched["joint_searched"].as_u64().unwrap(),
        "{searched}"
    );
    assert!(searched["seconds"].as_f64().unwrap() >= 0.0);
    // Every epoch's merge hypotheses and how far they got: one entry per epoch; an epoch
    // ending merged made a merge, and a merged epoch is one of those.
    let outcomes = report["epoch_outcomes"].as_array().unwrap();
    assert_eq!(outcomes.len(), started, "{report}");
    let ends = [
        "merged",
        "merge_undone",
        "conditional_never_full",
        "hypotheses_never_conditional",
        "no_hypothesis",
    ];
    let mut ended_merged = 0;
    for (k, o) in outcomes.iter().enumerate() {
        assert_eq!(o["epoch"].as_u64().unwrap() as usize, k, "{o}");
        let end = o["end"].as_str().unwrap();
        assert!(ends.contains(&end), "{o}");
        if end == "merged" {
            ended_merged += 1;
            assert!(o["merges"].as_u64().unwrap() >= 1, "{o}");
        }
        if end == "no_hypothesis" {
            assert_eq!(o["hypotheses"], 0, "{o}");
        }
    }
    assert!(
        ended_merged >= report["epochs_merged_correctly"].as_u64().unwrap(),
        "{report}"
    );
    // Every later epoch's revisit of earlier places, against the truth: one entry per epoch
    // after the first, the revisit part of its path, and the merged ones as counted above.
    let revisits = report["epoch_revisits"].as_array().unwrap();
    assert_eq!(revisits.len(), started - 1, "{report}");
    let mut merged_correctly = 0;
    let mut revisiting = (0, 0);
    for (k, e) in revisits.iter().enumerate() {
        assert_eq!(e["epoch"].as_u64().unwrap() as usize, k + 1);
        let (travel, revisit) = (
            e["travel_m"].as_f64().unwrap(),
            e["revisit_travel_m"].as_f64().unwrap(),
        );
        assert!((0.0..=travel + 1e-9).contains(&revisit), "{e}");
        let merged = e["merged_correctly"].as_bool().unwrap();
        merged_correctly += usize::from(merged);
        if revisit >= 5.0 {
            revisiting.0 += 1;
            revisiting.1 += usize::from(merged);
        }
    }
    assert_eq!(
        report["epochs_merged_correctly"].as_u64().unwrap() as usize,
        merged_correctly
    );
    assert_eq!(
        report["epochs_revisiting"].as_u64().unwrap() as usize,
        revisiting.0
    );
    assert_eq!(
        report["epochs_revisiting_merged_correctly"]
            .as_u64()
            .unwrap() as usize,
        revisiting.1
    );
    assert!(dir.join("atlas/active.g2o").is_file());
    // --merge-results: one line per judged merge and method (the detector's own reading
    // first), labelled by the truth, in the format `eval calibrate --results` reads.
    let lines: Vec<serde_json::Value> = std::fs::read_to_string(dir.join("merges.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let mut expected = Vec::new();
    for (k, m) in report["merges"].as_array().unwrap().iter().enumerate() {
        for reading in m["readings"].as_array().unwrap() {
            let label = if m["correct"] == true {
                "valid"
            } else {
                "invalid"
            };
            expected.push((
                format!(
                    "sim-office-aliased/{}/merge{k}",
                    dir.file_name().unwrap().to_string_lossy()
                ),
                reading["method"].as_str().unwrap().to_owned(),
                label,
                reading["peak_ratio"].as_f64().unwrap(),
            ));
        }
        if let Some(first) = m["readings"].as_array().unwrap().first() {
            assert_eq!(first["method"], "learned", "{m}");
        }
    }
    let got: Vec<_> = lines
        .iter()
        .map(|l| {
            (
                l["id"].as_str().unwrap().to_owned(),
                l["method"].as_str().unwrap().to_owned(),
                l["label"].as_str().unwrap(),
                l["max_invalidity"].as_f64().unwrap(),
            )
        })
        .collect();
    assert_eq!(got, expected);
    assert!(!got.is_empty(), "no merge was judged on this seed");
    assert!(lines.iter().all(|l| l["log"] == "sim-office-aliased"));
}

/// `mapmerge atlas LOG --odometry-noise default --seed 1 --no-pictures -o DIR --json`.
pub(crate) fn noisy_atlas_seed_1(
    log: &std::path::Path,
    dir: &std::path::Path,
) -> serde_json::Value {
    ok_json(&[
        "atlas",
        p(log),
        "--odometry-noise",
        "default",
        "--seed",
        "1",
        "--no-pictures",
        "-o",
        p(dir),
        "--json",
    ])
}

#[test]
fn a_carried_robot_with_noisy_odometry_is_judged_against_the_corrected_poses() {
    let Some(log) = mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz") else {
        return;
    };
    let dir = scratch("atlas-intel-noisy");
    let report = noisy_atlas_seed_1(&log, &dir);
    // Kidnaps drawn by the seed: each carry's scans are missing, each starts an epoch.
    let carries = report["carries"][0].as_array().unwrap();
    assert!(!carries.is_empty() && carries.len() <= 4, "{report}");
    let skipped: u64 = carries
        .iter()
        .map(|c| c["resume"].as_u64().unwrap() - c["at"].as_u64().unwrap())
        .sum();
    assert_eq!(report["scans"].as_u64().unwrap(), 910 - skipped, "{report}");
    assert_eq!(
        report["epochs"].as_u64().unwrap() as usize,
        1 + carries.len()
    );
    let ended: Vec<_> = events(&dir)
        .into_iter()
        .filter(|e| e["event"] == "epoch_ended")
        .collect();
    assert!(ended.iter().all(|e| e["reason"] == "kidnap"), "{ended:?}");
    // Judged against the corrected poses, as the simulator's runs are.
    assert!(report["wrong_merges"].is_u64() && report["epoch_revisits"].is_array());
    // Every kept scan is in one map's trajectory exactly once, as maps.json lists it, and the
    // judgement from those files covers every segment.
    let maps: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("maps.json")).unwrap()).unwrap();
    assert_eq!(maps, report["maps"]);
    let mut seen = vec![0u32; report["scans"].as_u64().unwrap() as usize];
    for map in maps.as_array().unwrap() {
        let mut listed = 0;
        for epoch in map["epochs"].as_array().unwrap() {
            for range in epoch["scan_ranges"].as_array().unwrap() {
                let (a, b) = (range[0].as_u64().unwrap(), range[1].as_u64().unwrap());
                for k in a..=b {
                    seen[k as usize] += 1;
                }
                listed += b + 1 - a;
            }
        }
        let tum = std::fs::read_to_string(map["trajectory"].as_str().unwrap()).unwrap();
        assert_eq!(tum.lines().count() as u64, listed, "{map}");
        assert_eq!(map["scans"].as_u64().unwrap(), listed);
        let reference = dir
            .join("maps")
            .join(map["map"].as_str().unwrap())
            .join("reference.tum");
        assert_eq!(
            std::fs::read_to_string(reference).unwrap().lines().count() as u64,
            listed
        );
    }
    assert!(seen.iter().all(|&n| n == 1), "{seen:?}");
    let judged = &report["from_trajectories"];
    assert_eq!(judged["scans_in_no_map"], 0, "{judged}");
    assert_eq!(
        judged["segments"].as_array().unwrap().len(),
        1 + carries.len(),
        "{judged}"
    );
    // The same seed draws the same run; a bad profile is bad input.
    let again = noisy_atlas_seed_1(&log, &dir.join("again"));
    assert_eq!(again["merges"], report["merges"]);
    let out = run(&["atlas", p(&log), "--odometry-noise", "wild", "-o", p(&dir)]);
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn a_public_log_cut_by_a_kidnap_gives_two_epochs() {
    let Some(log) = mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz") else {
        return;
    };
    let dir = scratch("atlas-intel");
    let report = ok_json(&[
        "atlas",
        p(&log),
        "--kidnap-at",
        "450",
        "--no-pictures",
        "-o",
        p(&dir),
        "--json",
    ]);
    assert_eq!(report["scans"], 910, "{report}");
    assert_eq!(report["epochs"], 2, "{report}");
    // Without ground truth nothing is judged.
    assert!(report["wrong_merges"].is_null());
    assert!(report["epoch_revisits"].is_null());
    let kidnap = events(&dir)
        .into_iter()
        .find(|e| e["event"] == "epoch_ended")
        .unwrap();
    assert_eq!(kidnap["reason"], "kidnap");
    assert_eq!(kidnap["scan"], 450);
}

#[test]
fn bad_input_is_refused_with_exit_code_2() {
    let dir = scratch("atlas-bad");
    let missing = dir.join("missing.log");
    let out = run(&["atlas", p(&missing), "-o", p(&dir)]);
    assert_eq!(out.status.code(), Some(2), "{out:?}");
    let out = run(&["atlas", "--sim", "no-such-world", "-o", p(&dir)]);
    assert_eq!(out.status.code(), Some(2), "{out:?}");
    let out = run(&["atlas", "-o", p(&dir)]);
    assert_eq!(out.status.code(), Some(2), "{out:?}");
}

#[test]
fn eval_lifelong_judges_a_kidnapped_robot_from_its_maps() {
    let Some(log) = mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz") else {
        return;
    };
    let dir = scratch("eval-lifelong");
    let report = ok_json(&[
        "eval",
        "lifelong",
        p(&log),
        "--seeds",
        "1",
        "--diagnose",
        "-o",
        p(&dir),
        "--json",
    ]);
    let run = &report["runs"][0];
    assert_eq!(run["run"], "intel-s1", "{report}");
    // Seed 1 carries the robot three times; all three later segments come back where an
    // earlier one had been, and each ends merged into one map and placed there.
    assert_eq!(run["segments"], 4, "{run}");
    assert_eq!(run["revisiting"], 3, "{run}");
    assert_eq!(run["merged"], 3, "{run}");
    assert_eq!(run["misplaced"], 0, "{run}");
    // A relocalization distance per merged segment, the full merge after the conditional.
    let (conditional, full) = (
        run["to_conditional_m"].as_array().unwrap(),
        run["to_full_m"].as_array().unwrap(),
    );
    assert_eq!(full.len(), 3);
    for (c, f) in conditional.iter().zip(full) {
        assert!(c.as_f64().unwrap() <= f.as_f64().unwrap(), "{run}");
    }
    assert!(dir.join("intel-s1/maps.json").exists());
    // The merge queries at true revisits, stage by stage: each stage keeps at most what the
    // one before it kept, and the merges came from accepted true matches.
    let q = &run["queries"];
    let stage = |name: &str| q[name].as_u64().unwrap();
    let stages = [
        "revisit_queries",
        "retrieved_true",
        "admitted_true",
        "verified_true",
        "verified_true_above",
    ];
    for pair in stages.windows(2) {
        assert!(stage(pair[0]) >= stage(pair[1]), "{q}");
    }
    assert!(
        stage("accepted_true") >= 3 && stage("accepted_wrong") == 0,
        "{q}"
    );
    assert!(!q["scores_true"].as_array().unwrap().is_empty());
}
