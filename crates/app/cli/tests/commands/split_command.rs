//! Integration tests of `mapmerge split`: a public corrected log cut into segments that start
//! at their own origin, with the truth kept apart and consistent; bad input.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common::{ok_json, p, run, scratch};
use mapmerge_geometry::{LieGroup, Se2};

/// `a` and `b` within `tolerance` (m and rad).
fn close(a: &Se2, b: &Se2, tolerance: f64) -> bool {
    a.local(b).abs().max() < tolerance
}

#[test]
fn split_intel_into_four_rebased_segments_with_truth() {
    let Some(log_path) = mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz") else {
        return;
    };
    let original = mapmerge_io::read_carmen(&log_path).unwrap();
    let original_poses: Vec<Se2> = original
        .scans
        .iter()
        .map(|r| r.odom_from_robot.unwrap())
        .collect();
    for noise in ["none", "default"] {
        let dir = scratch(&format!("split-intel-{noise}"));
        let report = ok_json(&[
            "split",
            p(&log_path),
            "--segments",
            "4",
            "--overlap",
            "0.1",
            "--odometry-noise",
            noise,
            "--seed",
            "3",
            "-o",
            p(&dir),
            "--json",
        ]);
        let segments = report["segments"].as_array().unwrap();
        assert_eq!(segments.len(), 4, "{report}");
        // The same summary is kept with the truth.
        let summary: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join("truth/segments.json")).unwrap(),
        )
        .unwrap();
        assert_eq!(summary["segments"], report["segments"]);
        let mut covered = vec![false; original.scans.len()];
        let mut previous_last = None;
        for (index, entry) in segments.iter().enumerate() {
            let file = entry["file"].as_str().unwrap();
            assert_eq!(file, format!("intel_{index:02}.log"));
            let (first, last) = (
                entry["first_scan"].as_u64().unwrap() as usize,
                entry["last_scan"].as_u64().unwrap() as usize,
            );
            let scans = entry["scans"].as_u64().unwrap() as usize;
            assert_eq!(last + 1 - first, scans);
            covered[first..=last].iter_mut().for_each(|c| *c = true);
            // Consecutive segments overlap by about 10 % of a segment.
            if let Some(previous_last) = previous_last {
                let shared = previous_last + 1 - first;
                assert!(
                    (shared as f64 - 0.1 * scans as f64).abs() <= 2.0,
                    "{shared}"
                );
            }
            previous_last = Some(last);

            let segment = mapmerge_io::read_carmen(&dir.join(file)).unwrap();
            assert_eq!(segment.scans.len(), scans);
            assert_eq!(segment.odometry.len(), scans, "one ODOM per scan");
            let odometry: Vec<Se2> = segment
                .scans
                .iter()
                .map(|r| r.odom_from_robot.unwrap())
                .collect();
            // Each segment starts at its own origin, in the scans and the ODOM messages.
            assert!(
                close(&odometry[0], &Se2::identity(), 1e-9),
                "{:?}",
                odometry[0]
            );
            assert!(close(
                &segment.odometry[0].odom_from_robot,
                &Se2::identity(),
                1e-9
            ));
            // Same ranges as the original scans.
            assert_eq!(
                segment.scans[5].scan.ranges_m,
                original.scans[first + 5].scan.ranges_m
            );

            // Truth: one line per scan, the original poses with the scans' stamps.
            let truth_path = dir.join(entry["truth"].as_str().unwrap());
            let truth = mapmerge_io::read_tum_planar(&truth_path).unwrap();
            assert_eq!(truth.len(), scans);
            for (k, (stamp, pose)) in truth.iter().enumerate() {
                assert_eq!(*stamp, original.scans[first + k].stamp_secs);
                assert!(close(pose, &original_poses[first + k], 1e-6));
            }
            // Composing the truth's first pose with the segment's poses gives the original
            // poses back: exactly without noise, with drift (but not wildly) with it.
            let world_from_segment = truth[0].1;
            let worst_m = odometry
                .iter()
                .zip(&original_poses[first..=last])
                .map(|(o, t)| {
                    (world_from_segment.compose(o).translation() - t.translation()).norm()
                })
                .fold(0.0, f64::max);
            if noise == "none" {
                assert!(worst_m < 1e-6, "segment {index}: {worst_m} m");
            } else {
                assert!(
                    worst_m > 1e-3 && worst_m < 50.0,
                    "segment {index}: {worst_m} m"
                );
            }
        }
        assert!(covered.iter().all(|&c| c), "every scan is in some segment");
    }
}

#[test]
fn split_refuses_bad_input_with_exit_code_2() {
    let dir = scratch("split-bad");
    let missing = dir.join("missing.log");
    let out = run(&["split", p(&missing), "--segments", "2", "-o", p(&dir)]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("missing.log"));

    // A tiny valid log of 3 scans.
    let log = dir.join("tiny.log");
    let mut text = String::new();
    for k in 0..3 {
        text.push_str(&format!(
            "FLASER 3 1.5 2 2.5 {k} 0 0 {k} 0 0 {k}.0 host {k}.0\n"
        ));
    }
    std::fs::write(&log, text).unwrap();
    for (segments, overlap) in [("0", "0.1"), ("4", "0.1"), ("2", "1.5")] {
        let out = run(&[
            "split",
            p(&log),
            "--segments",
            segments,
            "--overlap",
            overlap,
            "-o",
            p(&dir),
        ]);
        assert_eq!(
            out.status.code(),
            Some(2),
            "{segments} segments, overlap {overlap}"
        );
    }
    let out = run(&[
        "split",
        p(&log),
        "--segments",
        "1",
        "--odometry-noise",
        "wobbly",
        "-o",
        p(&dir),
    ]);
    assert_eq!(out.status.code(), Some(2));
    // One segment of the whole tiny log works.
    let report = ok_json(&["split", p(&log), "--segments", "1", "-o", p(&dir), "--json"]);
    assert_eq!(report["segments"][0]["scans"], 3);
    assert!(dir.join("tiny_00.log").is_file());
}
