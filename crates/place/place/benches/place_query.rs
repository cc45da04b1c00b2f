//! Query time of the place index with 20,000 keyframes: lidar scans from pseudo-random free
//! poses in the simulator's `office` world.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use mapmerge_geometry::Se2;
use mapmerge_place::{KeyframeId, PlaceDescriptor, PlaceIndex, ScanContext, ScanContextParams};
use mapmerge_scan::{BeamFilter, Point2};
use mapmerge_sim::{generate_world, Lidar, LidarParams, WorldPreset};

/// `count` scans (points in the robot frame) from free poses of the office world.
fn office_scans(count: usize) -> Vec<Vec<Point2>> {
    let world = generate_world(&WorldPreset::Office.params(), 1).unwrap();
    let lidar = Lidar::new(&world, LidarParams::default()).unwrap();
    let bounds = world.bounds();
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        // xorshift64*: deterministic, no extra dependency.
        state ^= state >> 12;
        state ^= state << 25;
        state ^= state >> 27;
        (state.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut scans = Vec::with_capacity(count);
    while scans.len() < count {
        let p = Point2::new(
            bounds.min_m.x + next() * (bounds.max_m.x - bounds.min_m.x),
            bounds.min_m.y + next() * (bounds.max_m.y - bounds.min_m.y),
        );
        let yaw = (next() - 0.5) * std::f64::consts::TAU;
        if !world.is_inside_building(&p) || world.is_inside_obstacle(&p) {
            continue;
        }
        let scan = lidar.scan(&Se2::new(p.x, p.y, yaw), scans.len() as u64);
        scans.push(scan.points_in_robot(&BeamFilter::default()));
    }
    scans
}

fn bench_place(c: &mut Criterion) {
    const INDEXED: usize = 20_000;
    let params = ScanContextParams::default();
    let scans = office_scans(INDEXED + 200);
    let descriptors: Vec<ScanContext> =
        scans.iter().map(|s| ScanContext::new(s, &params)).collect();
    let mut index: PlaceIndex = PlaceIndex::default();
    for (i, d) in descriptors.iter().take(INDEXED).enumerate() {
        index.insert(KeyframeId(i as u64), d.clone());
    }
    let queries = &descriptors[INDEXED..];
    let mut q = 0usize;
    c.bench_function("place_query_office_20000_k5", |b| {
        b.iter(|| {
            q = (q + 1) % queries.len();
            black_box(index.query(&queries[q], 5))
        })
    });
    c.bench_function("place_describe_office_360_beams", |b| {
        b.iter(|| black_box(ScanContext::new(&scans[q % scans.len()], &params)))
    });
    c.bench_function("place_compare_20x60", |b| {
        b.iter(|| black_box(descriptors[0].compare(&descriptors[1])))
    });
    c.bench_function("place_insert_office_20000", |b| {
        b.iter(|| {
            let mut index: PlaceIndex = PlaceIndex::default();
            for (i, d) in descriptors.iter().take(INDEXED).enumerate() {
                index.insert(KeyframeId(i as u64), d.clone());
            }
            black_box(index.len())
        })
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench_place
}
criterion_main!(benches);
