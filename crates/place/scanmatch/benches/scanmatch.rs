//! Scan-to-local-map matching on simulated office scans at 5 cm: a 360-beam query against
//! the points of 50 scans, (a) in a small window (±0.3 m, ±10°, scan-to-map odometry) and
//! (b) in a large one (±5 m, ±π, loop closing), correlative search alone and with ICP.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use criterion::{criterion_group, criterion_main, Criterion};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::{transform_points, voxel_downsample, BeamFilter, Point2};
use mapmerge_scanmatch::{ScanMatchParams, ScanMatcher, SearchWindow};
use mapmerge_sim::{generate_world, Lidar, LidarParams, WorldPreset};

struct Problem {
    map_in_world: Vec<Point2>,
    query_in_robot: Vec<Point2>,
    truth: Se2,
}

fn problem() -> Problem {
    let world = generate_world(&WorldPreset::Office.params(), 3).unwrap();
    let lidar = Lidar::new(&world, LidarParams::default()).unwrap();
    // A room whose centre is free, then 50 poses on a small loop around it.
    let centre = world
        .rooms
        .iter()
        .map(|room| room.rect.center_m())
        .map(|c| Se2::new(c.x, c.y, 0.0))
        .find(|pose| {
            let points = lidar.scan(pose, 0).points_in_robot(&BeamFilter::default());
            points.len() > 300 && points.iter().all(|p| p.norm() > 0.6)
        })
        .unwrap();
    let mut map_in_world = Vec::new();
    for k in 0..50 {
        let angle = k as f64 / 50.0 * std::f64::consts::TAU;
        let pose = centre.compose(&Se2::new(0.3 * angle.cos(), 0.3 * angle.sin(), angle));
        let points = lidar.scan(&pose, k).points_in_robot(&BeamFilter::default());
        map_in_world.extend(transform_points(&pose, &points));
    }
    let truth = centre.compose(&Se2::new(0.1, -0.05, 0.4));
    let query_in_robot = lidar
        .scan(&truth, 99)
        .points_in_robot(&BeamFilter::default());
    Problem {
        map_in_world,
        query_in_robot,
        truth,
    }
}

fn bench(c: &mut Criterion) {
    let problem = problem();
    let matcher = ScanMatcher::default();
    let target = matcher.target(&problem.map_in_world).unwrap();
    let correlative_only = ScanMatcher::new(ScanMatchParams {
        icp: None,
        ..ScanMatchParams::default()
    })
    .unwrap();
    let small = SearchWindow::new(0.3, 10f64.to_radians());
    let small_guess = problem.truth.compose(&Se2::new(0.12, -0.1, 0.07));
    let large = SearchWindow::global(5.0);
    let large_guess = problem.truth.compose(&Se2::new(1.7, 2.3, 2.0));
    for (name, window, guess) in [("small", small, small_guess), ("large", large, large_guess)] {
        let found = matcher
            .match_scan(&target, &problem.query_in_robot, &guess, &window)
            .unwrap();
        let error = problem.truth.between(&found.target_from_query);
        eprintln!(
            "{name}: {} candidates, error {:.3} m {:.4} rad, score {:.3}",
            found.candidates,
            error.translation().norm(),
            error.theta_rad,
            found.score
        );
        c.bench_function(
            &format!("scanmatch_office_50scans_{name}_window_correlative"),
            |b| {
                b.iter(|| {
                    correlative_only.match_scan(&target, &problem.query_in_robot, &guess, &window)
                })
            },
        );
        c.bench_function(
            &format!("scanmatch_office_50scans_{name}_window_with_icp"),
            |b| b.iter(|| matcher.match_scan(&target, &problem.query_in_robot, &guess, &window)),
        );
    }
    let voxel = voxel_downsample(&problem.map_in_world, 0.05);
    eprintln!(
        "map: {} points ({} voxels)",
        problem.map_in_world.len(),
        voxel.len()
    );
    c.bench_function("scanmatch_office_50scans_build_target", |b| {
        b.iter(|| matcher.target(&problem.map_in_world))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
