//! The matcher on exact simulated scans of a generated office: scan-to-scan and scan-to-map
//! with a perturbed guess, and global search in a local map.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::{transform_points, BeamFilter, Point2};
use mapmerge_scanmatch::{ScanMatcher, SearchWindow};
use mapmerge_sim::{generate_world, Lidar, LidarParams, World, WorldPreset};

fn office() -> World {
    generate_world(&WorldPreset::Office.params(), 3).unwrap()
}

/// Room centres from which the lidar sees walls all around (not inside furniture).
fn free_poses(world: &World, lidar: &Lidar) -> Vec<Se2> {
    world
        .rooms
        .iter()
        .map(|room| {
            let c = room.rect.center_m();
            Se2::new(c.x, c.y, 0.3)
        })
        .filter(|pose| {
            let scan = lidar.scan(pose, 1);
            let points = scan.points_in_robot(&BeamFilter::default());
            points.len() > 300 && points.iter().all(|p| p.norm() > 0.4)
        })
        .collect()
}

#[test]
fn scan_to_scan_in_simulated_office_recovers_relative_pose() {
    let world = office();
    let lidar = Lidar::new(&world, LidarParams::default()).unwrap();
    let matcher = ScanMatcher::default();
    let poses = free_poses(&world, &lidar);
    assert!(poses.len() >= 3, "only {} free poses", poses.len());
    for (k, world_from_a) in poses.iter().enumerate() {
        let world_from_b = world_from_a.compose(&Se2::new(0.25, 0.1, 0.08));
        let points_a = lidar
            .scan(world_from_a, 10 + k as u64)
            .points_in_robot(&BeamFilter::default());
        let points_b = lidar
            .scan(&world_from_b, 20 + k as u64)
            .points_in_robot(&BeamFilter::default());
        let truth = world_from_a.between(&world_from_b);
        let guess = truth.compose(&Se2::new(-0.12, 0.09, -0.06));
        let target = matcher.target(&points_a).unwrap();
        let found = matcher
            .match_scan(&target, &points_b, &guess, &SearchWindow::default())
            .unwrap();
        let error = truth.between(&found.target_from_query);
        assert!(
            error.translation().norm() < 0.03 && error.theta_rad.abs() < 0.5f64.to_radians(),
            "room {k}: error {error:?}, match {found:?}"
        );
    }
}

#[test]
fn global_search_in_simulated_local_map_finds_the_pose() {
    let world = office();
    let lidar = Lidar::new(&world, LidarParams::default()).unwrap();
    let matcher = ScanMatcher::default();
    let poses = free_poses(&world, &lidar);
    let Some(centre) = poses.first() else {
        panic!("no free pose");
    };
    // A local map in the world frame from three scans around the centre.
    let mut map: Vec<Point2> = Vec::new();
    for (k, offset) in [
        Se2::new(0.0, 0.0, 0.0),
        Se2::new(0.3, 0.0, 0.5),
        Se2::new(-0.2, 0.2, -0.7),
    ]
    .iter()
    .enumerate()
    {
        let world_from_robot = centre.compose(offset);
        let points = lidar
            .scan(&world_from_robot, k as u64)
            .points_in_robot(&BeamFilter::default());
        map.extend(transform_points(&world_from_robot, &points));
    }
    let target = matcher.target(&map).unwrap();
    let truth = centre.compose(&Se2::new(0.15, -0.1, 2.0));
    let query = lidar
        .scan(&truth, 99)
        .points_in_robot(&BeamFilter::default());
    let guess = Se2::new(centre.x_m, centre.y_m, 0.0);
    let found = matcher
        .match_scan(&target, &query, &guess, &SearchWindow::global(3.0))
        .unwrap();
    let error = truth.between(&found.target_from_query);
    assert!(
        error.translation().norm() < 0.03 && error.theta_rad.abs() < 0.5f64.to_radians(),
        "error {error:?}, match {found:?}"
    );
}
