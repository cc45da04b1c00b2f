//! Targets built scan by scan (submaps): the grid holds exactly the max of every inserted
//! point's kernel however it grew, its coarse levels stay block maxima, and a scan matches
//! the incrementally built target as it matches one built at once.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::Point2;
use mapmerge_scanmatch::{CorrelationGrid, CorrelativeParams, ScanMatcher, SearchWindow};
use proptest::prelude::*;

mod common;
use common::segment;

/// The quantised kernel value a cell centre gets from point `q` (the definition the grid
/// must follow: Olson 2009's rasterised Gaussian, max over points).
fn expected_cell(
    grid: &CorrelationGrid,
    i: i64,
    j: i64,
    points: &[Point2],
    sigma_cells: f64,
) -> u16 {
    let resolution = grid.resolution_m();
    let origin = grid.origin_m();
    let reach = (3.0 * sigma_cells).ceil() as i64;
    let mut best = 0u16;
    for q in points {
        let u = (q.x - origin.x) / resolution;
        let v = (q.y - origin.y) / resolution;
        // The kernel covers the cells within `reach` of the point's own cell.
        if (u.floor() as i64 - i).abs() > reach || (v.floor() as i64 - j).abs() > reach {
            continue;
        }
        let du = i as f64 + 0.5 - u;
        let dv = j as f64 + 0.5 - v;
        let two_sigma_sq = 2.0 * sigma_cells * sigma_cells;
        let value = ((-du * du / two_sigma_sq).exp()
            * (-dv * dv / two_sigma_sq).exp()
            * f64::from(u16::MAX))
        .round() as u16;
        best = best.max(value);
    }
    best
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn grown_grid_is_the_max_of_all_kernels(
        batches in prop::collection::vec(
            prop::collection::vec((-6.0f64..6.0, -6.0f64..6.0), 1..12), 1..5),
        margin in 0usize..20,
    ) {
        let params = CorrelativeParams::default();
        let mut grid = CorrelationGrid::empty(&params).unwrap();
        let mut all = Vec::new();
        for batch in &batches {
            let points: Vec<Point2> = batch.iter().map(|&(x, y)| Point2::new(x, y)).collect();
            grid.insert(&points, margin).unwrap();
            all.extend(points);
        }
        let (width, height) = grid.size();
        for j in 0..height as i64 {
            for i in 0..width as i64 {
                let centre = grid.origin_m()
                    + Point2::new(i as f64 + 0.5, j as f64 + 0.5) * grid.resolution_m();
                let got = (grid.likelihood(&centre) * f64::from(u16::MAX)).round() as u16;
                let want = expected_cell(&grid, i, j, &all, params.kernel_sigma_cells);
                // A point exactly on a cell boundary may fall on either side once the grid
                // has grown (the origin moves by whole cells, in floating point), which only
                // changes the kernel's outermost ring: ≤ exp(−(3σ)²/2σ²)·max ≈ 0.011·max.
                prop_assert!(
                    (i32::from(got) - i32::from(want)).abs() <= 750,
                    "cell ({}, {}): {} vs {}", i, j, got, want
                );
            }
        }
    }
}

/// A corridor with rooms off it: long enough that scans along it see different parts.
fn world() -> Vec<Point2> {
    let mut points = Vec::new();
    segment(&mut points, (0.0, 0.0), (20.0, 0.0));
    segment(&mut points, (0.0, 3.0), (6.0, 3.0));
    segment(&mut points, (7.0, 3.0), (13.0, 3.0));
    segment(&mut points, (14.0, 3.0), (20.0, 3.0));
    segment(&mut points, (0.0, 0.0), (0.0, 3.0));
    segment(&mut points, (20.0, 0.0), (20.0, 3.0));
    segment(&mut points, (6.0, 3.0), (6.0, 6.0));
    segment(&mut points, (7.0, 3.0), (7.0, 5.0));
    segment(&mut points, (13.0, 3.0), (13.0, 7.0));
    segment(&mut points, (14.0, 3.0), (14.0, 4.5));
    segment(&mut points, (3.0, 0.5), (3.6, 0.5)); // a bench
    segment(&mut points, (16.0, 2.2), (16.0, 2.8)); // a pillar
    points
}

/// The world's points within 8 m of a robot at `world_from_robot`, in the robot frame,
/// sorted by bearing (as a laser would see them, without occlusion).
fn scan_at(world_points: &[Point2], world_from_robot: &Se2) -> Vec<Point2> {
    let robot_from_world = world_from_robot.inverse();
    let mut points: Vec<Point2> = world_points
        .iter()
        .map(|p| robot_from_world.transform_point(p))
        .filter(|p| p.norm() < 8.0)
        .collect();
    points.sort_by(|a, b| a.y.atan2(a.x).total_cmp(&b.y.atan2(b.x)));
    points
}

#[test]
fn scan_matches_a_submap_built_scan_by_scan() {
    let world = world();
    let matcher = ScanMatcher::default();
    let mut submap = matcher.empty_target().unwrap();
    let poses: Vec<Se2> = (0..8)
        .map(|k| Se2::new(1.0 + 2.0 * f64::from(k), 1.5, 0.05 * f64::from(k % 3)))
        .collect();
    for pose in &poses {
        submap.insert_scan(pose, &scan_at(&world, pose)).unwrap();
    }
    let truth = Se2::new(9.3, 1.2, 0.1);
    let query = scan_at(&world, &truth);
    let guess = truth.compose(&Se2::new(0.2, -0.15, 0.05));
    let found = matcher
        .match_scan(&submap, &query, &guess, &SearchWindow::new(0.5, 0.2))
        .unwrap();
    let error = truth.between(&found.target_from_query);
    assert!(
        error.translation().norm() < 0.01 && error.theta_rad.abs() < 0.003,
        "{error:?}"
    );
    assert!(found.icp.is_some(), "ICP refined the match");
    // The same as matching a target built from all points at once.
    let all: Vec<Point2> = poses
        .iter()
        .flat_map(|pose| {
            scan_at(&world, pose)
                .into_iter()
                .map(|p| pose.transform_point(&p))
                .collect::<Vec<_>>()
        })
        .collect();
    let batch = matcher.target(&all).unwrap();
    let found_batch = matcher
        .match_scan(&batch, &query, &guess, &SearchWindow::new(0.5, 0.2))
        .unwrap();
    let difference = found_batch
        .target_from_query
        .between(&found.target_from_query);
    assert!(difference.translation().norm() < 0.01, "{difference:?}");
}

#[test]
fn empty_target_matches_nothing_and_refuses_non_finite_scans_quietly() {
    let matcher = ScanMatcher::default();
    let mut target = matcher.empty_target().unwrap();
    let scan = scan_at(&world(), &Se2::new(5.0, 1.5, 0.0));
    assert!(matcher
        .match_scan(&target, &scan, &Se2::identity(), &SearchWindow::default())
        .is_none());
    target
        .insert_scan(&Se2::identity(), &[Point2::new(f64::NAN, 1.0)])
        .unwrap();
    assert!(target.correlative().grid().is_empty());
}

/// A target rebuilt for other points — here one built scan by scan by a coarser matcher —
/// matches exactly as a target built afresh by this matcher, and an empty rebuild fails.
#[test]
fn a_retargeted_target_matches_as_a_fresh_one() {
    let world = world();
    let fine = ScanMatcher::default();
    let mut coarse_params = mapmerge_scanmatch::ScanMatchParams::default();
    coarse_params.correlative.resolution_m = 0.1;
    let coarse = ScanMatcher::new(coarse_params).unwrap();
    let mut reused = coarse.empty_target().unwrap();
    let first = Se2::new(3.0, 1.5, 0.0);
    reused
        .insert_scan(&first, &scan_at(&world, &first))
        .unwrap();
    let at = Se2::new(11.0, 1.5, 0.1);
    let target_points: Vec<Point2> = scan_at(&world, &at)
        .into_iter()
        .map(|p| at.transform_point(&p))
        .collect();
    fine.retarget(&mut reused, &target_points).unwrap();
    let fresh = fine.target(&target_points).unwrap();
    let truth = Se2::new(10.7, 1.3, 0.05);
    let query = scan_at(&world, &truth);
    let guess = truth.compose(&Se2::new(0.2, -0.15, 0.05));
    let window = SearchWindow::new(0.5, 0.2);
    assert_eq!(
        fine.match_scan(&reused, &query, &guess, &window),
        fine.match_scan(&fresh, &query, &guess, &window)
    );
    assert!(fine.retarget(&mut reused, &[]).is_err());
}

/// A target built from points makes its ICP target when a match first refines: until then it
/// holds the correlation grids alone; the refined match is the same every time; and scans
/// inserted afterwards join the ICP target made from the points before them.
#[test]
fn a_target_from_points_makes_its_icp_target_on_first_use() {
    let world = world();
    let matcher = ScanMatcher::default();
    let at = Se2::new(11.0, 1.5, 0.1);
    let target_points: Vec<Point2> = scan_at(&world, &at)
        .into_iter()
        .map(|p| at.transform_point(&p))
        .collect();
    let mut target = matcher.target(&target_points).unwrap();
    let grids_only = target.heap_bytes();
    assert_eq!(grids_only, target.correlative().heap_bytes());
    let truth = Se2::new(10.7, 1.3, 0.05);
    let query = scan_at(&world, &truth);
    let guess = truth.compose(&Se2::new(0.2, -0.15, 0.05));
    let window = SearchWindow::new(0.5, 0.2);
    let first = matcher
        .match_scan(&target, &query, &guess, &window)
        .unwrap();
    assert!(first.icp.is_some(), "{first:?}");
    assert!(target.heap_bytes() > grids_only);
    assert_eq!(
        matcher.match_scan(&target, &query, &guess, &window),
        Some(first)
    );
    // Nothing found, nothing made; a scan inserted later makes it first.
    let mut untouched = matcher.target(&target_points).unwrap();
    let far = Se2::new(-40.0, 30.0, 0.0);
    let missed = matcher.match_scan(
        &untouched,
        &scan_at(&world, &far),
        &far,
        &SearchWindow::new(0.1, 0.01),
    );
    assert!(missed.is_none(), "{missed:?}");
    assert_eq!(untouched.heap_bytes(), untouched.correlative().heap_bytes());
    untouched.insert_scan(&truth, &query).unwrap();
    assert!(untouched.heap_bytes() > untouched.correlative().heap_bytes());
    target.insert_scan(&truth, &query).unwrap();
    assert_eq!(untouched.heap_bytes(), target.heap_bytes());
}

/// A point on a cell border next to the grid's edge (found by the property test above): its
/// kernel is written, clipped to the grid, not skipped.
#[test]
fn a_point_on_a_cell_border_at_the_grids_edge_keeps_its_kernel() {
    let params = CorrelativeParams::default();
    let mut grid = CorrelationGrid::empty(&params).unwrap();
    let point = Point2::new(-0.281_167_207_026_939_37, 0.0);
    grid.insert(&[point], 0).unwrap();
    assert!(
        grid.likelihood(&point) > 0.85,
        "{}",
        grid.likelihood(&point)
    );
}
