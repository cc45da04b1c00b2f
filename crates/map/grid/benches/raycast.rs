//! Ray-casting throughput: cell updates per second when inserting 360-beam scans
//! (`cargo bench -p mapmerge-grid --bench raycast`). The target is 20 million cell
//! updates per second on one core.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use mapmerge_geometry::Se2;
use mapmerge_grid::{InsertParams, OccupancyGrid};
use mapmerge_scan::LaserScan;

/// A 360° scan of a 16 × 10 m room seen from `(x, y)` inside it.
fn room_scan(x: f64, y: f64) -> LaserScan {
    let n = 360;
    let (half_w, half_h) = (8.0, 5.0);
    let ranges = (0..n)
        .map(|i| {
            let a = -std::f64::consts::PI + i as f64 * std::f64::consts::TAU / n as f64;
            let (s, c) = a.sin_cos();
            let tx = if c > 0.0 {
                (half_w - x) / c
            } else if c < 0.0 {
                (-half_w - x) / c
            } else {
                f64::INFINITY
            };
            let ty = if s > 0.0 {
                (half_h - y) / s
            } else if s < 0.0 {
                (-half_h - y) / s
            } else {
                f64::INFINITY
            };
            tx.min(ty) as f32
        })
        .collect();
    LaserScan::new(
        -std::f64::consts::PI,
        std::f64::consts::PI - std::f64::consts::TAU / n as f64,
        30.0,
        ranges,
    )
}

fn raycast(c: &mut Criterion) {
    let scans: Vec<(Se2, LaserScan)> = (0..32)
        .map(|k| {
            let (x, y) = (-6.0 + 0.37 * k as f64, -3.0 + 0.19 * k as f64);
            (Se2::new(x, y, 0.1 * k as f64), room_scan(x, y))
        })
        .collect();
    let params = InsertParams::default();
    for resolution_m in [0.05, 0.02] {
        let mut grid = OccupancyGrid::new(resolution_m).unwrap_or_else(|e| panic!("{e}"));
        let mut cells = 0;
        for (pose, scan) in &scans {
            // Scans are in the room frame; rotate the pose back so beams stay in the room.
            let pose = Se2::new(pose.x_m, pose.y_m, 0.0);
            cells += grid
                .insert_scan(&pose, scan, &params)
                .map(|i| i.cells_visited)
                .unwrap_or(0);
        }
        let mut group = c.benchmark_group(format!("insert_32_scans_{}cm", resolution_m * 100.0));
        group.throughput(Throughput::Elements(cells as u64));
        group.bench_function("cell_updates", |b| {
            b.iter(|| {
                for (pose, scan) in &scans {
                    let pose = Se2::new(pose.x_m, pose.y_m, 0.0);
                    let _ = grid.insert_scan(&pose, scan, &params);
                }
            })
        });
        group.finish();
    }
}

/// Rendering local maps anchored to nodes: everything from scratch, and incrementally after
/// 5 of 200 nodes moved (what an online system does after a loop closure nudges a few nodes).
fn render_local_maps(c: &mut Criterion) {
    use mapmerge_grid::{LocalMapParams, LocalMaps};
    use mapmerge_posegraph::NodeId;
    use std::collections::BTreeMap;
    let nodes = 200;
    let mut maps = LocalMaps::new(LocalMapParams::new(0.05)).unwrap_or_else(|e| panic!("{e}"));
    let mut poses = BTreeMap::new();
    for k in 0..nodes {
        let (x, y) = (
            -6.0 + 12.0 * (k as f64 / nodes as f64),
            -3.0 + 0.02 * (k % 50) as f64,
        );
        let _ = maps.insert_scan(NodeId(k), &Se2::new(0.0, 0.0, 0.0), &room_scan(x, y));
        poses.insert(NodeId(k), Se2::new(x, y, 0.0));
    }
    let mut group = c.benchmark_group("render_200_local_maps_5cm");
    group.bench_function("from_scratch", |b| {
        b.iter_batched(
            || maps.clone(),
            |mut fresh| {
                let _ = fresh.render(&poses);
                fresh
            },
            criterion::BatchSize::LargeInput,
        )
    });
    let _ = maps.render(&poses);
    let mut moved = poses.clone();
    let mut flip = false;
    group.bench_function("incremental_5_moved", |b| {
        b.iter(|| {
            flip = !flip;
            for k in 0..5 {
                if let Some(pose) = moved.get_mut(&NodeId(k * 40)) {
                    pose.x_m += if flip { 0.1 } else { -0.1 };
                }
            }
            let _ = maps.render(&moved);
        })
    });
    group.finish();
}

criterion_group!(benches, raycast, render_local_maps);
criterion_main!(benches);
