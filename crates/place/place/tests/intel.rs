//! Retrieval of revisits on the Intel Research Lab log (corrected poses): scans far apart in
//! the log but within 0.5 m and 10° of each other must find each other.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::scan_points;
use mapmerge_geometry::{wrap_angle_rad, Se2};
use mapmerge_place::{PlaceIndex, ScanContext};

/// Scans closer than this in the log are the same visit, not a revisit.
const MIN_INDEX_GAP: usize = 30;

#[test]
fn intel_revisits_are_retrieved() {
    let Some(path) = mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz") else {
        return;
    };
    let log = mapmerge_io::read_carmen(&path).unwrap();
    let scans: Vec<(Vec<mapmerge_scan::Point2>, Se2)> = log
        .scans
        .iter()
        .filter_map(|r| Some((scan_points(&r.scan), r.odom_from_robot?)))
        .collect();
    assert!(scans.len() > 500);
    let params = common::descriptor_params();
    let started = std::time::Instant::now();
    let descriptors: Vec<ScanContext> = scans
        .iter()
        .map(|(p, _)| ScanContext::new(p, &params))
        .collect();
    let describe_secs = started.elapsed().as_secs_f64();
    let mut index: PlaceIndex = PlaceIndex::new(common::index_params());
    for (i, d) in descriptors.iter().enumerate() {
        index.insert(mapmerge_place::KeyframeId(i as u64), d.clone());
    }
    let revisit = |a: &Se2, b: &Se2, metres: f64, degrees: f64| {
        (a.translation() - b.translation()).norm() < metres
            && wrap_angle_rad(a.theta_rad - b.theta_rad).abs() < degrees.to_radians()
    };
    let (mut total, mut strict1, mut strict5, mut loose1, mut loose5) = (0, 0, 0, 0, 0);
    let started = std::time::Instant::now();
    for i in 0..scans.len() {
        let pose = &scans[i].1;
        let has_revisit = scans
            .iter()
            .enumerate()
            .any(|(j, (_, p))| i.abs_diff(j) > MIN_INDEX_GAP && revisit(pose, p, 0.5, 10.0));
        if !has_revisit {
            continue;
        }
        total += 1;
        let found = index.query_filtered(&descriptors[i], 5, |ordinal, _| {
            ordinal.abs_diff(i) > MIN_INDEX_GAP
        });
        let hit = |c: &mapmerge_place::Candidate, m: f64, deg: f64| {
            revisit(pose, &scans[c.keyframe.0 as usize].1, m, deg)
        };
        strict1 += usize::from(found.first().is_some_and(|c| hit(c, 0.5, 10.0)));
        strict5 += usize::from(found.iter().any(|c| hit(c, 0.5, 10.0)));
        loose1 += usize::from(found.first().is_some_and(|c| hit(c, 1.5, 30.0)));
        loose5 += usize::from(found.iter().any(|c| hit(c, 1.5, 30.0)));
    }
    let query_secs = started.elapsed().as_secs_f64();
    let r = |n: usize| n as f64 / total.max(1) as f64;
    println!(
        "intel: {} scans indexed ({describe_secs:.2} s to describe), {total} queries with a revisit; \
         recall@1 {:.3}, recall@5 {:.3} (hit: within 0.5 m and 10°); recall@1 {:.3}, recall@5 {:.3} (within 1.5 m and 30°); {:.2} ms per query incl. revisit search",
        scans.len(),
        r(strict1),
        r(strict5),
        r(loose1),
        r(loose5),
        1e3 * query_secs / total.max(1) as f64
    );
    assert!(total > 50);
    assert!(r(strict5) > 0.7, "recall@5 {}", r(strict5));
}
