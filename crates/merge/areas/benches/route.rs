//! One route query on a hybrid map of 1,000 areas (target: ≤ 1 ms): areas on a 40 × 25 grid of
//! 10 m rooms, a door between each room and its right and upper neighbours (1,935 link points,
//! each room's link points fully connected), a query between opposite corners; and door
//! detection per scan on a simulated session.
//!
//! `cargo bench -p mapmerge-areas --bench route`

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use mapmerge_areas::{Area, DoorDetector, DoorParams, Environment, HybridMap, LinkPoint};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::Point2;
use mapmerge_sim::{simulate, SimParams};

fn grid_of_rooms(columns: usize, rows: usize) -> HybridMap {
    let room = |c: usize, r: usize| r * columns + c;
    // Each room's frame: its corner, turned by a room-specific angle.
    let world_from_room = |id: usize| {
        let (c, r) = (id % columns, id / columns);
        Se2::new(10.0 * c as f64, 10.0 * r as f64, 0.01 * id as f64)
    };
    let mut map = HybridMap {
        areas: (0..columns * rows)
            .map(|id| Area {
                id,
                environment: Environment::Indoor,
                first_from_area: world_from_room(id),
            })
            .collect(),
        ..HybridMap::default()
    };
    let mut add = |a: usize, b: usize, world: Se2| {
        let id = map.link_points.len();
        map.link_points.push(LinkPoint {
            id,
            areas: [a, b],
            poses: [
                world_from_room(a).inverse().compose(&world),
                world_from_room(b).inverse().compose(&world),
            ],
        });
    };
    for r in 0..rows {
        for c in 0..columns {
            let (x, y) = (10.0 * c as f64, 10.0 * r as f64);
            if c + 1 < columns {
                add(room(c, r), room(c + 1, r), Se2::new(x + 10.0, y + 5.0, 0.0));
            }
            if r + 1 < rows {
                add(room(c, r), room(c, r + 1), Se2::new(x + 5.0, y + 10.0, 0.0));
            }
        }
    }
    map.connect();
    map
}

fn route(c: &mut Criterion) {
    let map = grid_of_rooms(40, 25);
    let (start, goal) = (0, map.areas.len() - 1);
    c.bench_function("route_1000_areas", |b| {
        b.iter(|| {
            map.route(
                black_box(start),
                Point2::new(2.0, 3.0),
                black_box(goal),
                Point2::new(4.0, 4.0),
            )
        })
    });
}

fn door_detection(c: &mut Criterion) {
    let params = match SimParams::default().with_preset_name("office") {
        Ok(p) => p.with_sessions(1).with_duration_secs(120.0),
        Err(e) => panic!("{e}"),
    };
    let data = match simulate(&params, 101) {
        Ok(d) => d,
        Err(e) => panic!("{e}"),
    };
    let scans: Vec<_> = data.sessions[0]
        .log
        .scans
        .iter()
        .filter_map(|r| Some((r.odom_from_robot?, r.scan.clone())))
        .collect();
    c.bench_function("door_detection_session_1201_scans", |b| {
        b.iter(|| {
            let mut detector = match DoorDetector::new(DoorParams::default()) {
                Ok(d) => d,
                Err(e) => panic!("{e}"),
            };
            let mut found = 0;
            for (pose, scan) in &scans {
                found += usize::from(detector.push(pose, scan).is_some());
            }
            found
        })
    });
}

criterion_group!(benches, route, door_detection);
criterion_main!(benches);
