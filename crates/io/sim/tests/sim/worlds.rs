//! Generated worlds look like office floors and warehouses: sizes, doors, rooms, look-alikes,
//! reachability, and the ground-truth grid.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{CellClass, ClassThresholds};
use mapmerge_sim::{
    generate_world, DoorKind, LayoutParams, ObstacleKind, OfficeParams, Roadmap, RoomKind,
    SimError, SimParams, World, WorldParams, WorldPreset,
};
use proptest::prelude::*;

fn size(world: &World) -> (f64, f64) {
    let b = world.footprint[0];
    (b.width_m(), b.height_m())
}

/// Checks shared by every office world.
fn check_office(world: &World) {
    for room in &world.rooms {
        let (w, h) = (room.rect.width_m(), room.rect.height_m());
        match room.kind {
            RoomKind::Office => {
                assert!(
                    (3.0 - 1e-9..=8.0 + 1e-9).contains(&w),
                    "{} is {w} m wide",
                    room.name
                );
                assert!((3.0..=8.0).contains(&h), "{} is {h} m deep", room.name);
            }
            RoomKind::Storage => assert!(
                (1.6 - 1e-9..3.0).contains(&w),
                "{} is {w} m wide",
                room.name
            ),
            RoomKind::Corridor => {
                assert!((w.min(h) - 2.0).abs() < 1e-9, "{} is {w} × {h}", room.name)
            }
            kind => panic!("unexpected {kind:?} in an office"),
        }
        let doors = world.doors_of(room.id).count();
        assert!(
            doors >= 1 || room.kind == RoomKind::Corridor,
            "{} has no door",
            room.name
        );
    }
    for door in &world.doors {
        assert!(
            (0.9..=1.0).contains(&door.width_m),
            "door {} is {} m",
            door.id.0,
            door.width_m
        );
        // The gap is open: no obstacle covers the door's span.
        let span = door.span();
        for t in [0.02, 0.5, 0.98] {
            let p = span.start_m + (span.end_m - span.start_m) * t;
            assert!(!world.is_inside_obstacle(&p), "door {} blocked", door.id.0);
        }
        // And it is a gap in a wall: just beyond its jambs there is wall.
        let beyond = door.center_m + door.wall_direction() * (0.5 * door.width_m + 0.05);
        assert!(
            world.is_inside_obstacle(&beyond),
            "door {} is not in a wall",
            door.id.0
        );
    }
    // Walls have thickness: no thin segments in a generated world.
    assert!(world
        .obstacles
        .iter()
        .all(|o| !matches!(o.shape, mapmerge_sim::Shape::Segment(_))));
}

/// Every destination room has free space reachable from the largest free area.
fn check_reachable(world: &World) {
    let roadmap = Roadmap::build(world, 0.3);
    for room in world.rooms.iter().filter(|r| r.kind.is_destination()) {
        assert!(
            !roadmap.main_nodes_in(&room.rect).is_empty(),
            "{} cannot be reached",
            room.name
        );
    }
}

#[test]
fn presets_are_listed_and_unknown_names_are_refused() {
    assert_eq!(
        WorldPreset::names(),
        vec![
            "office",
            "office-aliased",
            "corridor-loop",
            "warehouse",
            "symmetric-hall"
        ]
    );
    let err = WorldPreset::from_name("offce").unwrap_err();
    assert!(matches!(err, SimError::UnknownPreset { .. }));
    let message = err.to_string();
    for name in WorldPreset::names() {
        assert!(message.contains(name), "{message}");
    }
    assert_eq!(
        "corridor-loop".parse::<WorldPreset>().unwrap(),
        WorldPreset::CorridorLoop
    );
}

#[test]
fn office_is_a_varied_30_by_20_floor() {
    for seed in 0..5 {
        let world = generate_world(&WorldPreset::Office.params(), seed).unwrap();
        assert_eq!(world.name, "office");
        assert_eq!(size(&world), (30.0, 20.0));
        check_office(&world);
        check_reachable(&world);
        let offices: Vec<f64> = world
            .rooms
            .iter()
            .filter(|r| r.kind == RoomKind::Office)
            .map(|r| r.rect.width_m())
            .collect();
        assert!(offices.len() >= 10, "{} offices", offices.len());
        let spread = offices.iter().cloned().fold(0.0, f64::max)
            - offices.iter().cloned().fold(f64::MAX, f64::min);
        assert!(spread > 1.0, "rooms all alike: {offices:?}");
        assert!(world.rooms.iter().all(|r| r.alias_group.is_none()));
        let furniture = world
            .obstacles
            .iter()
            .filter(|o| o.kind == ObstacleKind::Furniture)
            .count();
        assert!(
            furniture >= offices.len(),
            "{furniture} pieces of furniture"
        );
        assert_eq!(
            world
                .rooms
                .iter()
                .filter(|r| r.name.starts_with("corridor"))
                .count(),
            2
        );
        assert_eq!(
            world
                .rooms
                .iter()
                .filter(|r| r.name.starts_with("connector"))
                .count(),
            2
        );
    }
}

#[test]
fn office_aliased_repeats_rooms_and_a_corridor_section() {
    let world = generate_world(&WorldPreset::OfficeAliased.params(), 2).unwrap();
    assert_eq!(size(&world), (40.0, 20.0));
    check_office(&world);
    check_reachable(&world);
    let mut groups: BTreeMap<u32, Vec<&mapmerge_sim::Room>> = BTreeMap::new();
    for room in &world.rooms {
        if let Some(group) = room.alias_group {
            groups.entry(group).or_default().push(room);
        }
    }
    assert!(
        groups.values().any(|rooms| rooms.len() >= 3),
        "no room repeated three times"
    );
    // The repeated section: at least three templates (rooms on both sides of the corridor)
    // each used twice.
    assert!(groups.values().filter(|rooms| rooms.len() == 2).count() >= 3);
    // Copies look the same: the same furniture, seen from each room's own frame.
    for rooms in groups.values() {
        let furniture_of = |room: &mapmerge_sim::Room| {
            let mut shapes: Vec<String> = world
                .obstacles
                .iter()
                .filter(|o| o.room == Some(room.id))
                .map(|o| {
                    let local = o.shape.transformed(&room.world_from_room.inverse());
                    let b = local.bounds();
                    // Rounded to the micrometre (and -0 made 0) so that turned copies compare equal.
                    let r = |v: f64| (v * 1e6).round() / 1e6 + 0.0;
                    format!(
                        "{} {} {} {}",
                        r(b.min_m.x),
                        r(b.min_m.y),
                        r(b.max_m.x),
                        r(b.max_m.y)
                    )
                })
                .collect();
            shapes.sort();
            shapes
        };
        let first = furniture_of(rooms[0]);
        for room in &rooms[1..] {
            assert_eq!(
                furniture_of(room),
                first,
                "{} vs {}",
                rooms[0].name,
                room.name
            );
            assert!((room.rect.width_m() - rooms[0].rect.width_m()).abs() < 1e-9);
            assert!((room.rect.height_m() - rooms[0].rect.height_m()).abs() < 1e-9);
        }
    }
}

#[test]
fn look_alike_rooms_give_look_alike_scans() {
    let world = generate_world(&WorldPreset::OfficeAliased.params(), 6).unwrap();
    let lidar = mapmerge_sim::Lidar::new(
        &world,
        mapmerge_sim::LidarParams {
            range_sigma_m: 0.0,
            ..Default::default()
        },
    )
    .unwrap();
    let roadmap = Roadmap::build(&world, 0.3);
    let room = world
        .rooms
        .iter()
        .find(|r| world.look_alikes(r.id).len() >= 2)
        .unwrap();
    let node = roadmap.main_nodes_in(&room.rect)[0];
    let p = roadmap.nodes()[node];
    let pose = Se2::new(p.x, p.y, 0.4);
    let in_room = room.world_from_room.inverse().compose(&pose);
    let reference = lidar.scan(&pose, 0);
    for copy in world.look_alikes(room.id) {
        let scan = lidar.scan(&copy.world_from_room.compose(&in_room), 0);
        let same = reference
            .ranges_m
            .iter()
            .zip(&scan.ranges_m)
            .filter(|(a, b)| (**a - **b).abs() < 0.01)
            .count();
        // Only beams leaving through the door may see something different.
        assert!(
            same >= 300,
            "{} of 360 beams agree between {} and {}",
            same,
            room.name,
            copy.name
        );
    }
}

#[test]
fn corridor_loop_is_a_ring() {
    let mut world = generate_world(&WorldPreset::CorridorLoop.params(), 1).unwrap();
    check_office(&world);
    check_reachable(&world);
    let connectors: Vec<_> = world
        .rooms
        .iter()
        .filter(|r| r.name.starts_with("connector"))
        .cloned()
        .collect();
    assert_eq!(connectors.len(), 2);
    let (w, _) = size(&world);
    assert!(connectors[0].rect.min_m.x < 0.5 && connectors[1].rect.max_m.x > w - 0.5);
    // With every door closed, the corridors still connect through both connectors: block one
    // and the other still leads round; block both and the corridors are apart.
    let doors: Vec<_> = world.doors.iter().map(|d| d.id).collect();
    for door in doors {
        world.close_door(door).unwrap();
    }
    let c1 = world.room_by_name("corridor-1").unwrap().rect.center_m();
    let c2 = world.room_by_name("corridor-2").unwrap().rect.center_m();
    let route_length = |world: &World| {
        Roadmap::build(world, 0.3)
            .plan(&c1, &c2)
            .map(|route| route.windows(2).map(|l| (l[1] - l[0]).norm()).sum::<f64>())
    };
    let around = route_length(&world).unwrap();
    assert!(around > 0.9 * w, "{around} m");
    for (k, connector) in connectors.iter().enumerate() {
        let block = mapmerge_sim::Rect::from_center(
            connector.rect.center_m(),
            mapmerge_sim::Point2::new(connector.rect.width_m() + 0.2, 0.5),
        );
        world.add_obstacle(ObstacleKind::Wall, mapmerge_sim::Shape::Rect(block), None);
        let length = route_length(&world);
        if k == 0 {
            assert!(length.unwrap() > 0.9 * w);
        } else {
            assert!(length.is_none());
        }
    }
}

#[test]
fn warehouse_is_a_repetitive_hall() {
    let world = generate_world(&WorldPreset::Warehouse.params(), 1).unwrap();
    assert_eq!(size(&world), (40.0, 30.0));
    check_reachable(&world);
    let aisles: Vec<_> = world
        .rooms
        .iter()
        .filter(|r| r.kind == RoomKind::Aisle)
        .collect();
    assert!(aisles.len() >= 8, "{} aisles", aisles.len());
    assert!(aisles.iter().all(|a| a.alias_group == Some(0)));
    assert!(aisles.iter().all(|a| (a.rect.width_m() - 3.0).abs() < 1e-9));
    let shelves = world
        .obstacles
        .iter()
        .filter(|o| o.kind == ObstacleKind::Shelf)
        .count();
    assert!(shelves >= 40, "{shelves} shelf parts");
    assert_eq!(
        world
            .doors
            .iter()
            .filter(|d| d.kind == DoorKind::Entrance)
            .count(),
        2
    );
}

#[test]
fn ground_truth_grid_is_occupied_free_and_unknown_where_it_should_be() {
    let world = generate_world(&WorldPreset::Office.params(), 3).unwrap();
    let grid = world.to_grid(0.05).unwrap();
    let g = grid.geometry();
    assert!(g.width >= 600 && g.height >= 400);
    let t = ClassThresholds::default();
    let class = |p: &mapmerge_sim::Point2| t.classify(grid.log_odds_at(p));
    // Outside the building: unknown; walls occupied; the roadmap's free points free.
    assert_eq!(
        class(&mapmerge_sim::Point2::new(-0.5, -0.5)),
        CellClass::Unknown
    );
    assert_eq!(
        class(&mapmerge_sim::Point2::new(0.1, 10.0)),
        CellClass::Occupied
    );
    let roadmap = Roadmap::build(&world, 0.3);
    assert!(roadmap.nodes().iter().all(|p| class(p) == CellClass::Free));
    for door in &world.doors {
        assert_eq!(class(&door.center_m), CellClass::Free);
    }
    let classes = grid.classes(&t);
    let occupied = classes
        .iter()
        .filter(|c| **c == CellClass::Occupied)
        .count() as f64;
    let free = classes.iter().filter(|c| **c == CellClass::Free).count() as f64;
    assert!(occupied / (occupied + free) > 0.05 && occupied / (occupied + free) < 0.3);
}

#[test]
fn params_parse_with_defaults_and_refuse_unknown_fields() {
    let parsed: SimParams = serde_json::from_str("{}").unwrap();
    assert_eq!(parsed, SimParams::default());
    let parsed: SimParams = serde_json::from_str(
        r#"{"preset": "office-aliased", "sessions": 5, "lidar": {"beam_count": 720}}"#,
    )
    .unwrap();
    assert_eq!(parsed.preset, WorldPreset::OfficeAliased);
    assert_eq!((parsed.sessions, parsed.lidar.beam_count), (5, 720));
    assert!(serde_json::from_str::<SimParams>(r#"{"sesions": 5}"#).is_err());
    let round_trip: SimParams =
        serde_json::from_str(&serde_json::to_string(&parsed).unwrap()).unwrap();
    assert_eq!(round_trip, parsed);
    let world = WorldParams {
        layout: LayoutParams::Office(OfficeParams {
            width_m: 25.0,
            ..OfficeParams::default()
        }),
        ..WorldParams::default()
    };
    let text = serde_json::to_string(&world).unwrap();
    assert_eq!(serde_json::from_str::<WorldParams>(&text).unwrap(), world);
}

#[test]
fn bad_world_params_are_errors_not_panics() {
    let tiny = WorldParams {
        layout: LayoutParams::Office(OfficeParams {
            height_m: 8.0,
            ..OfficeParams::default()
        }),
        ..WorldParams::default()
    };
    assert!(matches!(
        generate_world(&tiny, 0),
        Err(SimError::InvalidParams { .. })
    ));
    let crowded = WorldParams {
        layout: LayoutParams::Office(OfficeParams {
            width_m: 20.0,
            aliased_room_copies: 6,
            ..OfficeParams::default()
        }),
        ..WorldParams::default()
    };
    assert!(matches!(
        generate_world(&crowded, 0),
        Err(SimError::InvalidParams { .. })
    ));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// Any seed and a range of sizes give a valid, fully reachable office floor.
    #[test]
    fn random_offices_are_valid(
        seed in any::<u64>(),
        width_m in 22.0f64..45.0,
        height_m in 16.0f64..24.0,
        one_corridor in any::<bool>(),
        connector in 0.0f64..1.0,
    ) {
        let params = WorldParams {
            name: "random".to_owned(),
            layout: LayoutParams::Office(OfficeParams {
                width_m,
                height_m: if one_corridor { height_m.min(17.0) } else { height_m },
                corridor_count: if one_corridor { 1 } else { 2 },
                connector_positions: vec![0.0, connector],
                ..OfficeParams::default()
            }),
        };
        let world = generate_world(&params, seed).unwrap();
        check_office(&world);
        check_reachable(&world);
    }
}
