//! Fusion of two 1000 × 1000-cell grids (the size), rotated, at equal and at 0.07 / 0.10
//! resolutions.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use criterion::{criterion_group, criterion_main, Criterion};
use mapmerge_geometry::Se2;
use mapmerge_grid::{GridGeometry, OccupancyGrid, Point2};
use mapmerge_gridmerge::{fuse, FusionParams};

/// A deterministic room-like grid: free space, walls every 40 cells, unknown outside a disc.
fn grid(resolution_m: f64, cells: usize) -> OccupancyGrid {
    let geometry = GridGeometry {
        resolution_m,
        origin_m: Point2::zeros(),
        width: cells,
        height: cells,
    };
    let c = cells as f64 / 2.0;
    let values = (0..cells * cells)
        .map(|i| {
            let (x, y) = ((i % cells) as f64, (i / cells) as f64);
            if (x - c).hypot(y - c) > c {
                0.0
            } else if (i % cells) % 40 == 0 || (i / cells) % 40 == 0 {
                2.0
            } else {
                -1.5
            }
        })
        .collect();
    OccupancyGrid::from_log_odds(geometry, values).unwrap()
}

fn bench(c: &mut Criterion) {
    let a = grid(0.07, 1000);
    let b_same = grid(0.07, 1000);
    let b_coarse = grid(0.10, 1000);
    let a_from_b = Se2::new(3.0, -2.0, 0.4);
    let params = FusionParams::default();
    c.bench_function("fuse_1000x1000_same_resolution", |bench| {
        bench.iter(|| fuse(&a, &b_same, &a_from_b, &params).unwrap())
    });
    c.bench_function("fuse_1000x1000_a007_b010", |bench| {
        bench.iter(|| fuse(&a, &b_coarse, &a_from_b, &params).unwrap())
    });
    c.bench_function("fuse_1000x1000_a010_b007", |bench| {
        bench.iter(|| fuse(&b_coarse, &a, &a_from_b, &params).unwrap())
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
