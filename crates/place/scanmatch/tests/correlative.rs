//! The correlative matcher on hand-made rooms: known transforms, whole-map search, branch-and-
//! bound against brute force, degenerate inputs.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::Point2;
use mapmerge_scanmatch::{
    match_scan, match_scan_above, match_scan_brute_force, CorrelativeParams, Match, MatchTarget,
    ScanMatchParams, ScanMatcher, SearchWindow,
};
use proptest::prelude::*;

mod common;
use common::segment;

/// An 8 × 5 m room with no symmetry: an alcove, a cabinet, a pillar and a desk.
fn room() -> Vec<Point2> {
    let mut points = Vec::new();
    segment(&mut points, (0.0, 0.0), (8.0, 0.0));
    segment(&mut points, (8.0, 0.0), (8.0, 5.0));
    segment(&mut points, (8.0, 5.0), (3.0, 5.0));
    segment(&mut points, (3.0, 5.0), (3.0, 6.2)); // alcove
    segment(&mut points, (3.0, 6.2), (0.0, 6.2));
    segment(&mut points, (0.0, 6.2), (0.0, 0.0));
    segment(&mut points, (5.5, 1.0), (6.7, 1.0)); // cabinet
    segment(&mut points, (6.7, 1.0), (6.7, 1.6));
    segment(&mut points, (6.7, 1.6), (5.5, 1.6));
    segment(&mut points, (5.5, 1.6), (5.5, 1.0));
    segment(&mut points, (2.0, 3.0), (2.3, 3.0)); // pillar
    segment(&mut points, (2.3, 3.0), (2.3, 3.3));
    segment(&mut points, (2.3, 3.3), (2.0, 3.3));
    segment(&mut points, (2.0, 3.3), (2.0, 3.0));
    segment(&mut points, (1.0, 0.8), (2.6, 0.8)); // desk
    points
}

/// The room's points in the frame of a robot at `world_from_robot`.
fn seen_from(points: &[Point2], world_from_robot: &Se2) -> Vec<Point2> {
    let robot_from_world = world_from_robot.inverse();
    points
        .iter()
        .map(|p| robot_from_world.transform_point(p))
        .collect()
}

fn assert_close(found: &Se2, truth: &Se2, linear_m: f64, angular_rad: f64) {
    let error = truth.between(found);
    assert!(
        error.translation().norm() <= linear_m && error.theta_rad.abs() <= angular_rad,
        "found {found:?}, truth {truth:?}"
    );
}

#[test]
fn recovers_known_transform_in_hand_made_room() {
    let world = room();
    let matcher = ScanMatcher::default();
    let target = matcher.target(&world).unwrap();
    for (k, truth) in [
        Se2::new(4.0, 2.5, 0.0),
        Se2::new(3.23, 2.17, 0.12),
        Se2::new(5.02, 3.4, -0.15),
    ]
    .iter()
    .enumerate()
    {
        let query = seen_from(&world, truth);
        let guess = truth.compose(&Se2::new(0.17, -0.21, 0.09 * (k as f64 - 1.0)));
        let found = matcher
            .match_scan(&target, &query, &guess, &SearchWindow::default())
            .unwrap();
        assert_close(&found.target_from_query, truth, 0.01, 0.005);
        assert!(found.score > 0.8, "{found:?}");
        assert!(found.icp.is_some());
    }
}

#[test]
fn whole_map_search_finds_pose_in_non_symmetric_room() {
    let world = room();
    let matcher = ScanMatcher::default();
    let target = matcher.target(&world).unwrap();
    let truth = Se2::new(4.4, 2.1, 2.3);
    // Only what a 6 m sensor would see around the robot.
    let query: Vec<Point2> = seen_from(&world, &truth)
        .into_iter()
        .filter(|p| p.norm() < 6.0)
        .collect();
    let found = matcher
        .match_scan(
            &target,
            &query,
            &Se2::new(4.0, 3.0, 0.0),
            &SearchWindow::global(10.0),
        )
        .unwrap();
    assert_close(&found.target_from_query, &truth, 0.02, 0.01);
    // The correlative result alone is within one step.
    assert_close(&found.correlative_target_from_query, &truth, 0.05, 0.02);
}

#[test]
fn covariance_is_symmetric_positive_definite_and_wider_along_a_corridor() {
    let mut corridor = Vec::new();
    segment(&mut corridor, (0.0, 0.0), (12.0, 0.0));
    segment(&mut corridor, (0.0, 2.0), (12.0, 2.0));
    let params = CorrelativeParams::default();
    let target = MatchTarget::new(&corridor, &params).unwrap();
    let truth = Se2::new(6.0, 1.0, 0.0);
    let query: Vec<Point2> = seen_from(&corridor, &truth)
        .into_iter()
        .filter(|p| p.norm() < 4.0)
        .collect();
    let found = match_scan(&target, &query, &truth, &SearchWindow::default()).unwrap();
    let c = found.covariance;
    assert!((c - c.transpose()).norm() < 1e-12);
    let eigen = c.symmetric_eigen();
    assert!(eigen.eigenvalues.min() > 0.0, "{c}");
    assert!(
        c[(0, 0)] > 4.0 * c[(1, 1)],
        "along-corridor variance should dominate: {c}"
    );
}

#[test]
fn empty_and_non_finite_inputs_give_none_or_an_error() {
    let params = CorrelativeParams::default();
    assert!(MatchTarget::new(&[], &params).is_err());
    assert!(MatchTarget::new(&[Point2::new(f64::NAN, 0.0)], &params).is_err());
    let huge = [Point2::new(-1e12, 0.0), Point2::new(1e12, 0.0)];
    assert!(MatchTarget::new(&huge, &params).is_err());
    let bad = CorrelativeParams {
        resolution_m: 0.0,
        ..params
    };
    assert!(MatchTarget::new(&room(), &bad).is_err());
    let target = MatchTarget::new(&room(), &params).unwrap();
    let window = SearchWindow::default();
    assert!(match_scan(&target, &[], &Se2::identity(), &window).is_none());
    let nan_points = [Point2::new(f64::NAN, 1.0)];
    assert!(match_scan(&target, &nan_points, &Se2::identity(), &window).is_none());
    let nan_pose = Se2 {
        x_m: 0.0,
        y_m: f64::NAN,
        theta_rad: 0.0,
    };
    assert!(match_scan(&target, &room(), &nan_pose, &window).is_none());
    let nan_window = SearchWindow::new(f64::NAN, 0.1);
    assert!(match_scan(&target, &room(), &Se2::identity(), &nan_window).is_none());
    let infinite_window = SearchWindow::new(f64::INFINITY, f64::INFINITY);
    assert!(match_scan(&target, &room(), &Se2::identity(), &infinite_window).is_none());
    let huge_window = SearchWindow::new(1e4, std::f64::consts::PI);
    assert!(match_scan(&target, &room(), &Se2::identity(), &huge_window).is_none());
    // Far away from everything: no pose reaches min_score.
    let far = Se2::new(100.0, 100.0, 0.0);
    assert!(match_scan(&target, &room(), &far, &window).is_none());
}

fn random_target(seed: &[(f64, f64, f64, f64)]) -> Vec<Point2> {
    let mut points = Vec::new();
    for &(x0, y0, x1, y1) in seed {
        segment(&mut points, (x0, y0), (x1, y1));
    }
    points
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn branch_and_bound_equals_brute_force(
        segments in prop::collection::vec((-2.0..2.0f64, -2.0..2.0f64, -2.0..2.0f64, -2.0..2.0f64), 1..6),
        offset in (-0.2..0.2f64, -0.2..0.2f64, -0.2..0.2f64),
        linear_m in 0.0..0.35f64,
        angular_rad in 0.0..0.25f64,
        depth in 0usize..6,
        min_score in 0.0..0.6f64,
        keep_every in 1usize..4,
    ) {
        let points = random_target(&segments);
        let params = CorrelativeParams { branch_and_bound_depth: depth, min_score, ..CorrelativeParams::default() };
        let target = MatchTarget::new(&points, &params).unwrap();
        let truth = Se2::new(offset.0, offset.1, offset.2);
        let query: Vec<Point2> = seen_from(&points, &truth).into_iter().step_by(keep_every).collect();
        let window = SearchWindow::new(linear_m, angular_rad);
        let fast = match_scan(&target, &query, &Se2::identity(), &window);
        let slow = match_scan_brute_force(&target, &query, &Se2::identity(), &window);
        match (fast, slow) {
            (None, None) => {}
            (Some(fast), Some(slow)) => {
                prop_assert_eq!(fast.target_from_query, slow.target_from_query);
                prop_assert_eq!(fast.score, slow.score);
                prop_assert_eq!(fast.covariance, slow.covariance);
                prop_assert!(fast.candidates > 0);
            }
            (fast, slow) => prop_assert!(false, "fast {:?} slow {:?}", fast, slow),
        }
    }

    /// With a floor of its own, the search finds the same optimum when that reaches the
    /// floor and nothing otherwise, never with more candidates than the target's floor.
    #[test]
    fn a_higher_floor_keeps_the_optimum_above_it(
        segments in prop::collection::vec((-2.0..2.0f64, -2.0..2.0f64, -2.0..2.0f64, -2.0..2.0f64), 1..6),
        offset in (-0.2..0.2f64, -0.2..0.2f64, -0.2..0.2f64),
        depth in 0usize..6,
        floor in 0.0..1.0f64,
    ) {
        let points = random_target(&segments);
        let params = CorrelativeParams { branch_and_bound_depth: depth, min_score: 0.0, ..CorrelativeParams::default() };
        let target = MatchTarget::new(&points, &params).unwrap();
        let truth = Se2::new(offset.0, offset.1, offset.2);
        let query = seen_from(&points, &truth);
        let window = SearchWindow::new(0.3, 0.2);
        let all = match_scan(&target, &query, &Se2::identity(), &window).unwrap();
        let above = match_scan_above(&target, &query, &Se2::identity(), &window, floor);
        if all.score >= floor {
            let above = above.unwrap();
            prop_assert_eq!(above.target_from_query, all.target_from_query);
            prop_assert_eq!(above.score, all.score);
            prop_assert!(above.candidates <= all.candidates);
        } else {
            prop_assert!(above.is_none(), "{:?} below {}", above, floor);
        }
    }

    /// The floor is applied exactly as a caller compares scores: a floor at the optimum's own
    /// score keeps it, the next score up refuses it, and so does the target's own floor when
    /// the caller's is lower. The matcher (correlative search, then ICP) gives the same match
    /// with a floor it reaches as without one.
    #[test]
    fn a_floor_at_the_optimums_score_keeps_it_and_the_next_score_up_refuses_it(
        segments in prop::collection::vec((-2.0..2.0f64, -2.0..2.0f64, -2.0..2.0f64, -2.0..2.0f64), 1..6),
        offset in (-0.2..0.2f64, -0.2..0.2f64, -0.2..0.2f64),
        keep_every in 1usize..7,
    ) {
        let points = random_target(&segments);
        let mut params = ScanMatchParams::default();
        params.correlative.min_score = 0.0;
        let matcher = ScanMatcher::new(params).unwrap();
        let target = matcher.target(&points).unwrap();
        let truth = Se2::new(offset.0, offset.1, offset.2);
        let query: Vec<Point2> = seen_from(&points, &truth).into_iter().step_by(keep_every).collect();
        let window = SearchWindow::new(0.3, 0.2);
        let all = matcher.match_scan(&target, &query, &Se2::identity(), &window).unwrap();
        prop_assume!(all.score > 0.0);
        let at = matcher.match_scan_above(&target, &query, &Se2::identity(), &window, all.score);
        // The same match, found with fewer candidates scored.
        let at = at.unwrap();
        prop_assert!(at.candidates <= all.candidates);
        prop_assert_eq!(Match { candidates: all.candidates, ..at }, all);
        let next_up = f64::from_bits(all.score.to_bits() + 1);
        let above = matcher.match_scan_above(&target, &query, &Se2::identity(), &window, next_up);
        prop_assert!(above.is_none(), "{:?} above {}", above, next_up);
        // A lower floor of the caller's does not lower the target's own.
        params.correlative.min_score = next_up;
        let strict = ScanMatcher::new(params).unwrap();
        let strict_target = strict.target(&points).unwrap();
        let below = strict.match_scan_above(&strict_target, &query, &Se2::identity(), &window, 0.0);
        prop_assert!(below.is_none(), "{:?} below the target's {}", below, next_up);
    }
}

#[test]
fn branch_and_bound_equals_brute_force_over_the_whole_circle() {
    let world = room();
    let params = CorrelativeParams {
        min_score: 0.0,
        ..CorrelativeParams::default()
    };
    let target = MatchTarget::new(&world, &params).unwrap();
    let truth = Se2::new(4.1, 2.6, -2.8);
    let query: Vec<Point2> = seen_from(&world, &truth)
        .into_iter()
        .filter(|p| p.norm() < 3.0)
        .step_by(3)
        .collect();
    let guess = Se2::new(4.0, 2.5, 0.0);
    let window = SearchWindow::new(0.2, std::f64::consts::PI);
    let fast = match_scan(&target, &query, &guess, &window).unwrap();
    let slow = match_scan_brute_force(&target, &query, &guess, &window).unwrap();
    assert_eq!(fast.target_from_query, slow.target_from_query);
    assert_eq!(fast.score, slow.score);
    assert!(
        fast.candidates < slow.candidates / 4,
        "{} vs {}",
        fast.candidates,
        slow.candidates
    );
    assert_close(&fast.target_from_query, &truth, 0.05, 0.03);
}
