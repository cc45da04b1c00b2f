//! The `symmetric-hall` preset: a hall block that a turn by 180° about its centre maps onto
//! itself (so scans from opposite sides agree), between two office wings that differ.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeSet;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_sim::{
    generate_world, simulate, KidnapParams, KidnapTarget, LayoutParams, Point2, RayCaster, Rect,
    Roadmap, RobotParams, RoomKind, SimError, SimParams, SymmetricHallParams, World, WorldParams,
    WorldPreset,
};

fn world(seed: u64) -> World {
    generate_world(&WorldPreset::SymmetricHall.params(), seed).unwrap()
}

/// The hall's centre and the block's x range (the hall with its rows of rooms and the walls
/// around them), from the two halves of the hall.
struct Block {
    centre: Point2,
    x0: f64,
    x1: f64,
}

fn block(world: &World) -> Block {
    let west = world.room_by_name("hall-west").unwrap();
    let east = world.room_by_name("hall-east").unwrap();
    let wall = match &WorldPreset::SymmetricHall.params().layout {
        LayoutParams::SymmetricHall(p) => p.west_wing.outer_wall_m,
        _ => unreachable!(),
    };
    let (x0, x1) = (west.rect.min_m.x, east.rect.max_m.x);
    Block {
        centre: Point2::new(0.5 * (x0 + x1), 0.5 * world.footprint[0].height_m()),
        x0: x0 - wall,
        x1: x1 + wall,
    }
}

/// `pose` turned by 180° about `centre`.
fn turned(centre: &Point2, pose: &Se2) -> Se2 {
    Se2::new(
        2.0 * centre.x - pose.x_m,
        2.0 * centre.y - pose.y_m,
        pose.theta_rad + std::f64::consts::PI,
    )
}

#[test]
fn the_world_is_a_hall_between_two_wings_and_deterministic_per_seed() {
    let a = world(3);
    assert_eq!(format!("{a:?}"), format!("{:?}", world(3)));
    assert_ne!(a, world(4));
    assert_eq!(a.name, "symmetric-hall");
    let size = a.footprint[0];
    assert_eq!((size.width_m(), size.height_m()), (40.0, 20.0));
    let names: BTreeSet<&str> = a.rooms.iter().map(|r| r.name.as_str()).collect();
    assert_eq!(names.len(), a.rooms.len(), "room names repeat");
    for name in [
        "hall-west",
        "hall-east",
        "hall-room-01",
        "west-corridor-1",
        "west-corridor-2",
        "east-corridor-1",
        "east-corridor-2",
    ] {
        assert!(names.contains(name), "no {name}: {names:?}");
    }
    let hall = a.room_by_name("hall-west").unwrap();
    assert!((hall.rect.width_m() - 7.0).abs() < 1e-9);
    assert!(hall.rect.height_m() > 10.0);
    // Rooms of the rows come in look-alike pairs, each a south and a north room.
    let rows: Vec<_> = a
        .rooms
        .iter()
        .filter(|r| r.name.starts_with("hall-room"))
        .collect();
    assert!(
        rows.len() >= 4 && rows.len() % 2 == 0,
        "{} rooms",
        rows.len()
    );
    for room in &rows {
        assert!(matches!(room.kind, RoomKind::Office | RoomKind::Storage));
        assert_eq!(a.look_alikes(room.id).len(), 1, "{}", room.name);
        assert_eq!(a.doors_of(room.id).count(), 1, "{}", room.name);
    }
    // Every door is a gap in a wall, and every destination can be reached.
    for door in &a.doors {
        let span = door.span();
        for t in [0.02, 0.5, 0.98] {
            let p = span.start_m + (span.end_m - span.start_m) * t;
            assert!(!a.is_inside_obstacle(&p), "door {} blocked", door.id.0);
        }
        let beyond = door.center_m + door.wall_direction() * (0.5 * door.width_m + 0.05);
        assert!(
            a.is_inside_obstacle(&beyond),
            "door {} not in a wall",
            door.id.0
        );
    }
    let roadmap = Roadmap::build(&a, 0.3);
    for room in a.rooms.iter().filter(|r| r.kind.is_destination()) {
        assert!(
            !roadmap.main_nodes_in(&room.rect).is_empty(),
            "{} cannot be reached",
            room.name
        );
    }
    // The wings differ: the west wing is not the east wing turned about the hall's centre.
    let b = block(&a);
    let outside = |world: &World, west: bool| -> Vec<String> {
        let mut shapes: Vec<String> = world
            .obstacles
            .iter()
            .map(|o| o.shape.bounds())
            .filter(|r| {
                if west {
                    r.max_m.x < b.x0 - 1e-6
                } else {
                    r.min_m.x > b.x1 + 1e-6
                }
            })
            .map(|r| {
                let r = if west {
                    r
                } else {
                    Rect::new(
                        2.0 * b.centre.x - r.max_m.x,
                        2.0 * b.centre.y - r.max_m.y,
                        2.0 * b.centre.x - r.min_m.x,
                        2.0 * b.centre.y - r.min_m.y,
                    )
                };
                format!(
                    "{:.3} {:.3} {:.3} {:.3}",
                    r.min_m.x, r.min_m.y, r.max_m.x, r.max_m.y
                )
            })
            .collect();
        shapes.sort();
        shapes
    };
    assert_ne!(outside(&a, true), outside(&a, false));
}

#[test]
fn the_hall_block_is_point_symmetric_and_scans_agree_from_opposite_sides() {
    for seed in 0..4 {
        let world = world(seed);
        let b = block(&world);
        // The halves of the hall and the pairs of rooms: one frame is the other turned.
        for room in world.rooms.iter().filter(|r| r.name.starts_with("hall-")) {
            let copies = world.look_alikes(room.id);
            assert_eq!(copies.len(), 1, "{}", room.name);
            let relative = copies[0]
                .world_from_room
                .compose(&room.world_from_room.inverse());
            let expected = turned(&b.centre, &Se2::new(0.0, 0.0, 0.0));
            assert!(
                (relative.translation() - expected.translation()).norm() < 1e-9
                    && (relative.theta_rad.abs() - std::f64::consts::PI).abs() < 1e-9,
                "{}: {relative:?}",
                room.name
            );
        }
        // Every obstacle of the block has its turned copy (the counter is its own).
        let key = |r: &Rect| {
            let q = |v: f64| (v * 1e6).round() as i64;
            (q(r.min_m.x), q(r.min_m.y), q(r.max_m.x), q(r.max_m.y))
        };
        let inside: Vec<Rect> = world
            .obstacles
            .iter()
            .map(|o| o.shape.bounds())
            .filter(|r| r.min_m.x >= b.x0 - 1e-9 && r.max_m.x <= b.x1 + 1e-9)
            .collect();
        let keys: BTreeSet<_> = inside.iter().map(key).collect();
        for r in &inside {
            let t = Rect::new(
                2.0 * b.centre.x - r.max_m.x,
                2.0 * b.centre.y - r.max_m.y,
                2.0 * b.centre.x - r.min_m.x,
                2.0 * b.centre.y - r.min_m.y,
            );
            assert!(
                keys.contains(&key(&t)),
                "seed {seed}: {r:?} has no turned copy"
            );
        }
        // Scans from a pose and from the pose turned about the centre agree wherever the beam
        // ends inside the block (beams through the corridors' mouths see the wings).
        let caster = RayCaster::new(&world);
        let roadmap = Roadmap::build(&world, 0.3);
        let in_block: Vec<Point2> = roadmap
            .nodes()
            .iter()
            .copied()
            .filter(|p| p.x > b.x0 && p.x < b.x1)
            .collect();
        assert!(in_block.len() > 200);
        let (mut compared, mut poses) = (0, 0);
        for (k, p) in in_block.iter().enumerate().step_by(7) {
            let pose = Se2::new(p.x, p.y, 0.3 * k as f64);
            let other = turned(&b.centre, &pose);
            poses += 1;
            for beam in 0..360 {
                let angle = pose.theta_rad + (beam as f64).to_radians();
                let Some(range) = caster.cast(&pose.translation(), angle, 30.0) else {
                    continue;
                };
                let hit = pose.translation() + Point2::new(angle.cos(), angle.sin()) * range;
                if hit.x < b.x0 - 1e-6 || hit.x > b.x1 + 1e-6 {
                    continue;
                }
                let mirrored = caster
                    .cast(
                        &other.translation(),
                        other.theta_rad + (beam as f64).to_radians(),
                        30.0,
                    )
                    .unwrap_or(f64::INFINITY);
                assert!(
                    (range - mirrored).abs() < 0.01,
                    "seed {seed}, beam {beam}: {range} m from {pose:?}, {mirrored} m turned"
                );
                compared += 1;
            }
        }
        assert!(
            compared > 300 * poses,
            "{compared} beams from {poses} poses"
        );
    }
}

#[test]
fn a_session_tours_both_sides_of_the_hall_and_both_wings() {
    let params = SimParams::default()
        .with_preset(WorldPreset::SymmetricHall)
        .with_sessions(3)
        .with_duration_secs(180.0);
    let dataset = simulate(&params, 101).unwrap();
    for session in &dataset.sessions {
        let mut seen = BTreeSet::new();
        for (_, pose) in &session.truth {
            if let Some(room) = session.world.room_at(&pose.translation()) {
                let side = match room.name.as_str() {
                    "hall-west" => "hall-west",
                    "hall-east" => "hall-east",
                    name if name.starts_with("west-") => "west wing",
                    name if name.starts_with("east-") => "east wing",
                    _ => "rows",
                };
                seen.insert(side);
            }
        }
        for side in ["hall-west", "hall-east", "west wing", "east wing"] {
            assert!(
                seen.contains(side),
                "session {} never in the {side}: {seen:?}",
                session.index
            );
        }
    }
}

#[test]
fn look_alike_kidnaps_turn_the_robot_about_the_hall_centre() {
    let generated = world(1);
    let b = block(&generated);
    let starts: Vec<String> = generated
        .rooms
        .iter()
        .filter(|r| r.name.starts_with("hall-"))
        .map(|r| r.name.clone())
        .collect();
    let mut turned_round = 0;
    for seed in 0..8u64 {
        let params = SimParams {
            world_seed: Some(1),
            start_rooms: vec![starts[seed as usize % starts.len()].clone()],
            kidnap: KidnapParams {
                max_per_session: 1,
                probability: 1.0,
                min_gap_secs: 1.0,
                target: KidnapTarget::LookAlike,
                ..KidnapParams::default()
            },
            robot: RobotParams {
                dwell_max_secs: 6.0,
                ..Default::default()
            },
            ..SimParams::default()
                .with_preset(WorldPreset::SymmetricHall)
                .with_sessions(1)
                .with_duration_secs(3.0)
        };
        let dataset = simulate(&params, seed).unwrap();
        let session = &dataset.sessions[0];
        let kidnap = session.kidnaps[0];
        let from_room = session.world.room_at(&kidnap.from.translation()).unwrap();
        if from_room.alias_group.is_some() {
            let to_room = session.world.room_at(&kidnap.to.translation()).unwrap();
            assert_eq!(from_room.alias_group, to_room.alias_group);
            assert_ne!(from_room.id, to_room.id);
            let expected = turned(&b.centre, &kidnap.from);
            let error = expected.between(&kidnap.to);
            assert!(
                error.translation().norm() < 1e-9 && error.theta_rad.abs() < 1e-9,
                "{kidnap:?}"
            );
            turned_round += 1;
        }
    }
    assert!(turned_round >= 6, "{turned_round}");
}

#[test]
fn wings_that_do_not_line_up_are_refused() {
    let mut p = SymmetricHallParams::default();
    p.east_wing.height_m = 22.0;
    let params = WorldParams {
        name: "bad".to_owned(),
        layout: LayoutParams::SymmetricHall(p.clone()),
    };
    assert!(matches!(
        generate_world(&params, 0),
        Err(SimError::InvalidParams { .. })
    ));
    p.east_wing.height_m = 20.0;
    p.west_wing.corridor_count = 1;
    p.hall_width_m = 14.0;
    let params = WorldParams {
        name: "bad".to_owned(),
        layout: LayoutParams::SymmetricHall(p),
    };
    let err = generate_world(&params, 0).unwrap_err().to_string();
    assert!(err.contains("west_wing.corridor_count"), "{err}");
    // The parameters round-trip through JSON.
    let text = serde_json::to_string(&WorldPreset::SymmetricHall.params()).unwrap();
    assert_eq!(
        serde_json::from_str::<WorldParams>(&text).unwrap(),
        WorldPreset::SymmetricHall.params()
    );
}
