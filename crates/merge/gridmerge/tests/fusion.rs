//! Fusion properties: identity for an unknown B, A's resolution and lattice, no holes at any
//! resolution ratio and rotation, deterministic.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use core::f64::consts::PI;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{Cell, GridGeometry, OccupancyGrid, Point2};
use mapmerge_gridmerge::{fuse, resample_into, FusionParams, FusionWeighting};
use proptest::prelude::*;

fn grid_strategy(known: bool) -> impl Strategy<Value = OccupancyGrid> {
    (
        0.03f64..0.2,
        -5.0f64..5.0,
        -5.0f64..5.0,
        1usize..40,
        1usize..40,
    )
        .prop_flat_map(move |(resolution_m, x, y, width, height)| {
            let geometry = GridGeometry {
                resolution_m,
                origin_m: Point2::new(x, y),
                width,
                height,
            };
            let value = if known {
                prop_oneof![Just(0.0f32), -2.0f32..-0.05, 0.05f32..3.5].boxed()
            } else {
                Just(0.0f32).boxed()
            };
            prop::collection::vec(value, width * height)
                .prop_map(move |values| OccupancyGrid::from_log_odds(geometry, values).unwrap())
        })
}

fn transform() -> impl Strategy<Value = Se2> {
    (-3.0f64..3.0, -3.0f64..3.0, -PI..PI).prop_map(|(x, y, yaw)| Se2::new(x, y, yaw))
}

fn params() -> impl Strategy<Value = FusionParams> {
    prop::bool::ANY.prop_map(|quality| FusionParams {
        weighting: if quality {
            FusionWeighting::Quality
        } else {
            FusionWeighting::Uniform
        },
        ..FusionParams::default()
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    /// Fusing a map that knows nothing changes nothing, bit for bit.
    #[test]
    fn fusing_an_unknown_map_is_the_identity(
        a in grid_strategy(true),
        b in grid_strategy(false),
        a_from_b in transform(),
        params in params(),
    ) {
        let fused = fuse(&a, &b, &a_from_b, &params).unwrap();
        prop_assert_eq!(fused.merged.geometry(), a.geometry());
        let bits = |g: &OccupancyGrid| g.log_odds().iter().map(|l| l.to_bits()).collect::<Vec<_>>();
        prop_assert_eq!(bits(&fused.merged), bits(&a));
        prop_assert!(fused.b_in_a.log_odds().iter().all(|&l| l == 0.0));
    }

    /// The merged map is in A's frame and resolution, on A's lattice; A's cells sit at
    /// `a_shift_cells`, and cells B did not touch keep A's value.
    #[test]
    fn fusion_is_in_a_resolution_on_a_lattice(
        a in grid_strategy(true),
        b in grid_strategy(true),
        a_from_b in transform(),
        params in params(),
    ) {
        let fused = fuse(&a, &b, &a_from_b, &params).unwrap();
        let (ga, gm) = (a.geometry(), fused.merged.geometry());
        prop_assert_eq!(gm.resolution_m, ga.resolution_m);
        prop_assert_eq!(fused.b_in_a.geometry(), gm);
        let shift = fused.info.a_shift_cells;
        let offset = (ga.origin_m - gm.origin_m) / ga.resolution_m;
        prop_assert!((offset.x - shift.x as f64).abs() < 1e-6, "{} vs {}", offset.x, shift.x);
        prop_assert!((offset.y - shift.y as f64).abs() < 1e-6);
        for (cell, _, l) in a.cells() {
            let m = Cell::new(cell.x + shift.x, cell.y + shift.y);
            if fused.b_in_a.cell_log_odds(m) == 0.0 {
                prop_assert_eq!(fused.merged.cell_log_odds(m).to_bits(), l.to_bits());
            }
        }
        // Every fused cell stays within the clamp unless A already was outside it.
        for (cell, _, l) in fused.merged.cells() {
            if fused.b_in_a.cell_log_odds(cell) != 0.0 {
                let before = a.cell_log_odds(Cell::new(cell.x - shift.x, cell.y - shift.y));
                prop_assert!(
                    l == before || (params.min_log_odds..=params.max_log_odds).contains(&l)
                );
            }
        }
        // Deterministic.
        prop_assert_eq!(fuse(&a, &b, &a_from_b, &params).unwrap(), fused);
    }

    /// A fully observed B leaves no hole in A's cells it covers, whether A is finer or
    /// coarser (ratios 1:2 to 2:1) and however B is turned.
    #[test]
    fn resampling_leaves_no_holes(
        resolution_a in 0.05f64..0.2,
        ratio in 0.5f64..2.0,
        a_from_b in transform(),
    ) {
        let resolution_b = resolution_a * ratio;
        let b_geometry = GridGeometry {
            resolution_m: resolution_b,
            origin_m: Point2::new(-1.0, -0.5),
            width: 30,
            height: 20,
        };
        let b = OccupancyGrid::from_log_odds(b_geometry, vec![-1.0; 600]).unwrap();
        let target = GridGeometry {
            resolution_m: resolution_a,
            origin_m: Point2::new(-12.0, -12.0),
            width: (24.0 / resolution_a) as usize,
            height: (24.0 / resolution_a) as usize,
        };
        let out = resample_into(&b, &a_from_b, &target).unwrap();
        let b_from_a = a_from_b.inverse();
        let (lo, hi) = b_geometry.bounds_m();
        // Cells wholly inside B: the cell's half diagonal away from B's edges.
        let margin = resolution_a * 0.75;
        let mut inside = 0;
        for (cell, centre, l) in out.cells() {
            let p = b_from_a.transform_point(&centre);
            if p.x > lo.x + margin && p.x < hi.x - margin && p.y > lo.y + margin && p.y < hi.y - margin {
                inside += 1;
                prop_assert_eq!(l, -1.0, "hole at {:?}", cell);
            }
            // Nothing appears far outside B.
            let far = resolution_a * 1.5 + resolution_b;
            if p.x < lo.x - far || p.x > hi.x + far || p.y < lo.y - far || p.y > hi.y + far {
                prop_assert_eq!(l, 0.0, "value far outside B at {:?}", cell);
            }
        }
        prop_assert!(inside > 0);
    }
}

#[test]
fn coarse_b_into_fine_a_fills_every_fine_cell() {
    // A at 0.05 all unknown, B at 0.1 all free, turned 30°: every A cell whose centre is in
    // B gets B's value once (A unknown: filled).
    let a_geometry = GridGeometry {
        resolution_m: 0.05,
        origin_m: Point2::new(-2.0, -2.0),
        width: 80,
        height: 80,
    };
    let a = OccupancyGrid::with_geometry(a_geometry).unwrap();
    let b_geometry = GridGeometry {
        resolution_m: 0.1,
        origin_m: Point2::new(-0.5, -0.5),
        width: 10,
        height: 10,
    };
    let b = OccupancyGrid::from_log_odds(b_geometry, vec![-0.7; 100]).unwrap();
    let a_from_b = Se2::new(0.2, 0.1, PI / 6.0);
    let fused = fuse(&a, &b, &a_from_b, &FusionParams::default()).unwrap();
    assert_eq!(fused.merged.geometry(), &a_geometry);
    let b_from_a = a_from_b.inverse();
    let mut filled = 0;
    for (_, centre, l) in fused.merged.cells() {
        let p = b_from_a.transform_point(&centre);
        if p.x.abs() < 0.5 && p.y.abs() < 0.5 {
            assert_eq!(l, -0.7);
            filled += 1;
        }
    }
    // About 1 m² of 0.05 m cells.
    assert!((380..=420).contains(&filled), "{filled}");
    assert_eq!(fused.info.cells_new, fused.info.cells_changed);
    assert_eq!(fused.info.samples_per_cell, 1);
}
