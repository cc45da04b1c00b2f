//! Inserting scans: exact grid traversal of every beam (Amanatides & Woo 1987, "A fast voxel
//! traversal algorithm") with the inverse sensor model of [`SensorModel`].
//!
//! Each cell changes at most once per scan and hits win over misses (as Cartographer's
//! `ProbabilityGridRangeDataInserter2D`), so a wall grazed by neighbouring beams stays a wall.

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::{BeamFilter, LaserScan};
use serde::{Deserialize, Serialize};

use crate::occupancy::grown_to_cells;
use crate::{GridError, OccupancyGrid, Point2, SensorModel};

/// How scans are turned into cell updates.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct InsertParams {
    /// Hit/miss log-odds and clamping.
    pub model: SensorModel,
    /// Returns beyond this range (m) are not trusted as hits: the beam clears free space up
    /// to this range and marks nothing occupied (GMapping's `maxUrange`).
    pub max_hit_range_m: f32,
    /// Beams without a return (reading ≥ the sensor's maximum) clear free space up to this
    /// range (m); 0 leaves them out.
    pub no_return_free_range_m: f32,
    /// Beams shorter than this (m) are ignored (robot body, dirt on the window).
    pub min_range_m: f32,
}

impl Default for InsertParams {
    fn default() -> Self {
        Self {
            model: SensorModel::default(),
            max_hit_range_m: f32::INFINITY,
            no_return_free_range_m: 0.0,
            min_range_m: 0.0,
        }
    }
}

/// What one insertion did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct InsertInfo {
    /// Beams that ended in an occupied-cell update.
    pub hits: usize,
    /// Beams used for free space only.
    pub free_only: usize,
    /// Cells visited by the traversal (hit and miss updates, counting skipped repeats).
    pub cells_visited: usize,
}

impl InsertInfo {
    /// Adds another insertion's counts.
    pub fn accumulate(&mut self, other: &InsertInfo) {
        self.hits += other.hits;
        self.free_only += other.free_only;
        self.cells_visited += other.cells_visited;
    }
}

/// One beam in the grid frame.
#[derive(Clone, Copy, Debug)]
struct Beam {
    end: Point2,
    hit: bool,
}

/// The sensor's position and the beams of `scan` taken with the robot at `grid_from_robot`
/// (grid frame): hits up to `max_hit_range_m`, longer returns and no-returns as free space
/// only.
fn scan_beams(
    grid_from_robot: &Se2,
    scan: &LaserScan,
    params: &InsertParams,
) -> Result<(Point2, Vec<Beam>), GridError> {
    let grid_from_sensor = grid_from_robot.compose(&scan.robot_from_sensor);
    let origin = grid_from_sensor.translation();
    if !grid_from_sensor.is_finite() {
        return Err(GridError::NotFinite);
    }
    let filter = BeamFilter {
        min_range_m: params.min_range_m,
        ..BeamFilter::default()
    };
    let rotation = grid_from_sensor.rotation_matrix();
    let mut beams = Vec::with_capacity(scan.len());
    for (angle_rad, range_m) in scan.beams() {
        let (length_m, hit) = if scan.passes(&filter, angle_rad, range_m) {
            if range_m <= params.max_hit_range_m {
                (range_m, true)
            } else {
                (params.max_hit_range_m, false)
            }
        } else if range_m.is_finite() && range_m >= scan.range_max_m {
            (params.no_return_free_range_m, false)
        } else {
            continue;
        };
        if !(length_m > 0.0 && length_m.is_finite()) {
            continue;
        }
        let (sin, cos) = angle_rad.sin_cos();
        let end = origin + rotation * Point2::new(cos, sin) * f64::from(length_m);
        beams.push(Beam { end, hit });
    }
    Ok((origin, beams))
}

/// The bounding box of `origin` and every beam's end; `None` without beams.
fn beams_box(origin: &Point2, beams: &[Beam]) -> Option<(Point2, Point2)> {
    if beams.is_empty() {
        return None;
    }
    let (mut lo, mut hi) = (*origin, *origin);
    for beam in beams {
        lo = lo.inf(&beam.end);
        hi = hi.sup(&beam.end);
    }
    Some((lo, hi))
}

impl OccupancyGrid {
    /// A grid of `resolution_m` built from scans taken at known poses (`grid_from_robot`),
    /// inserted in order.
    pub fn from_scans<'a>(
        resolution_m: f64,
        posed_scans: impl IntoIterator<Item = (Se2, &'a LaserScan)>,
        params: &InsertParams,
    ) -> Result<(OccupancyGrid, InsertInfo), GridError> {
        let posed: Vec<(Se2, &LaserScan)> = posed_scans.into_iter().collect();
        Self::from_posed_scans(resolution_m, &posed, params, || ())
    }

    /// [`OccupancyGrid::from_scans`] over a slice, calling `progress()` after each scan. The
    /// grid is made at once as large as inserting the scans one by one would grow it (the
    /// same geometry), so it is never copied as it grows, and its insertion scratch is
    /// freed at the end.
    pub fn from_posed_scans(
        resolution_m: f64,
        posed_scans: &[(Se2, &LaserScan)],
        params: &InsertParams,
        mut progress: impl FnMut(),
    ) -> Result<(OccupancyGrid, InsertInfo), GridError> {
        let mut boxes = Vec::with_capacity(posed_scans.len());
        for (grid_from_robot, scan) in posed_scans {
            let (origin, beams) = scan_beams(grid_from_robot, scan, params)?;
            boxes.extend(beams_box(&origin, &beams));
        }
        let mut grid = Self::sized_for(resolution_m, boxes)?;
        let mut total = InsertInfo::default();
        for (grid_from_robot, scan) in posed_scans {
            total.accumulate(&grid.insert_scan(grid_from_robot, scan, params)?);
            progress();
        }
        grid.release_scratch();
        Ok((grid, total))
    }

    /// An empty grid of `resolution_m` as large as inserting rays within each box `(lo, hi)`
    /// (metres; a scan's sensor and beam ends), in order, would grow it: the same geometry,
    /// made at once, so that inserting those rays never copies the grid.
    pub fn sized_for(
        resolution_m: f64,
        boxes: impl IntoIterator<Item = (Point2, Point2)>,
    ) -> Result<OccupancyGrid, GridError> {
        let mut geometry = *OccupancyGrid::new(resolution_m)?.geometry();
        for (lo, hi) in boxes {
            if !(lo.iter().chain(hi.iter()).all(|v| v.is_finite())) {
                return Err(GridError::NotFinite);
            }
            if let Some((grown, _)) =
                grown_to_cells(&geometry, geometry.cell_of(&lo), geometry.cell_of(&hi))?
            {
                geometry = grown;
            }
        }
        if geometry.is_empty() {
            OccupancyGrid::new(resolution_m)
        } else {
            OccupancyGrid::with_geometry(geometry)
        }
    }

    /// Inserts `scan` taken with the robot at `grid_from_robot`: free space along every beam,
    /// occupied where it ends. The grid grows to hold every beam.
    pub fn insert_scan(
        &mut self,
        grid_from_robot: &Se2,
        scan: &LaserScan,
        params: &InsertParams,
    ) -> Result<InsertInfo, GridError> {
        let (origin, beams) = scan_beams(grid_from_robot, scan, params)?;
        self.insert_beams(&origin, &beams, &params.model)
    }

    /// Inserts beams from `origin` (grid frame) to each end point; `hit[i]` says whether beam
    /// `i` ends on an obstacle.
    pub fn insert_rays(
        &mut self,
        origin: &Point2,
        ends: &[Point2],
        hit: &[bool],
        model: &SensorModel,
    ) -> Result<InsertInfo, GridError> {
        let beams: Vec<Beam> = ends
            .iter()
            .zip(hit.iter().chain(core::iter::repeat(&true)))
            .map(|(&end, &hit)| Beam { end, hit })
            .collect();
        self.insert_beams(origin, &beams, model)
    }

    fn insert_beams(
        &mut self,
        origin: &Point2,
        beams: &[Beam],
        model: &SensorModel,
    ) -> Result<InsertInfo, GridError> {
        let mut info = InsertInfo::default();
        if beams.is_empty() {
            return Ok(info);
        }
        // 1. Grow to the bounding box of the sensor and every beam end.
        let Some((lo, hi)) = beams_box(origin, beams) else {
            return Ok(info);
        };
        self.grow_to_contain(&lo, &hi)?;
        let generation = self.next_generation();
        let geometry = *self.geometry();
        let (log_odds, marks) = self.cells_and_marks();
        let width = geometry.width;
        let to_local = |p: &Point2| (p - geometry.origin_m) / geometry.resolution_m;
        // 2. Hits first, so the misses of neighbouring beams cannot erase them.
        for beam in beams.iter().filter(|b| b.hit) {
            let cell = geometry.cell_of(&beam.end);
            if let Some(index) = geometry.index_of(cell) {
                if let (Some(l), Some(mark)) = (log_odds.get_mut(index), marks.get_mut(index)) {
                    *l = (*l + model.hit_log_odds).clamp(model.min_log_odds, model.max_log_odds);
                    *mark = generation;
                }
                info.hits += 1;
                info.cells_visited += 1;
            }
        }
        // 3. Misses along every beam, the end cell excluded for hits.
        let start = to_local(origin);
        for beam in beams {
            if !beam.hit {
                info.free_only += 1;
            }
            let end = to_local(&beam.end);
            info.cells_visited += traverse(start, end, width, beam.hit, |index| {
                if let (Some(l), Some(mark)) = (log_odds.get_mut(index), marks.get_mut(index)) {
                    if *mark != generation {
                        *mark = generation;
                        *l = (*l + model.miss_log_odds)
                            .clamp(model.min_log_odds, model.max_log_odds);
                    }
                }
            });
        }
        Ok(info)
    }
}

/// Visits the row-major indices of the cells the segment `start → end` (in cell units, both
/// inside a grid `width` wide) passes through, from the start cell on. The end cell is
/// visited unless `skip_end`. Returns the number of cells visited.
///
/// [`traverse_cells`] with the cells given as row-major indices.
pub fn traverse(
    start: Point2,
    end: Point2,
    width: usize,
    skip_end: bool,
    mut visit: impl FnMut(usize),
) -> usize {
    let width = width as i64;
    traverse_cells(start, end, skip_end, |x, y| visit((y * width + x) as usize))
}

/// Visits the cells `(x, y)` the segment `start → end` (in cell units, both at non-negative
/// coordinates) passes through, from the start cell on. The end cell is visited unless
/// `skip_end`. Returns the number of cells visited. (For storage laid out other than row by
/// row, e.g. in tiles.)
///
/// Amanatides & Woo's traversal, stepping exactly `|Δx| + |Δy|` times between the end cells so
/// rounding can never overshoot; where the segment crosses a cell corner exactly, one of the
/// two side cells is visited.
pub fn traverse_cells(
    start: Point2,
    end: Point2,
    skip_end: bool,
    mut visit: impl FnMut(i64, i64),
) -> usize {
    let (mut x, mut y) = (start.x.floor() as i64, start.y.floor() as i64);
    let (ex, ey) = (end.x.floor() as i64, end.y.floor() as i64);
    let delta = end - start;
    let step_x: i64 = (ex - x).signum();
    let step_y: i64 = (ey - y).signum();
    // Parameter t ∈ [0, 1] along the segment at which the next x / y cell border is crossed.
    let boundary = |c: i64, step: i64| if step > 0 { (c + 1) as f64 } else { c as f64 };
    let mut t_max_x = if step_x != 0 {
        (boundary(x, step_x) - start.x) / delta.x
    } else {
        f64::INFINITY
    };
    let mut t_max_y = if step_y != 0 {
        (boundary(y, step_y) - start.y) / delta.y
    } else {
        f64::INFINITY
    };
    let t_delta_x = if step_x != 0 {
        (1.0 / delta.x).abs()
    } else {
        f64::INFINITY
    };
    let t_delta_y = if step_y != 0 {
        (1.0 / delta.y).abs()
    } else {
        f64::INFINITY
    };
    let mut remaining_x = (ex - x).unsigned_abs();
    let mut remaining_y = (ey - y).unsigned_abs();
    let steps = remaining_x + remaining_y;
    for _ in 0..steps {
        visit(x, y);
        // Take the nearer border; once an axis has reached the end column/row, only the
        // other one may step.
        if remaining_y == 0 || (remaining_x > 0 && t_max_x < t_max_y) {
            x += step_x;
            t_max_x += t_delta_x;
            remaining_x -= 1;
        } else {
            y += step_y;
            t_max_y += t_delta_y;
            remaining_y -= 1;
        }
    }
    if skip_end {
        steps as usize
    } else {
        visit(x, y);
        steps as usize + 1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::collections::BTreeSet;

    /// Cells whose open interior the segment crosses with positive length (Liang–Barsky
    /// clipping against every cell of the bounding box), plus the two end cells.
    fn brute_force(start: Point2, end: Point2, width: usize) -> BTreeSet<usize> {
        let mut out = BTreeSet::new();
        let (x0, x1) = (
            start.x.min(end.x).floor() as i64,
            start.x.max(end.x).floor() as i64,
        );
        let (y0, y1) = (
            start.y.min(end.y).floor() as i64,
            start.y.max(end.y).floor() as i64,
        );
        let d = end - start;
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (mut t0, mut t1) = (0.0f64, 1.0f64);
                let mut inside = true;
                for (p, q) in [
                    (-d.x, start.x - x as f64),
                    (d.x, (x + 1) as f64 - start.x),
                    (-d.y, start.y - y as f64),
                    (d.y, (y + 1) as f64 - start.y),
                ] {
                    if p == 0.0 {
                        if q < 0.0 {
                            inside = false;
                        }
                    } else {
                        let r = q / p;
                        if p < 0.0 {
                            t0 = t0.max(r);
                        } else {
                            t1 = t1.min(r);
                        }
                    }
                }
                if inside && t1 - t0 > 1e-9 {
                    out.insert((y * width as i64 + x) as usize);
                }
            }
        }
        for p in [start, end] {
            out.insert((p.y.floor() as i64 * width as i64 + p.x.floor() as i64) as usize);
        }
        out
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]
        #[test]
        fn traversal_equals_brute_force(sx in 0.0..64.0f64, sy in 0.0..64.0f64, ex in 0.0..64.0f64, ey in 0.0..64.0f64) {
            let (start, end) = (Point2::new(sx, sy), Point2::new(ex, ey));
            let mut visited = Vec::new();
            let count = traverse(start, end, 64, false, |i| visited.push(i));
            prop_assert_eq!(count, visited.len());
            let as_set: BTreeSet<usize> = visited.iter().copied().collect();
            prop_assert_eq!(as_set.len(), visited.len(), "a cell was visited twice");
            prop_assert_eq!(as_set, brute_force(start, end, 64));
            // The visit order is a 4-connected path.
            for pair in visited.windows(2) {
                let (a, b) = (pair[0] as i64, pair[1] as i64);
                prop_assert!((a - b).abs() == 1 || (a - b).abs() == 64);
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]
        /// A grid sized once (`from_posed_scans`) takes the geometry scan-by-scan growth
        /// reaches and the same cells, but where a point rounds to the other side of a cell
        /// boundary against another origin while inserting.
        #[test]
        fn a_grid_sized_once_is_the_grid_grown_scan_by_scan(
            poses in prop::collection::vec((-20.0..20.0f64, -20.0..20.0f64, -3.2..3.2f64), 1..10),
            range_m in 0.5..12.0f32,
            seed in 0u64..1000,
        ) {
            let scans: Vec<LaserScan> = (0..poses.len() as u64)
                .map(|k| {
                    let ranges = (0..91u64)
                        .map(|i| {
                            let wobble = ((i * 7919 + seed + k * 31) % 97) as f32 / 97.0;
                            // Some beams beyond the range limit: no return, free space only.
                            range_m * (1.0 + 3.0 * wobble)
                        })
                        .collect();
                    LaserScan::new(-90f64.to_radians(), 90f64.to_radians(), 30.0, ranges)
                })
                .collect();
            let posed: Vec<(Se2, &LaserScan)> = poses
                .iter()
                .zip(&scans)
                .map(|(&(x, y, t), scan)| (Se2::new(x, y, t), scan))
                .collect();
            let params = InsertParams::default();
            let mut calls = 0;
            let (sized, info) =
                OccupancyGrid::from_posed_scans(0.05, &posed, &params, || calls += 1).unwrap();
            prop_assert_eq!(calls, posed.len());
            let mut grown = OccupancyGrid::new(0.05).unwrap();
            let mut grown_info = InsertInfo::default();
            for (pose, scan) in &posed {
                grown_info.accumulate(&grown.insert_scan(pose, scan, &params).unwrap());
            }
            prop_assert_eq!(sized.geometry(), grown.geometry());
            prop_assert_eq!(info.hits, grown_info.hits);
            let differ = sized
                .log_odds()
                .iter()
                .zip(grown.log_odds())
                .filter(|(a, b)| a != b)
                .count();
            let known = grown.log_odds().iter().filter(|l| **l != 0.0).count();
            prop_assert!(known > 0);
            prop_assert!(differ * 1000 <= known, "{} of {} known cells differ", differ, known);
        }
    }

    #[test]
    fn axis_aligned_and_single_cell_rays() {
        let mut v = Vec::new();
        traverse(
            Point2::new(0.5, 0.5),
            Point2::new(3.5, 0.5),
            10,
            false,
            |i| v.push(i),
        );
        assert_eq!(v, [0, 1, 2, 3]);
        v.clear();
        traverse(
            Point2::new(2.5, 3.5),
            Point2::new(2.5, 0.2),
            10,
            true,
            |i| v.push(i),
        );
        assert_eq!(v, [32, 22, 12]);
        v.clear();
        traverse(
            Point2::new(1.2, 1.2),
            Point2::new(1.7, 1.9),
            10,
            false,
            |i| v.push(i),
        );
        assert_eq!(v, [11]);
    }

    #[test]
    fn a_scan_marks_free_space_and_walls() {
        // A wall 2.02 m in front of the robot, 61 beams over ±30°.
        let n = 61;
        let first = -30f64.to_radians();
        let ranges = (0..n)
            .map(|i| {
                let angle = first + i as f64 * 1f64.to_radians();
                (2.02 / angle.cos()) as f32
            })
            .collect();
        let scan = LaserScan::new(first, 30f64.to_radians(), 30.0, ranges);
        let mut grid = OccupancyGrid::new(0.05).unwrap();
        let info = grid
            .insert_scan(&Se2::new(0.0, 0.0, 0.0), &scan, &InsertParams::default())
            .unwrap();
        assert_eq!(info.hits, n);
        let thresholds = crate::ClassThresholds::default();
        let class_at = |grid: &OccupancyGrid, x: f64, y: f64| {
            grid.class(grid.geometry().cell_of(&Point2::new(x, y)), &thresholds)
        };
        assert_eq!(class_at(&grid, 2.02, 0.0), crate::CellClass::Occupied);
        assert_eq!(class_at(&grid, 2.02, 1.02), crate::CellClass::Occupied);
        assert_eq!(class_at(&grid, -1.0, 0.0), crate::CellClass::Unknown);
        // One miss (p = 0.4) is not yet free with the default thresholds; a second scan is.
        grid.insert_scan(&Se2::new(0.0, 0.0, 0.0), &scan, &InsertParams::default())
            .unwrap();
        assert_eq!(class_at(&grid, 1.0, 0.0), crate::CellClass::Free);
        assert_eq!(class_at(&grid, 2.02, 0.5), crate::CellClass::Occupied);
    }
}
