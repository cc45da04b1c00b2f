//! Issue 69, part 3: publishing a 2000 × 2000 map. The grid → message conversion, the CDR
//! encoding, and a whole `publish` on a RustDDS writer (reliable, transient-local, as `/map`)
//! with no subscriber. `cargo bench -p mapmerge-ros2 --bench publish_map`.

#![allow(clippy::expect_used)]

use criterion::{criterion_group, criterion_main, Criterion};
use mapmerge_grid::{log_odds_of, ClassThresholds, GridGeometry, OccupancyGrid, Point2};
use mapmerge_rosbag::{encode, occupancy_grid_message, Header, OccupancyGridMessage};
use ros2_client::dds::{Context, ContextOptions};
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{MessageTypeName, Name, NodeName, NodeOptions, QosProfile};

/// A 2000 × 2000 grid of building-like content: runs of unknown, free and walls.
fn building() -> OccupancyGrid {
    let geometry = GridGeometry {
        resolution_m: 0.05,
        origin_m: Point2::new(-50.0, -50.0),
        width: 2000,
        height: 2000,
    };
    let (occupied, free) = (log_odds_of(0.97), log_odds_of(0.12));
    let cells = (0..geometry.len())
        .map(|i| {
            let (x, y) = (i % 2000, i / 2000);
            if x < 200 || y < 200 {
                0.0
            } else if x % 97 == 0 || y % 131 == 0 {
                occupied
            } else if (x * 7 + y * 13) % 29 == 0 {
                0.3 // seen once
            } else {
                free
            }
        })
        .collect();
    OccupancyGrid::from_log_odds(geometry, cells).expect("a valid grid")
}

fn publish_map(c: &mut Criterion) {
    let grid = building();
    let thresholds = ClassThresholds::default();
    let mut group = c.benchmark_group("map 2000x2000");
    group.sample_size(20);
    group.bench_function("grid to message", |b| {
        b.iter(|| occupancy_grid_message(&grid, &thresholds, Header::default()))
    });
    let message = occupancy_grid_message(&grid, &thresholds, Header::default());
    group.bench_function("CDR encoding", |b| b.iter(|| encode(&message)));
    let context = Context::with_options(ContextOptions::new().domain_id(231)).expect("a context");
    let mut node = context
        .new_node(
            NodeName::new("/", "bench").expect("a name"),
            NodeOptions::new(),
        )
        .expect("a node");
    let qos = QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 1 });
    let topic = node
        .create_topic(
            &Name::parse("/map").expect("a name"),
            MessageTypeName::new("nav_msgs", "OccupancyGrid"),
            &qos,
        )
        .expect("a topic");
    let publisher = node
        .create_publisher::<OccupancyGridMessage>(&topic, Some(qos))
        .expect("a publisher");
    group.bench_function("grid to message to publish", |b| {
        b.iter(|| {
            publisher
                .publish(occupancy_grid_message(
                    &grid,
                    &thresholds,
                    Header::default(),
                ))
                .is_ok()
        })
    });
    group.finish();
}

criterion_group!(benches, publish_map);
criterion_main!(benches);
