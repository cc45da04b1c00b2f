//! `find_loop_candidates` on hand-made scenes: it finds the right place and pose, stays
//! deterministic, and survives empty and non-finite keyframes.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::BruteForceVerifier;
use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_place::{find_loop_candidates, Keyframe, PlaceParams};
use mapmerge_scan::Point2;

/// Wall points of an irregular polygon room number `k` (each a different shape), world frame.
fn room_walls(k: u32) -> Vec<Point2> {
    let s = 1.0 + 0.25 * f64::from(k);
    let corners = [
        Point2::new(-3.0, -2.0 * s),
        Point2::new(4.0 * s, -2.0),
        Point2::new(4.0, 2.5 + 0.5 * s),
        Point2::new(-s, 3.0),
        Point2::new(-3.5, 1.0),
    ];
    let mut points = Vec::new();
    for i in 0..corners.len() {
        let (a, b) = (corners[i], corners[(i + 1) % corners.len()]);
        let n = ((b - a).norm() / 0.03).ceil() as usize;
        for j in 0..n {
            points.push(a + (b - a) * (j as f64 / n as f64));
        }
    }
    points
}

fn keyframe(id: u64, world_points: &[Point2], world_from_keyframe: &Se2) -> Keyframe {
    let keyframe_from_world = world_from_keyframe.inverse();
    Keyframe::new(
        id,
        world_points
            .iter()
            .map(|p| keyframe_from_world.transform_point(p))
            .collect::<Vec<_>>(),
    )
}

#[test]
fn finds_the_right_room_and_pose() {
    let rooms: Vec<Vec<Point2>> = (0..6).map(room_walls).collect();
    let b: Vec<Keyframe> = rooms
        .iter()
        .enumerate()
        .map(|(i, r)| keyframe(100 + i as u64, r, &Se2::new(0.0, 0.0, 0.3 * i as f64)))
        .collect();
    let poses_a: Vec<Se2> = (0..6)
        .map(|i| Se2::new(0.2, -0.15, 2.0 - 0.7 * i as f64))
        .collect();
    let mut a: Vec<Keyframe> = rooms
        .iter()
        .zip(&poses_a)
        .enumerate()
        .map(|(i, (r, pose))| keyframe(i as u64, r, pose))
        .collect();
    a.push(Keyframe::new(98, Vec::new()));
    a.push(Keyframe::new(99, vec![Point2::new(f64::NAN, 0.0); 10]));
    let verifier = BruteForceVerifier::default();
    let loops = find_loop_candidates(&a, &b, &verifier, &PlaceParams::default());
    assert_eq!(loops.len(), 6, "{loops:?}");
    for (i, l) in loops.iter().enumerate() {
        assert_eq!(l.a.0, i as u64);
        assert_eq!(l.b.0, 100 + i as u64);
        let truth = common::between(&Se2::new(0.0, 0.0, 0.3 * i as f64), &poses_a[i]);
        assert!(
            (l.b_from_a.translation() - truth.translation()).norm() < 0.1,
            "{l:?} vs {truth:?}"
        );
        assert!(wrap_angle_rad(l.b_from_a.theta_rad - truth.theta_rad).abs() < 0.04);
        assert!(l.score > 0.9 && l.confidence > 0.3, "{l:?}");
    }
    // Deterministic.
    assert_eq!(
        loops,
        find_loop_candidates(&a, &b, &verifier, &PlaceParams::default())
    );
    // Nothing to find.
    assert!(find_loop_candidates(&a, &[], &verifier, &PlaceParams::default()).is_empty());
    assert!(find_loop_candidates(&[], &b, &verifier, &PlaceParams::default()).is_empty());
}

#[test]
fn identical_rooms_get_low_confidence() {
    // Rooms 0 and 20 positions apart in B are copies: the match is right but ambiguous.
    let room = room_walls(1);
    let mut b: Vec<Keyframe> = (0..30)
        .map(|i| keyframe(i, &room_walls(10 + i as u32), &Se2::identity()))
        .collect();
    b[0] = keyframe(0, &room, &Se2::identity());
    b[20] = keyframe(20, &room, &Se2::identity());
    let a = vec![keyframe(1000, &room, &Se2::new(0.1, 0.1, 1.0))];
    let loops = find_loop_candidates(
        &a,
        &b,
        &BruteForceVerifier::default(),
        &PlaceParams::default(),
    );
    assert_eq!(loops.len(), 1);
    assert!(loops[0].b.0 == 0 || loops[0].b.0 == 20);
    assert!(loops[0].confidence < 0.1, "{:?}", loops[0]);
}
