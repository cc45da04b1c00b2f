//! Changes between sessions: a closed door blocks rays and routes in its session only; every
//! listed change is what differs from session 0.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_sim::{
    simulate, ChangeParams, Lidar, LidarParams, ObstacleKind, RayCaster, Roadmap, SimParams,
    WorldChange,
};

fn params() -> SimParams {
    SimParams {
        changes: ChangeParams {
            doors_closed: 2,
            furniture_moved: 3,
            furniture_added: 2,
            furniture_removed: 2,
        },
        ..SimParams::default()
            .with_sessions(3)
            .with_duration_secs(30.0)
    }
}

#[test]
fn a_closed_door_blocks_rays_and_routes_in_its_session() {
    let dataset = simulate(&params(), 12).unwrap();
    let base = RayCaster::new(&dataset.world);
    let base_roadmap = Roadmap::build(&dataset.world, 0.3);
    let mut checked = 0;
    for session in &dataset.sessions[1..] {
        let caster = RayCaster::new(&session.world);
        let roadmap = Roadmap::build(&session.world, 0.3);
        for change in &session.world_changes {
            let WorldChange::DoorClosed { door, leaf } = change else {
                continue;
            };
            let door = session.world.door(*door).unwrap();
            assert_eq!(door.closed_by, Some(*leaf));
            assert_eq!(
                session.world.obstacle(*leaf).unwrap().kind,
                ObstacleKind::ClosedDoor
            );
            assert!(dataset.world.door(door.id).unwrap().closed_by.is_none());
            // A ray through the doorway from 1 m in front of it: stopped at the leaf now,
            // passing in session 0.
            let origin = door.approach_point(0, 1.0);
            let angle = door.passage_yaw_rad;
            let blocked = caster.cast(&origin, angle, 30.0).unwrap();
            assert!(
                (blocked - (1.0 - 0.5 * mapmerge_sim::DOOR_LEAF_THICKNESS_M)).abs() < 1e-6,
                "{blocked}"
            );
            let open = base.cast(&origin, angle, 30.0).unwrap_or(30.0);
            assert!(open > 1.5, "{open}");
            // The lidar sees it too, from the same spot looking through the door.
            let lidar = Lidar::new(
                &session.world,
                LidarParams {
                    range_sigma_m: 0.0,
                    ..LidarParams::default()
                },
            )
            .unwrap();
            let pose = mapmerge_geometry::Se2::new(origin.x, origin.y, angle);
            let scan = lidar.scan(&pose, 0);
            assert!((f64::from(scan.ranges_m[180]) - blocked).abs() < 1e-4);
            // No route goes through it: either none, or a detour.
            let (a, b) = (door.approach_point(0, 0.6), door.approach_point(1, 0.6));
            let open_route = base_roadmap.plan(&a, &b).unwrap();
            assert!(route_length(&open_route) < 1.5);
            if let Some(route) = roadmap.plan(&a, &b) {
                assert!(route_length(&route) > 3.0);
                for leg in route.windows(2) {
                    assert!(caster.is_path_free(&leg[0], &leg[1]));
                }
            }
            checked += 1;
        }
    }
    assert_eq!(checked, 4);
}

fn route_length(route: &[mapmerge_sim::Point2]) -> f64 {
    route.windows(2).map(|leg| (leg[1] - leg[0]).norm()).sum()
}

#[test]
fn listed_changes_are_exactly_the_differences_from_session_zero() {
    let dataset = simulate(&params(), 4).unwrap();
    let base = &dataset.world;
    assert!(dataset.sessions[0].world_changes.is_empty());
    assert_eq!(&dataset.sessions[0].world, base);
    for session in &dataset.sessions[1..] {
        let world = &session.world;
        let mut explained = Vec::new();
        for change in &session.world_changes {
            match change {
                WorldChange::DoorClosed { leaf, .. } => {
                    assert!(base.obstacle(*leaf).is_none());
                    explained.push(*leaf);
                }
                WorldChange::FurnitureMoved {
                    obstacle, from, to, ..
                } => {
                    assert_eq!(base.obstacle(*obstacle).unwrap().shape, *from);
                    assert_eq!(world.obstacle(*obstacle).unwrap().shape, *to);
                    assert_ne!(from, to);
                    explained.push(*obstacle);
                }
                WorldChange::FurnitureAdded {
                    obstacle, shape, ..
                } => {
                    assert!(base.obstacle(*obstacle).is_none());
                    assert_eq!(world.obstacle(*obstacle).unwrap().shape, *shape);
                    explained.push(*obstacle);
                }
                WorldChange::FurnitureRemoved {
                    obstacle, shape, ..
                } => {
                    assert_eq!(base.obstacle(*obstacle).unwrap().shape, *shape);
                    assert!(world.obstacle(*obstacle).is_none());
                    explained.push(*obstacle);
                }
            }
        }
        let kinds = |c: &WorldChange| match c {
            WorldChange::DoorClosed { .. } => 0,
            WorldChange::FurnitureMoved { .. } => 1,
            WorldChange::FurnitureAdded { .. } => 2,
            WorldChange::FurnitureRemoved { .. } => 3,
        };
        for kind in 0..4 {
            assert!(
                session.world_changes.iter().any(|c| kinds(c) == kind),
                "no change of kind {kind}"
            );
        }
        // Every other obstacle is unchanged.
        for obstacle in &base.obstacles {
            if !explained.contains(&obstacle.id) {
                assert_eq!(world.obstacle(obstacle.id), Some(obstacle));
            }
        }
        for obstacle in &world.obstacles {
            assert!(
                explained.contains(&obstacle.id) || base.obstacle(obstacle.id) == Some(obstacle)
            );
        }
        assert_eq!(world.rooms, base.rooms);
    }
}
