//! Local maps anchored to nodes: incremental rendering equals rendering from scratch, moves
//! move the map, removal restores what was there.

#![allow(clippy::unwrap_used)]

use std::collections::BTreeMap;

use mapmerge_geometry::Se2;
use mapmerge_grid::{Cell, LocalMapParams, LocalMaps, OccupancyGrid, Point2};
use mapmerge_posegraph::NodeId;
use mapmerge_scan::LaserScan;
use proptest::prelude::*;

/// A scan of a square room of half-size `half_m` seen from its centre.
fn room_scan(half_m: f64) -> LaserScan {
    let n = 180;
    let ranges = (0..n)
        .map(|i| {
            let a = -std::f64::consts::PI + i as f64 * 2.0 * std::f64::consts::PI / n as f64;
            (half_m / a.cos().abs().max(a.sin().abs())) as f32
        })
        .collect();
    let mut scan = LaserScan::new(
        -std::f64::consts::PI,
        std::f64::consts::PI * (1.0 - 2.0 / n as f64),
        30.0,
        ranges,
    );
    scan.range_min_m = 0.05;
    scan
}

fn maps_with(nodes: usize) -> LocalMaps {
    let mut maps = LocalMaps::new(LocalMapParams::new(0.1)).unwrap();
    for k in 0..nodes {
        let scan = room_scan(1.0 + 0.3 * k as f64);
        maps.insert_scan(NodeId(k as u64), &Se2::new(0.0, 0.0, 0.0), &scan)
            .unwrap();
        maps.insert_scan(NodeId(k as u64), &Se2::new(0.1, 0.0, 0.05), &scan)
            .unwrap();
    }
    maps
}

/// The rendered grid cropped to its known cells, as (world cell centre → log-odds).
fn known(grid: &OccupancyGrid) -> BTreeMap<(i64, i64), f32> {
    grid.known_cells()
        .map(|(_, p, l)| (((p.x / 0.1).floor() as i64, (p.y / 0.1).floor() as i64), l))
        .collect()
}

fn poses(values: &[(f64, f64, f64)]) -> BTreeMap<NodeId, Se2> {
    values
        .iter()
        .enumerate()
        .map(|(k, &(x, y, t))| (NodeId(k as u64), Se2::new(x, y, t)))
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    #[test]
    fn incremental_render_equals_render_from_scratch(
        first in proptest::collection::vec((-3.0..3.0f64, -3.0..3.0f64, -3.0..3.0f64), 3),
        second in proptest::collection::vec((-3.0..3.0f64, -3.0..3.0f64, -3.0..3.0f64), 3),
        drop_node in 0usize..4,
    ) {
        let mut incremental = maps_with(3);
        incremental.render(&poses(&first)).unwrap();
        let mut later = poses(&second);
        later.remove(&NodeId(drop_node as u64));
        let info = incremental.render(&later).unwrap();
        prop_assert_eq!(info.removed, usize::from(drop_node < 3));
        let mut scratch = maps_with(3);
        scratch.render(&later).unwrap();
        prop_assert_eq!(known(incremental.rendered()), known(scratch.rendered()));

        // Going back restores the first rendering bit for bit.
        incremental.render(&poses(&first)).unwrap();
        let mut again = maps_with(3);
        again.render(&poses(&first)).unwrap();
        prop_assert_eq!(known(incremental.rendered()), known(again.rendered()));
    }
}

#[test]
fn a_translation_by_whole_cells_moves_the_map_exactly() {
    let mut maps = maps_with(1);
    maps.render(&poses(&[(0.0, 0.0, 0.0)])).unwrap();
    let before = known(maps.rendered());
    let info = maps.render(&poses(&[(0.5, -0.3, 0.0)])).unwrap();
    assert_eq!((info.moved, info.added, info.unchanged), (1, 0, 0));
    let after = known(maps.rendered());
    let shifted: BTreeMap<_, _> = before
        .iter()
        .map(|(&(x, y), &l)| ((x + 5, y - 3), l))
        .collect();
    assert_eq!(after, shifted);
}

#[test]
fn small_moves_are_not_redrawn_and_removal_empties_the_grid() {
    let mut maps = maps_with(2);
    let info = maps
        .render(&poses(&[(0.0, 0.0, 0.0), (4.0, 0.0, 1.0)]))
        .unwrap();
    assert_eq!(info.added, 2);
    let info = maps
        .render(&poses(&[(0.01, 0.0, 0.0), (4.0, 0.0, 1.0)]))
        .unwrap();
    assert_eq!((info.moved, info.unchanged), (0, 2));
    let info = maps.render(&BTreeMap::new()).unwrap();
    assert_eq!(info.removed, 2);
    assert_eq!(maps.rendered().known_cells().count(), 0);
}

#[test]
fn new_scans_and_removed_maps_update_the_rendering() {
    let mut maps = maps_with(2);
    let at = poses(&[(0.0, 0.0, 0.0), (10.0, 0.0, 0.0)]);
    maps.render(&at).unwrap();
    let wall = Point2::new(10.0 + 1.3, 0.0);
    let thresholds = mapmerge_grid::ClassThresholds::default();
    let class = |maps: &LocalMaps| {
        maps.rendered()
            .class(maps.rendered().geometry().cell_of(&wall), &thresholds)
    };
    assert_eq!(class(&maps), mapmerge_grid::CellClass::Occupied);
    let removed = maps.remove(NodeId(1)).unwrap();
    assert_eq!(class(&maps), mapmerge_grid::CellClass::Unknown);
    maps.insert_local_map(NodeId(1), removed);
    let info = maps.render(&at).unwrap();
    assert_eq!((info.added, info.unchanged), (1, 1));
    assert_eq!(class(&maps), mapmerge_grid::CellClass::Occupied);
    // A scan added to a drawn node takes it out until the next render.
    maps.insert_scan(NodeId(1), &Se2::new(0.0, 0.0, 0.0), &room_scan(1.3))
        .unwrap();
    assert_eq!(class(&maps), mapmerge_grid::CellClass::Unknown);
    maps.render(&at).unwrap();
    assert_eq!(class(&maps), mapmerge_grid::CellClass::Occupied);
    assert_eq!(maps.get(NodeId(1)).map(|m| m.scans()), Some(3));
    let _ = Cell::new(0, 0);
}

#[test]
fn rendering_local_maps_matches_inserting_the_scans_directly() {
    // One node per scan, each scan in its node's frame; rendering at the scan poses must give
    // the map that inserting the scans into one grid gives (up to resampling by a rotation).
    let thresholds = mapmerge_grid::ClassThresholds::default();
    let poses: Vec<Se2> = (0..12)
        .map(|k| Se2::new(0.3 * k as f64, 0.1 * (k % 3) as f64, 0.37 * k as f64))
        .collect();
    let scans: Vec<LaserScan> = poses
        .iter()
        .map(|p| {
            // The same 4 × 3 m room seen from each pose: ranges by ray-box intersection.
            let n = 360;
            let ranges = (0..n)
                .map(|i| {
                    let a = p.theta_rad - std::f64::consts::PI
                        + i as f64 * std::f64::consts::TAU / n as f64;
                    let (s, c) = a.sin_cos();
                    let tx = if c > 0.0 {
                        (6.0 - p.x_m) / c
                    } else {
                        (-2.0 - p.x_m) / c
                    };
                    let ty = if s > 0.0 {
                        (2.0 - p.y_m) / s
                    } else {
                        (-1.5 - p.y_m) / s
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
        })
        .collect();
    let params = LocalMapParams::new(0.05);
    let (direct, _) =
        OccupancyGrid::from_scans(0.05, poses.iter().copied().zip(&scans), &params.insert).unwrap();
    let mut maps = LocalMaps::new(params).unwrap();
    let mut at = BTreeMap::new();
    for (k, (pose, scan)) in poses.iter().zip(&scans).enumerate() {
        maps.insert_scan(NodeId(k as u64), &Se2::new(0.0, 0.0, 0.0), scan)
            .unwrap();
        at.insert(NodeId(k as u64), *pose);
    }
    maps.render(&at).unwrap();
    let rendered = maps.rendered();
    let occupied_direct = direct.mask(mapmerge_grid::CellClass::Occupied, &thresholds);
    let near_direct = occupied_direct.dilate(1);
    let occupied_rendered: Vec<Point2> = rendered
        .cells()
        .filter(|&(_, _, l)| thresholds.classify(l) == mapmerge_grid::CellClass::Occupied)
        .map(|(_, p, _)| p)
        .collect();
    let close = occupied_rendered
        .iter()
        .filter(|p| near_direct.is_set(direct.geometry().cell_of(p)))
        .count();
    assert!(occupied_rendered.len() > 500);
    assert!(
        close as f64 > 0.97 * occupied_rendered.len() as f64,
        "{close} of {}",
        occupied_rendered.len()
    );
    // Free space agrees cell for cell almost everywhere.
    let free_direct = direct.mask(mapmerge_grid::CellClass::Free, &thresholds);
    let free_rendered: Vec<Point2> = rendered
        .cells()
        .filter(|&(_, _, l)| thresholds.classify(l) == mapmerge_grid::CellClass::Free)
        .map(|(_, p, _)| p)
        .collect();
    let same = free_rendered
        .iter()
        .filter(|p| free_direct.is_set(direct.geometry().cell_of(p)))
        .count();
    assert!(
        same as f64 > 0.97 * free_rendered.len() as f64,
        "{same} of {}",
        free_rendered.len()
    );
}
