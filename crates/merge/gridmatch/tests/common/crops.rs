//! Pairs of overlapping crops of one real map with a known transform, shared by the tests,
//! the benchmark example and the criterion bench (`#[path]`-included).

#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{Cell, ClassThresholds, GridGeometry, OccupancyGrid, Point2};
use rand::Rng;

/// Two crops and the truth.
pub struct CropPair {
    /// Axis-aligned window of the map, in the map's frame.
    pub a: OccupancyGrid,
    /// A window in a turned and shifted frame, possibly at another resolution.
    pub b: OccupancyGrid,
    /// B's map frame in A's.
    pub a_from_b: Se2,
    /// Cells known in both under the truth / known cells of the smaller crop.
    pub overlap: f64,
}

/// Reads a ROS map_server map below the data folder.
pub fn read_map(path: &std::path::Path) -> Option<OccupancyGrid> {
    mapmerge_io::read_ros_map(path).ok()?.to_grid().ok()
}

fn known(grid: &OccupancyGrid) -> usize {
    grid.log_odds().iter().filter(|&&l| l != 0.0).count()
}

/// The square window `[x0, x0 + side) × [y0, y0 + side)` of `map` (same frame).
pub fn window(
    map: &OccupancyGrid,
    x0: usize,
    y0: usize,
    side_x: usize,
    side_y: usize,
) -> OccupancyGrid {
    let g = map.geometry();
    let geometry = GridGeometry {
        resolution_m: g.resolution_m,
        origin_m: g.origin_m + Point2::new(x0 as f64, y0 as f64) * g.resolution_m,
        width: side_x,
        height: side_y,
    };
    let mut log_odds = Vec::with_capacity(side_x * side_y);
    for y in y0..y0 + side_y {
        for x in x0..x0 + side_x {
            log_odds.push(map.cell_log_odds(Cell::new(x as i64, y as i64)));
        }
    }
    OccupancyGrid::from_log_odds(geometry, log_odds).unwrap()
}

/// `map` seen in a frame `map_from_b`: a `side_m` square grid at `resolution_m` (the map
/// is resampled to it first, so walls survive), cells read at the nearest map cell.
pub fn turned(
    map: &OccupancyGrid,
    map_from_b: &Se2,
    side_m: f64,
    resolution_m: f64,
) -> OccupancyGrid {
    let source = if (resolution_m - map.resolution_m()).abs() > 1e-12 {
        map.resample(resolution_m).unwrap()
    } else {
        map.clone()
    };
    let n = (side_m / resolution_m).round() as usize;
    let geometry = GridGeometry {
        resolution_m,
        origin_m: Point2::zeros(),
        width: n,
        height: n,
    };
    let mut grid = OccupancyGrid::with_geometry(geometry).unwrap();
    for (i, slot) in grid.log_odds_mut().iter_mut().enumerate() {
        let cell = geometry.cell_at(i);
        *slot = source.log_odds_at(&map_from_b.transform_point(&geometry.center_of(cell)));
    }
    grid
}

/// Fraction of the smaller crop's known cells known in both under `a_from_b`.
pub fn overlap(a: &OccupancyGrid, b: &OccupancyGrid, a_from_b: &Se2) -> f64 {
    let both = b
        .known_cells()
        .filter(|(_, p, _)| a.log_odds_at(&a_from_b.transform_point(p)) != 0.0)
        .count();
    // Count on the finer lattice, in the same area units.
    let area_b = both as f64 * b.resolution_m().powi(2);
    let area_a = known(a) as f64 * a.resolution_m().powi(2);
    let area_b_total = known(b) as f64 * b.resolution_m().powi(2);
    area_b / area_a.min(area_b_total).max(1e-9)
}

/// A random pair from `map`: windows of `side_m`, overlap in `[min_overlap, max_overlap]`,
/// any heading, one crop coarsened by up to `max_ratio`. `None` after 200 failed tries.
pub fn crop_pair<R: Rng>(
    map: &OccupancyGrid,
    rng: &mut R,
    side_m: f64,
    min_overlap: f64,
    max_overlap: f64,
    max_ratio: f64,
) -> Option<CropPair> {
    let g = *map.geometry();
    let side = (side_m / g.resolution_m).round() as usize;
    if side > g.width || side > g.height {
        return None;
    }
    let thresholds = ClassThresholds::default();
    for _ in 0..200 {
        let x0 = rng.random_range(0..=g.width - side);
        let y0 = rng.random_range(0..=g.height - side);
        let a = window(map, x0, y0, side, side);
        if known(&a) < side * side / 4 {
            continue;
        }
        // B's centre: A's centre plus a random offset; heading anywhere.
        let (lo, hi) = a.geometry().bounds_m();
        let centre = (lo + hi) * 0.5;
        let direction = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
        let distance = rng.random_range(0.1..0.8) * side_m;
        let theta = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
        let b_centre = centre + Point2::new(direction.cos(), direction.sin()) * distance;
        let ratio = rng.random_range(1.0..max_ratio.max(1.0 + 1e-9));
        let coarsen_a = rng.random_bool(0.5);
        let resolution_b = if coarsen_a {
            g.resolution_m
        } else {
            g.resolution_m * ratio
        };
        let rotation = Se2::new(0.0, 0.0, theta);
        // map_from_b maps B's square [0, side_m]² centre onto b_centre.
        let half = Point2::new(side_m, side_m) * 0.5;
        let turned_half = rotation.transform_point(&half);
        let map_from_b = Se2::new(
            b_centre.x - turned_half.x,
            b_centre.y - turned_half.y,
            theta,
        );
        let b = turned(map, &map_from_b, side_m, resolution_b);
        if known(&b) < (b.geometry().len()) / 4 {
            continue;
        }
        let a = if coarsen_a {
            a.resample(g.resolution_m * ratio).unwrap()
        } else {
            a
        };
        let occupied = |grid: &OccupancyGrid| {
            grid.log_odds()
                .iter()
                .filter(|&&l| thresholds.classify(l) == mapmerge_grid::CellClass::Occupied)
                .count()
        };
        if occupied(&a) < 200 || occupied(&b) < 200 {
            continue;
        }
        let a_from_b = map_from_b; // A's frame is the map's frame.
        let overlap = overlap(&a, &b, &a_from_b);
        if overlap < min_overlap || overlap > max_overlap {
            continue;
        }
        return Some(CropPair {
            a,
            b,
            a_from_b,
            overlap,
        });
    }
    None
}

/// Error of `found` against `truth` at B's known-cell centroid: (cells of `resolution_m`, rad).
pub fn error(b: &OccupancyGrid, truth: &Se2, found: &Se2, resolution_m: f64) -> (f64, f64) {
    let points: Vec<Point2> = b.known_cells().map(|(_, p, _)| p).collect();
    let centroid = points.iter().sum::<Point2>() / points.len().max(1) as f64;
    let d = (truth.transform_point(&centroid) - found.transform_point(&centroid)).norm();
    let turn = truth.between(found).theta_rad.abs();
    (d / resolution_m, turn)
}

/// Two 1000 × 1000-cell crops (50 m at 0.05 m) of a map of at least 1000 × 1000 cells
/// (UT Austin GDC): A at the lower left, B turned by 37° and shifted right, about half overlap.
pub fn pair_1000(map: &OccupancyGrid) -> (OccupancyGrid, OccupancyGrid, Se2) {
    let g = map.geometry();
    let side = 1000.min(g.width).min(g.height);
    let a = window(map, 0, 0, side, side);
    let side_m = side as f64 * g.resolution_m;
    let (lo, _) = a.geometry().bounds_m();
    let theta = 37f64.to_radians();
    let half = Point2::new(side_m, side_m) * 0.5;
    let centre = lo + half + Point2::new(0.45 * side_m, 0.1 * side_m);
    let turned_half = Se2::new(0.0, 0.0, theta).transform_point(&half);
    let map_from_b = Se2::new(centre.x - turned_half.x, centre.y - turned_half.y, theta);
    let b = turned(map, &map_from_b, side_m, g.resolution_m);
    (a, b, map_from_b)
}
