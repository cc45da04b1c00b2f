//! The lidar against hand-made worlds with known answers, and the ray caster against brute
//! force.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use std::f64::consts::{FRAC_PI_4, PI};

use mapmerge_geometry::Se2;
use mapmerge_sim::{
    Lidar, LidarParams, LineSegment, ObstacleKind, Point2, RayCaster, Rect, Shape, World,
};
use proptest::prelude::*;

/// A 6 × 4 m room of thin walls, its lower-left corner at the origin.
fn room() -> World {
    let mut world = World::new("room");
    world.footprint.push(Rect::new(0.0, 0.0, 6.0, 4.0));
    let c = [
        Point2::new(0.0, 0.0),
        Point2::new(6.0, 0.0),
        Point2::new(6.0, 4.0),
        Point2::new(0.0, 4.0),
    ];
    for i in 0..4 {
        world.add_obstacle(
            ObstacleKind::Wall,
            Shape::Segment(LineSegment::new(c[i], c[(i + 1) % 4])),
            None,
        );
    }
    world
}

/// Distance from `(x, y)` inside the room to its wall along `angle`.
fn expected_range(x: f64, y: f64, angle: f64) -> f64 {
    let (dx, dy) = (angle.cos(), angle.sin());
    let tx = if dx > 1e-12 {
        (6.0 - x) / dx
    } else if dx < -1e-12 {
        -x / dx
    } else {
        f64::INFINITY
    };
    let ty = if dy > 1e-12 {
        (4.0 - y) / dy
    } else if dy < -1e-12 {
        -y / dy
    } else {
        f64::INFINITY
    };
    tx.min(ty)
}

fn noiseless() -> LidarParams {
    LidarParams {
        range_sigma_m: 0.0,
        range_resolution_m: 0.0,
        ..LidarParams::default()
    }
}

#[test]
fn ranges_in_a_rectangular_room_are_exact_without_noise() {
    let world = room();
    let lidar = Lidar::new(&world, noiseless()).unwrap();
    for pose in [
        Se2::new(3.0, 2.0, 0.0),
        Se2::new(1.0, 3.0, 0.7),
        Se2::new(5.5, 0.5, -2.0),
    ] {
        let scan = lidar.scan(&pose, 1);
        assert_eq!(scan.ranges_m.len(), 360);
        assert_eq!(scan.range_max_m, 30.0);
        for (i, &range) in scan.ranges_m.iter().enumerate() {
            let angle = pose.theta_rad + scan.beam_angle_rad(i);
            let expected = expected_range(pose.x_m, pose.y_m, angle);
            assert!(
                (f64::from(range) - expected).abs() < 1e-5,
                "pose {pose:?} beam {i}: {range} vs {expected}"
            );
        }
    }
    // From the centre of the room: 3 m ahead, 2 m to the left, the corner diagonal at 45°.
    let scan = lidar.scan(&Se2::new(3.0, 2.0, 0.0), 1);
    let beam = |deg: f64| {
        ((deg.to_radians() - scan.angle_min_rad) / scan.angle_increment_rad).round() as usize
    };
    assert!((scan.ranges_m[beam(0.0)] - 3.0).abs() < 1e-5);
    assert!((scan.ranges_m[beam(90.0)] - 2.0).abs() < 1e-5);
    assert!((f64::from(scan.ranges_m[beam(-180.0)]) - 3.0).abs() < 1e-5);
    let diagonal = 2.0 / FRAC_PI_4.sin();
    assert!(
        (f64::from(scan.ranges_m[beam(45.0)]) - diagonal.min(3.0 / FRAC_PI_4.cos())).abs() < 1e-5
    );
}

#[test]
fn range_noise_has_the_configured_spread() {
    let world = room();
    let sigma = 0.02;
    let lidar = Lidar::new(
        &world,
        LidarParams {
            range_sigma_m: sigma,
            ..LidarParams::default()
        },
    )
    .unwrap();
    let pose = Se2::new(2.5, 1.5, 0.3);
    let mut errors = Vec::new();
    for seed in 0..100 {
        let scan = lidar.scan(&pose, seed);
        for (i, &range) in scan.ranges_m.iter().enumerate() {
            errors.push(
                f64::from(range)
                    - expected_range(pose.x_m, pose.y_m, pose.theta_rad + scan.beam_angle_rad(i)),
            );
        }
    }
    let n = errors.len() as f64;
    let mean = errors.iter().sum::<f64>() / n;
    let std = (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n).sqrt();
    assert!(mean.abs() < 0.001, "mean {mean}");
    assert!((std - sigma).abs() < 0.001, "std {std}");
    // Same seed, same scan; another seed, other noise.
    assert_eq!(lidar.scan(&pose, 3), lidar.scan(&pose, 3));
    assert_ne!(lidar.scan(&pose, 3), lidar.scan(&pose, 4));
}

#[test]
fn nothing_in_range_reads_max_range_and_dropouts_too() {
    // One wall 5 m ahead only.
    let mut world = World::new("wall");
    world.add_obstacle(
        ObstacleKind::Wall,
        Shape::Segment(LineSegment::new(
            Point2::new(5.0, -1.0),
            Point2::new(5.0, 1.0),
        )),
        None,
    );
    let params = LidarParams {
        range_max_m: 20.0,
        ..noiseless()
    };
    let scan = Lidar::new(&world, params.clone())
        .unwrap()
        .scan(&Se2::new(0.0, 0.0, 0.0), 0);
    let ahead = scan.ranges_m.len() / 2; // beam at 0 rad
    assert!((scan.ranges_m[ahead] - 5.0).abs() < 1e-5);
    assert!(scan.is_return(scan.ranges_m[ahead]));
    assert_eq!(scan.ranges_m[0], 20.0);
    assert!(!scan.is_return(scan.ranges_m[0]));
    let returns = scan.ranges_m.iter().filter(|&&r| scan.is_return(r)).count();
    assert_eq!(returns, 23, "beams within ±11.3° hit the wall");
    // Beyond the maximum range the wall is not seen.
    let far = Lidar::new(
        &world,
        LidarParams {
            range_max_m: 4.0,
            ..params.clone()
        },
    )
    .unwrap();
    assert!(far
        .scan(&Se2::new(0.0, 0.0, 0.0), 0)
        .ranges_m
        .iter()
        .all(|&r| r == 4.0));
    // Dropouts: about the configured share of returns lost.
    let lossy = Lidar::new(
        &room(),
        LidarParams {
            dropout_probability: 0.1,
            ..noiseless()
        },
    )
    .unwrap();
    let lost: usize = (0..50)
        .map(|seed| {
            lossy
                .scan(&Se2::new(3.0, 2.0, 0.0), seed)
                .ranges_m
                .iter()
                .filter(|&&r| r == 30.0)
                .count()
        })
        .sum();
    let share = lost as f64 / (50.0 * 360.0);
    assert!((share - 0.1).abs() < 0.01, "dropout share {share}");
}

#[test]
fn sensor_offset_and_partial_field_of_view() {
    let world = room();
    let params = LidarParams {
        beam_count: 181,
        field_of_view_rad: PI,
        robot_from_sensor: Se2::new(0.5, 0.0, 0.0),
        ..noiseless()
    };
    let lidar = Lidar::new(&world, params).unwrap();
    let scan = lidar.scan(&Se2::new(3.0, 2.0, 0.0), 0);
    assert_eq!(scan.robot_from_sensor, Se2::new(0.5, 0.0, 0.0));
    assert!(
        (scan.beam_angle_rad(0) + PI / 2.0).abs() < 1e-12
            && (scan.beam_angle_rad(180) - PI / 2.0).abs() < 1e-12
    );
    // The sensor sits 0.5 m ahead of the robot: 2.5 m to the wall ahead.
    assert!((scan.ranges_m[90] - 2.5).abs() < 1e-5);
    // The points in the robot frame land on the walls.
    for p in scan.points_in_robot(&mapmerge_scan::BeamFilter::default()) {
        let (x, y) = (p.x + 3.0, p.y + 2.0);
        let on_wall =
            x.abs() < 1e-4 || (x - 6.0).abs() < 1e-4 || y.abs() < 1e-4 || (y - 4.0).abs() < 1e-4;
        assert!(on_wall, "({x}, {y})");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// The grid traversal finds exactly the brute-force first hit, whatever the cell size.
    #[test]
    fn ray_caster_matches_brute_force(
        raw in prop::collection::vec((-10.0f64..10.0, -10.0f64..10.0, -10.0f64..10.0, -10.0f64..10.0), 1..40),
        cell_m in 0.2f64..4.0,
        origin in (-12.0f64..12.0, -12.0f64..12.0),
        angles in prop::collection::vec(-PI..PI, 20),
    ) {
        let segments: Vec<LineSegment> = raw
            .iter()
            .map(|&(a, b, c, d)| LineSegment::new(Point2::new(a, b), Point2::new(c, d)))
            .collect();
        let caster = RayCaster::from_segments(&segments, cell_m);
        let origin = Point2::new(origin.0, origin.1);
        for angle in angles {
            let fast = caster.cast(&origin, angle, 15.0);
            let slow = common::brute_force_cast(&segments, &origin, angle, 15.0);
            match (fast, slow) {
                (Some(a), Some(b)) => prop_assert!((a - b).abs() < 1e-9, "{a} vs {b}"),
                (None, None) => {}
                (a, b) => prop_assert!(false, "fast {a:?}, brute force {b:?}"),
            }
        }
    }
}
