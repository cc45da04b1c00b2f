//! Metric properties and matching on small synthetic maps (no data needed).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_geometry::{wrap_angle_rad, Se2};
use mapmerge_grid::{Cell, ClassThresholds, GridGeometry, OccupancyGrid, Point2};
use mapmerge_gridmatch::{map_metrics, match_grids, GridMatchError, GridMatchParams, Which};

mod common;
use common::crops;

const WALL: f32 = 2.0;
const FREE: f32 = -2.0;

/// A 12 × 8 m room at 0.05 m with an inner wall and two pillars; `symmetric` places the
/// pillars and wall point-symmetrically about the centre (the room looks the same turned by
/// 180°), otherwise not.
fn room(symmetric: bool) -> OccupancyGrid {
    let geometry = GridGeometry {
        resolution_m: 0.05,
        origin_m: Point2::new(-8.0, -6.0),
        width: 320,
        height: 240,
    };
    let mut grid = OccupancyGrid::with_geometry(geometry).unwrap();
    let (x0, x1, y0, y1) = (40i64, 280i64, 40i64, 200i64);
    for x in x0..x1 {
        for y in y0..y1 {
            let border = x == x0 || x == x1 - 1 || y == y0 || y == y1 - 1;
            let pillar = |cx: i64, cy: i64| (x - cx).abs() <= 4 && (y - cy).abs() <= 4;
            let inner = if symmetric {
                (x == 120 && y < 150) || (x == 199 && y >= 90)
            } else {
                (x == 120 && y < 150) || (y == 160 && (180..260).contains(&x))
            };
            let pillars = if symmetric {
                pillar(90, 170) || pillar(229, 69)
            } else {
                pillar(90, 170) || pillar(230, 100)
            };
            let value = if border || inner || pillars {
                WALL
            } else {
                FREE
            };
            grid.set(Cell::new(x, y), value).unwrap();
        }
    }
    grid
}

#[test]
fn identical_maps_have_sm_one_and_dm_zero() {
    let a = room(false);
    let m = map_metrics(
        &a,
        &a,
        &Se2::new(0.0, 0.0, 0.0),
        &ClassThresholds::default(),
    )
    .unwrap();
    assert_eq!(m.sm, 1.0);
    assert_eq!(m.dm_cells, 0.0);
    assert_eq!(m.disagree_cells, 0);
    assert_eq!(m.overlap_cells, a.known_cells().count());
}

#[test]
fn dm_grows_with_displacement() {
    let a = room(false);
    let thresholds = ClassThresholds::default();
    let dms: Vec<f64> = [0.0, 1.0, 2.0, 4.0, 8.0]
        .iter()
        .map(|cells| {
            let shift = Se2::new(cells * 0.05, cells * 0.025, 0.0);
            map_metrics(&a, &a, &shift, &thresholds).unwrap().dm_cells
        })
        .collect();
    assert!(dms.windows(2).all(|w| w[0] < w[1]), "{dms:?}");
    let turned = map_metrics(&a, &a, &Se2::new(0.0, 0.0, 3f64.to_radians()), &thresholds).unwrap();
    assert!(turned.dm_cells > dms[1] && turned.sm < 1.0);
}

#[test]
fn unknown_cells_are_ignored() {
    let full = room(false);
    // A: the left half forgotten (unknown); B: everything.
    let mut half = full.clone();
    let width = half.geometry().width;
    for (i, l) in half.log_odds_mut().iter_mut().enumerate() {
        if i % width < width / 2 {
            *l = 0.0;
        }
    }
    let thresholds = ClassThresholds::default();
    let identity = Se2::new(0.0, 0.0, 0.0);
    for (a, b) in [(&half, &full), (&full, &half)] {
        let m = map_metrics(a, b, &identity, &thresholds).unwrap();
        assert_eq!(m.sm, 1.0);
        assert_eq!(m.dm_cells, 0.0);
        assert_eq!(m.overlap_cells, half.known_cells().count());
    }
}

#[test]
fn metrics_work_across_resolutions() {
    let a = room(false);
    let coarse = a.resample(0.1).unwrap();
    let m = map_metrics(
        &a,
        &coarse,
        &Se2::new(0.0, 0.0, 0.0),
        &ClassThresholds::default(),
    )
    .unwrap();
    assert_eq!(m.resolution_m, 0.1);
    assert_eq!(m.sm, 1.0);
    assert_eq!(m.dm_cells, 0.0);
}

#[test]
fn finds_a_turned_coarser_copy() {
    let a = room(false);
    let map_from_b = Se2::new(-5.0, 3.0, -2.0);
    let b = crops::turned(&a, &map_from_b, 14.0, 0.08);
    let result = match_grids(&a, &b, &GridMatchParams::default()).unwrap();
    assert!(result.accepted, "{:?}", result.rejection);
    assert_eq!(result.resolution_m, 0.08);
    let (cells, rad) = crops::error(&b, &map_from_b, &result.hypotheses[0].a_from_b, 0.08);
    assert!(
        cells <= 2.0 && rad.to_degrees() <= 1.0,
        "{cells} cells, {rad} rad"
    );
}

#[test]
fn symmetric_room_keeps_the_180_degree_ambiguity() {
    let a = room(true);
    let map_from_b = Se2::new(-2.5, -9.0, 0.5);
    let b = crops::turned(&a, &map_from_b, 14.0, 0.05);
    let result = match_grids(&a, &b, &GridMatchParams::default()).unwrap();
    let has = |theta: f64| {
        result.hypotheses.iter().any(|h| {
            wrap_angle_rad(h.a_from_b.theta_rad - theta).abs() < 1f64.to_radians()
                && h.acceptance > 0.95
        })
    };
    assert!(
        has(0.5) && has(0.5 + std::f64::consts::PI),
        "{:?}",
        result.hypotheses
    );
    // Both explain the map equally well: not accepted.
    assert!(!result.accepted);
}

#[test]
fn refuses_bad_input_without_panicking() {
    let a = room(false);
    let empty = OccupancyGrid::new(0.05).unwrap();
    let params = GridMatchParams::default();
    assert_eq!(
        match_grids(&a, &empty, &params).unwrap_err(),
        GridMatchError::EmptyMap(Which::B)
    );
    let unknown = OccupancyGrid::with_geometry(*a.geometry()).unwrap();
    assert_eq!(
        match_grids(&unknown, &a, &params).unwrap_err(),
        GridMatchError::NoKnownCells(Which::A)
    );
    let mut free_only = a.clone();
    for l in free_only.log_odds_mut() {
        *l = l.min(FREE);
    }
    assert_eq!(
        match_grids(&a, &free_only, &params).unwrap_err(),
        GridMatchError::NoOccupiedCells(Which::B)
    );
    let thresholds = ClassThresholds::default();
    assert_eq!(
        map_metrics(
            &a,
            &a,
            &Se2 {
                x_m: f64::NAN,
                y_m: 0.0,
                theta_rad: 0.0
            },
            &thresholds
        )
        .unwrap_err(),
        GridMatchError::NonFiniteTransform
    );
    let bad = GridMatchParams {
        hough_angle_bins: 0,
        ..GridMatchParams::default()
    };
    assert!(matches!(
        match_grids(&a, &a, &bad),
        Err(GridMatchError::Params(ref e)) if e.field == "hough_angle_bins"
    ));
}
