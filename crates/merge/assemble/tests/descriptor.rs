//! The ring-spectrum descriptors' invariances on synthetic worlds: yaw (exact by construction,
//! up to beam resampling), small translations (distance small next to other places), distinct
//! places, empty input, and rotation about z in 3D.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::f64::consts::{PI, TAU};

use mapmerge_assemble::{
    cosine_distance, describe_submaps, Point3, RingSpectrumDescriptor, RingSpectrumDescriptor3,
    SegmentSubmap, SubmapDescriptor,
};
use mapmerge_geometry::wrap_angle_rad;
use mapmerge_scan::Point2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Wall segments of a random office-like floor: a 24 m × 24 m boundary, interior walls with
/// door gaps, and boxes (furniture).
fn world(seed: u64) -> Vec<(Point2, Point2)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut walls = Vec::new();
    let corners = [(-12.0, -12.0), (12.0, -12.0), (12.0, 12.0), (-12.0, 12.0)];
    for k in 0..4 {
        let (a, b) = (corners[k], corners[(k + 1) % 4]);
        walls.push((Point2::new(a.0, a.1), Point2::new(b.0, b.1)));
    }
    // Interior walls, horizontal or vertical, each with a 1 m door.
    for _ in 0..6 {
        let at: f64 = rng.random_range(-9.0..9.0);
        let from: f64 = rng.random_range(-12.0..0.0);
        let to: f64 = rng.random_range(2.0..12.0);
        let door: f64 = rng.random_range(from + 0.5..to - 1.5);
        let horizontal = rng.random::<bool>();
        for (s, e) in [(from, door), (door + 1.0, to)] {
            let (a, b) = if horizontal {
                (Point2::new(s, at), Point2::new(e, at))
            } else {
                (Point2::new(at, s), Point2::new(at, e))
            };
            walls.push((a, b));
        }
    }
    for _ in 0..12 {
        let c = Point2::new(rng.random_range(-11.0..11.0), rng.random_range(-11.0..11.0));
        let (w, h) = (rng.random_range(0.3..2.0), rng.random_range(0.3..2.0));
        let p = [
            c + Point2::new(-w, -h) * 0.5,
            c + Point2::new(w, -h) * 0.5,
            c + Point2::new(w, h) * 0.5,
            c + Point2::new(-w, h) * 0.5,
        ];
        for k in 0..4 {
            walls.push((p[k], p[(k + 1) % 4]));
        }
    }
    walls
}

/// A 360° scan (0.5° beams, 10 m) from `(x, y, heading)`, as points in the robot frame.
fn scan(walls: &[(Point2, Point2)], x_m: f64, y_m: f64, heading_rad: f64) -> Vec<Point2> {
    let origin = Point2::new(x_m, y_m);
    let mut points = Vec::new();
    for i in 0..720 {
        let beam_rad = i as f64 * TAU / 720.0;
        let direction = Point2::new(
            (heading_rad + beam_rad).cos(),
            (heading_rad + beam_rad).sin(),
        );
        let mut nearest = f64::INFINITY;
        for (a, b) in walls {
            let edge = b - a;
            let denominator = direction.x * edge.y - direction.y * edge.x;
            if denominator.abs() < 1e-12 {
                continue;
            }
            let offset = a - origin;
            let t = (offset.x * edge.y - offset.y * edge.x) / denominator;
            let u = (offset.x * direction.y - offset.y * direction.x) / denominator;
            if t > 0.0 && (0.0..=1.0).contains(&u) {
                nearest = nearest.min(t);
            }
        }
        if nearest < 10.0 {
            points.push(Point2::new(
                nearest * beam_rad.cos(),
                nearest * beam_rad.sin(),
            ));
        }
    }
    points
}

/// A free spot of `walls`' world: at least 0.8 m from every wall.
fn free_spot(walls: &[(Point2, Point2)], rng: &mut ChaCha8Rng) -> Point2 {
    loop {
        let p = Point2::new(rng.random_range(-9.0..9.0), rng.random_range(-9.0..9.0));
        let clear = walls.iter().all(|(a, b)| {
            let edge = b - a;
            let t = ((p - a).dot(&edge) / edge.norm_squared()).clamp(0.0, 1.0);
            (a + edge * t - p).norm() > 0.8
        });
        if clear {
            return p;
        }
    }
}

#[test]
fn yaw_leaves_the_descriptor_unchanged_and_relative_yaw_recovers_it() {
    let descriptor = RingSpectrumDescriptor::default();
    assert_eq!(descriptor.dim(), 256);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut worst_distance = 0.0f32;
    let mut worst_yaw_deg = 0.0f64;
    for seed in 0..6 {
        let walls = world(seed);
        let spot = free_spot(&walls, &mut rng);
        let candidate = scan(&walls, spot.x, spot.y, 0.0);
        let d_candidate = descriptor.describe(&candidate);
        for _ in 0..6 {
            let yaw_rad = rng.random_range(-PI..PI);
            let query = scan(&walls, spot.x, spot.y, yaw_rad);
            let distance = cosine_distance(&descriptor.describe(&query), &d_candidate);
            worst_distance = worst_distance.max(distance);
            let estimate = descriptor.relative_yaw(&query, &candidate).unwrap();
            let error_deg = wrap_angle_rad(estimate.yaw_rad - yaw_rad)
                .abs()
                .to_degrees();
            worst_yaw_deg = worst_yaw_deg.max(error_deg);
            assert!(estimate.score > 0.9, "score {}", estimate.score);
        }
    }
    eprintln!("rotation: worst distance {worst_distance}, worst yaw error {worst_yaw_deg}°");
    // Different places lie at 0.07 (median), a 0.5 m move at 0.01: a turn must stay far below.
    assert!(worst_distance < 0.002, "{worst_distance}");
    assert!(worst_yaw_deg < 3.0, "{worst_yaw_deg}");
}

/// Median of `values`.
fn median(values: &mut [f32]) -> f32 {
    values.sort_by(|a, b| a.total_cmp(b));
    values[values.len() / 2]
}

#[test]
fn small_translations_stay_closer_than_other_places() {
    let descriptor = RingSpectrumDescriptor::default();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    // Places: two spots in each of 8 worlds.
    let mut places = Vec::new();
    for seed in 100..108 {
        let walls = world(seed);
        for _ in 0..2 {
            let spot = free_spot(&walls, &mut rng);
            places.push((walls.clone(), spot));
        }
    }
    let reference: Vec<Vec<f32>> = places
        .iter()
        .map(|(walls, spot)| descriptor.describe(&scan(walls, spot.x, spot.y, 0.0)))
        .collect();
    let mut others = Vec::new();
    for (i, a) in reference.iter().enumerate() {
        for b in &reference[i + 1..] {
            others.push(cosine_distance(a, b));
        }
    }
    let others_median = median(&mut others);
    let mut by_shift = vec![Vec::new(); 3];
    let mut hits = [0usize; 3];
    for (k, (walls, spot)) in places.iter().enumerate() {
        for (s, shift_m) in [0.5, 1.0, 2.0].into_iter().enumerate() {
            for _ in 0..3 {
                let direction = rng.random_range(0.0..TAU);
                let moved = spot + Point2::new(direction.cos(), direction.sin()) * shift_m;
                let heading = rng.random_range(-PI..PI);
                let query = descriptor.describe(&scan(walls, moved.x, moved.y, heading));
                by_shift[s].push(cosine_distance(&query, &reference[k]));
                // Retrieval: the true place must be the nearest of all places.
                let best = reference
                    .iter()
                    .map(|r| cosine_distance(&query, r))
                    .enumerate()
                    .min_by(|a, b| a.1.total_cmp(&b.1))
                    .unwrap()
                    .0;
                hits[s] += usize::from(best == k);
            }
        }
    }
    let medians: Vec<f32> = by_shift.iter_mut().map(|v| median(v)).collect();
    let trials = places.len() * 3;
    eprintln!(
        "translation: median distance after 0.5/1/2 m {medians:?}, other places {others_median}, \
         right place first {hits:?} of {trials}"
    );
    assert!(
        medians[0] < 0.25 * others_median,
        "{medians:?} vs {others_median}"
    );
    assert!(
        medians[1] < 0.5 * others_median,
        "{medians:?} vs {others_median}"
    );
    assert!(medians[2] < others_median, "{medians:?} vs {others_median}");
    assert!(hits[0] * 10 >= trials * 9, "0.5 m: {hits:?} of {trials}");
    assert!(hits[1] * 10 >= trials * 6, "1 m: {hits:?} of {trials}");
}

#[test]
fn different_places_are_far_apart() {
    let descriptor = RingSpectrumDescriptor::default();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut rows = Vec::new();
    let mut worst_turn = 0.0f32;
    for seed in 200..212 {
        let walls = world(seed);
        let spot = free_spot(&walls, &mut rng);
        let row = descriptor.describe(&scan(&walls, spot.x, spot.y, rng.random_range(-PI..PI)));
        let turned = descriptor.describe(&scan(&walls, spot.x, spot.y, rng.random_range(-PI..PI)));
        worst_turn = worst_turn.max(cosine_distance(&row, &turned));
        rows.push(row);
    }
    let mut distances = Vec::new();
    for (i, a) in rows.iter().enumerate() {
        for b in &rows[i + 1..] {
            distances.push(cosine_distance(a, b));
        }
    }
    let nearest = distances.iter().copied().fold(f32::INFINITY, f32::min);
    let typical = median(&mut distances);
    eprintln!(
        "different places: nearest pair {nearest}, median {typical}; same place turned {worst_turn}"
    );
    // The distance scale: different places ≈ 0.07 (median), the closest pair ≈ 0.025, a
    // turn on the spot ≈ 1e-4.
    assert!(nearest > 0.01, "{nearest}");
    assert!(typical > 0.04, "{typical}");
    assert!(nearest > 20.0 * worst_turn, "{nearest} vs {worst_turn}");
}

#[test]
fn empty_input_gives_a_zero_descriptor_and_no_yaw() {
    let descriptor = RingSpectrumDescriptor::default();
    let empty = descriptor.describe(&[]);
    assert_eq!(empty.len(), descriptor.dim());
    assert!(empty.iter().all(|&v| v == 0.0));
    assert_eq!(cosine_distance(&empty, &empty), 1.0);
    assert!(descriptor
        .relative_yaw(&[], &[Point2::new(1.0, 0.0)])
        .is_none());
    let far_only = descriptor.describe(&[Point2::new(100.0, 0.0), Point2::new(f64::NAN, 1.0)]);
    assert!(far_only.iter().all(|&v| v == 0.0));
    let descriptor3 = RingSpectrumDescriptor3::default();
    assert!(descriptor3.describe(&[]).iter().all(|&v| v == 0.0));
    // Rows of submaps without points, in parallel.
    let submaps: Vec<SegmentSubmap<Point2, ()>> = (0..3)
        .map(|index| SegmentSubmap {
            index,
            centre_scan: index,
            scan_range: (index, index),
            segment_from_centre: (),
            travel_m: 0.0,
            points_in_centre: Vec::new(),
            free_space: None,
        })
        .collect();
    let rows = describe_submaps(&descriptor, &submaps);
    assert_eq!((rows.len(), rows.dim), (3, 256));
}

/// Points on the walls and roofs of random boxes (buildings) and on the ground, in a frame at
/// `(x, y, heading)` 1.73 m above the ground.
fn city(seed: u64, x_m: f64, y_m: f64, heading_rad: f64) -> Vec<Point3> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut world = Vec::new();
    for _ in 0..25 {
        let c = (rng.random_range(-45.0..45.0), rng.random_range(-45.0..45.0));
        let (w, d, h): (f64, f64, f64) = (
            rng.random_range(3.0..15.0),
            rng.random_range(3.0..15.0),
            rng.random_range(2.0..20.0),
        );
        let steps = |length: f64| (length / 0.5).ceil() as usize;
        for i in 0..=steps(w) {
            for k in 0..=steps(h) {
                let (u, z) = (i as f64 / steps(w) as f64 - 0.5, k as f64 * 0.5);
                world.push(Point3::new(c.0 + u * w, c.1 - d / 2.0, z.min(h)));
                world.push(Point3::new(c.0 + u * w, c.1 + d / 2.0, z.min(h)));
            }
        }
        for j in 0..=steps(d) {
            for k in 0..=steps(h) {
                let (v, z) = (j as f64 / steps(d) as f64 - 0.5, k as f64 * 0.5);
                world.push(Point3::new(c.0 - w / 2.0, c.1 + v * d, z.min(h)));
                world.push(Point3::new(c.0 + w / 2.0, c.1 + v * d, z.min(h)));
            }
        }
    }
    for i in -50..50 {
        for j in -50..50 {
            world.push(Point3::new(i as f64, j as f64, 0.0));
        }
    }
    let (s, c) = heading_rad.sin_cos();
    world
        .iter()
        .map(|p| {
            let (dx, dy) = (p.x - x_m, p.y - y_m);
            Point3::new(c * dx + s * dy, -s * dx + c * dy, p.z - 1.73)
        })
        .collect()
}

#[test]
fn three_d_descriptor_is_invariant_to_rotation_about_z() {
    let descriptor = RingSpectrumDescriptor3::default();
    assert_eq!(descriptor.dim(), 256);
    let candidate = city(5, 1.0, 2.0, 0.0);
    let d_candidate = descriptor.describe(&candidate);
    let norm: f32 = d_candidate.iter().map(|v| v * v).sum();
    assert!((norm - 1.0).abs() < 1e-4);
    for yaw_rad in [0.4, -2.0, 3.0] {
        let query = city(5, 1.0, 2.0, yaw_rad);
        let distance = cosine_distance(&descriptor.describe(&query), &d_candidate);
        assert!(distance < 0.02, "yaw {yaw_rad}: {distance}");
        let estimate = descriptor.relative_yaw(&query, &candidate).unwrap();
        let error_deg = wrap_angle_rad(estimate.yaw_rad - yaw_rad)
            .abs()
            .to_degrees();
        assert!(error_deg < 3.0, "yaw {yaw_rad}: error {error_deg}°");
    }
    // Another city is farther than a 2 m move in this one.
    let moved = cosine_distance(&descriptor.describe(&city(5, 3.0, 2.0, 1.0)), &d_candidate);
    let other = cosine_distance(&descriptor.describe(&city(6, 1.0, 2.0, 0.0)), &d_candidate);
    eprintln!("3D: moved 2 m {moved}, other city {other}");
    assert!(moved < 0.5 * other, "{moved} vs {other}");
}

/// Retrieval among 90 synthetic places after a move (prints a table; run with `--ignored
/// --nocapture`).
#[test]
#[ignore]
fn translation_retrieval_table() {
    let descriptor = RingSpectrumDescriptor::default();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut places = Vec::new();
    for seed in 100..130 {
        let walls = world(seed);
        for _ in 0..3 {
            let spot = free_spot(&walls, &mut rng);
            places.push((walls.clone(), spot));
        }
    }
    let reference: Vec<Vec<f32>> = places
        .iter()
        .map(|(walls, spot)| descriptor.describe(&scan(walls, spot.x, spot.y, 0.0)))
        .collect();
    let mut others = Vec::new();
    for (i, a) in reference.iter().enumerate() {
        for b in &reference[i + 1..] {
            others.push(cosine_distance(a, b));
        }
    }
    others.sort_by(|a, b| a.total_cmp(b));
    let mut by_shift = vec![Vec::new(); 3];
    let mut hits = [0; 3];
    for (k, (walls, spot)) in places.iter().enumerate() {
        for (s, shift_m) in [0.5, 1.0, 2.0].into_iter().enumerate() {
            let direction = rng.random_range(0.0..TAU);
            let moved = spot + Point2::new(direction.cos(), direction.sin()) * shift_m;
            let heading = rng.random_range(-PI..PI);
            let query = descriptor.describe(&scan(walls, moved.x, moved.y, heading));
            by_shift[s].push(cosine_distance(&query, &reference[k]));
            let best = reference
                .iter()
                .map(|r| cosine_distance(&query, r))
                .enumerate()
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap()
                .0;
            hits[s] += usize::from(best == k);
        }
    }
    for v in &mut by_shift {
        v.sort_by(|a, b| a.total_cmp(b));
    }
    let q = |v: &Vec<f32>, f: f64| v[((v.len() - 1) as f64 * f) as usize];
    eprintln!(
        "other places: 1st percentile {:.3}, median {:.3}",
        q(&others, 0.01),
        q(&others, 0.5)
    );
    for (s, shift_m) in [0.5, 1.0, 2.0].into_iter().enumerate() {
        eprintln!(
            "moved {shift_m} m: median {:.3}, 90th percentile {:.3}, right place first {}/{}",
            q(&by_shift[s], 0.5),
            q(&by_shift[s], 0.9),
            hits[s],
            places.len()
        );
    }
}
