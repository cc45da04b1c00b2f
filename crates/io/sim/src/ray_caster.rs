//! Fast queries against a world's segments: a uniform grid of cells, each listing the segments
//! whose bounding box touches it. A ray walks the cells it crosses (Amanatides & Woo 1987,
//! "A fast voxel traversal algorithm for ray tracing") and tests only their segments, stopping
//! at the first cell whose exit lies beyond the nearest hit found so far.

use crate::shapes::{point_segment_distance, segment_segment_distance, segments_intersect};
use crate::{LineSegment, Point2, World};

/// Default cell side of the index (m): about one room-wall spacing in a corridor, so a beam
/// crosses few cells and each cell holds few segments.
pub const DEFAULT_CELL_M: f64 = 1.0;

/// Segments are registered in every cell their box touches, grown by this much (m), so a
/// segment lying on a cell border is found from both sides.
const REGISTER_MARGIN_M: f64 = 1e-6;

/// A segment stored as start point and direction (`end = start + dir`).
#[derive(Clone, Copy, Debug)]
struct IndexedSegment {
    start_x: f64,
    start_y: f64,
    dir_x: f64,
    dir_y: f64,
}

/// A uniform spatial hash of a world's obstacle boundaries, for ray casting (the lidar) and
/// clearance checks (the planner, the robot's safety stop). Built once per world; cheap to
/// query from many threads.
#[derive(Clone, Debug)]
pub struct RayCaster {
    origin_m: Point2,
    cell_m: f64,
    inv_cell: f64,
    columns: usize,
    rows: usize,
    /// `cell_start[c]..cell_start[c + 1]` indexes `cell_items` for cell `c` (row-major).
    cell_start: Vec<u32>,
    cell_items: Vec<u32>,
    segments: Vec<IndexedSegment>,
}

impl RayCaster {
    /// The index of `world`'s segments with cells of [`DEFAULT_CELL_M`].
    pub fn new(world: &World) -> Self {
        Self::from_segments(&world.segments(), DEFAULT_CELL_M)
    }

    /// The index of arbitrary segments with cells of `cell_m` (clamped to at least 5 cm).
    pub fn from_segments(segments: &[LineSegment], cell_m: f64) -> Self {
        let cell_m = if cell_m.is_finite() {
            cell_m.max(0.05)
        } else {
            DEFAULT_CELL_M
        };
        let finite: Vec<&LineSegment> = segments
            .iter()
            .filter(|s| {
                s.start_m
                    .iter()
                    .chain(s.end_m.iter())
                    .all(|v| v.is_finite())
            })
            .collect();
        let mut min = Point2::new(0.0, 0.0);
        let mut max = Point2::new(1.0, 1.0);
        if let Some(first) = finite.first() {
            min = first.start_m;
            max = first.start_m;
        }
        for s in &finite {
            min = min.inf(&s.start_m).inf(&s.end_m);
            max = max.sup(&s.start_m).sup(&s.end_m);
        }
        // One spare cell on every side keeps every registered box strictly inside.
        let origin_m = min - Point2::new(cell_m, cell_m);
        let columns = (((max.x - origin_m.x) / cell_m).ceil() as usize + 1).max(1);
        let rows = (((max.y - origin_m.y) / cell_m).ceil() as usize + 1).max(1);
        let mut caster = Self {
            origin_m,
            cell_m,
            inv_cell: 1.0 / cell_m,
            columns,
            rows,
            cell_start: Vec::new(),
            cell_items: Vec::new(),
            segments: finite
                .iter()
                .map(|s| IndexedSegment {
                    start_x: s.start_m.x,
                    start_y: s.start_m.y,
                    dir_x: s.end_m.x - s.start_m.x,
                    dir_y: s.end_m.y - s.start_m.y,
                })
                .collect(),
        };
        // Counting sort into compressed rows: count, prefix-sum, fill.
        let mut counts = vec![0u32; columns * rows + 1];
        for s in &finite {
            caster.for_each_cell_of_box(&s.start_m, &s.end_m, REGISTER_MARGIN_M, |cell| {
                counts[cell] += 1
            });
        }
        let mut start = Vec::with_capacity(counts.len());
        let mut total = 0u32;
        for count in &counts {
            start.push(total);
            total += count;
        }
        let mut fill = start.clone();
        let mut items = vec![0u32; total as usize];
        for (index, s) in finite.iter().enumerate() {
            caster.for_each_cell_of_box(&s.start_m, &s.end_m, REGISTER_MARGIN_M, |cell| {
                items[fill[cell] as usize] = index as u32;
                fill[cell] += 1;
            });
        }
        caster.cell_start = start;
        caster.cell_items = items;
        caster
    }

    /// Number of indexed segments.
    pub fn segment_count(&self) -> usize {
        self.segments.len()
    }

    /// Distance (m) from `origin_m` along `angle_rad` (world frame) to the first segment hit,
    /// or `None` when nothing lies within `max_range_m`.
    pub fn cast(&self, origin_m: &Point2, angle_rad: f64, max_range_m: f64) -> Option<f64> {
        let (s, c) = angle_rad.sin_cos();
        let t = self.cast_direction(origin_m.x, origin_m.y, c, s, max_range_m);
        t.is_finite().then_some(t)
    }

    /// Distance along the unit direction `(dir_x, dir_y)` to the first hit, `f64::INFINITY`
    /// when nothing lies within `max_range_m`.
    pub(crate) fn cast_direction(
        &self,
        origin_x: f64,
        origin_y: f64,
        dir_x: f64,
        dir_y: f64,
        max_range_m: f64,
    ) -> f64 {
        // Clip the ray to the grid's box (slab method).
        let (grid_min, grid_max) = self.grid_box();
        let mut t_start = 0.0f64;
        let mut t_end = max_range_m;
        for (origin, dir, lo, hi) in [
            (origin_x, dir_x, grid_min.x, grid_max.x),
            (origin_y, dir_y, grid_min.y, grid_max.y),
        ] {
            if dir.abs() < 1e-300 {
                if origin < lo || origin > hi {
                    return f64::INFINITY;
                }
            } else {
                let ta = (lo - origin) / dir;
                let tb = (hi - origin) / dir;
                t_start = t_start.max(ta.min(tb));
                t_end = t_end.min(ta.max(tb));
            }
        }
        // Also catches NaN (a non-finite origin or direction).
        if t_start.partial_cmp(&t_end) != Some(std::cmp::Ordering::Less) && t_start != t_end {
            return f64::INFINITY;
        }
        let enter_x = origin_x + dir_x * t_start;
        let enter_y = origin_y + dir_y * t_start;
        let mut column = self.clamped_column(enter_x);
        let mut row = self.clamped_row(enter_y);
        let (step_column, delta_x, mut next_x) =
            axis_setup(origin_x, dir_x, self.origin_m.x, self.cell_m, column);
        let (step_row, delta_y, mut next_y) =
            axis_setup(origin_y, dir_y, self.origin_m.y, self.cell_m, row);
        let mut best = f64::INFINITY;
        loop {
            let cell = row * self.columns + column;
            let (from, to) = (
                self.cell_start[cell] as usize,
                self.cell_start[cell + 1] as usize,
            );
            for &index in &self.cell_items[from..to] {
                let s = &self.segments[index as usize];
                // Ray o + t·d against segment a + u·e: t = (a−o)×e / d×e, u = (a−o)×d / d×e.
                let denom = dir_x * s.dir_y - dir_y * s.dir_x;
                if denom.abs() < 1e-12 {
                    continue;
                }
                let ax = s.start_x - origin_x;
                let ay = s.start_y - origin_y;
                let t = (ax * s.dir_y - ay * s.dir_x) / denom;
                let u = (ax * dir_y - ay * dir_x) / denom;
                if t >= 0.0 && t < best && (0.0..=1.0).contains(&u) {
                    best = t;
                }
            }
            let t_exit = next_x.min(next_y);
            if best <= t_exit || t_exit >= t_end {
                return if best <= max_range_m {
                    best
                } else {
                    f64::INFINITY
                };
            }
            if next_x < next_y {
                if step_column < 0 {
                    if column == 0 {
                        break;
                    }
                    column -= 1;
                } else {
                    column += 1;
                    if column >= self.columns {
                        break;
                    }
                }
                next_x += delta_x;
            } else {
                if step_row < 0 {
                    if row == 0 {
                        break;
                    }
                    row -= 1;
                } else {
                    row += 1;
                    if row >= self.rows {
                        break;
                    }
                }
                next_y += delta_y;
            }
        }
        if best <= max_range_m {
            best
        } else {
            f64::INFINITY
        }
    }

    /// True when the straight move from `from_m` to `to_m` touches no segment.
    pub fn is_path_free(&self, from_m: &Point2, to_m: &Point2) -> bool {
        let mut free = true;
        self.for_each_candidate(from_m, to_m, REGISTER_MARGIN_M, |s| {
            let start = Point2::new(s.start_x, s.start_y);
            let end = Point2::new(s.start_x + s.dir_x, s.start_y + s.dir_y);
            if segments_intersect(from_m, to_m, &start, &end) {
                free = false;
            }
            free
        });
        free
    }

    /// True when every point of the segment `[from_m, to_m]` stays at least `clearance_m`
    /// from every indexed segment.
    pub fn is_clear(&self, from_m: &Point2, to_m: &Point2, clearance_m: f64) -> bool {
        let mut clear = true;
        self.for_each_candidate(from_m, to_m, clearance_m + REGISTER_MARGIN_M, |s| {
            let start = Point2::new(s.start_x, s.start_y);
            let end = Point2::new(s.start_x + s.dir_x, s.start_y + s.dir_y);
            if segment_segment_distance(from_m, to_m, &start, &end) < clearance_m {
                clear = false;
            }
            clear
        });
        clear
    }

    /// Distance from `p_m` to the nearest segment, or `search_radius_m` when none is closer.
    pub fn clearance_m(&self, p_m: &Point2, search_radius_m: f64) -> f64 {
        let mut nearest = search_radius_m;
        self.for_each_candidate(p_m, p_m, search_radius_m, |s| {
            let start = Point2::new(s.start_x, s.start_y);
            let end = Point2::new(s.start_x + s.dir_x, s.start_y + s.dir_y);
            nearest = nearest.min(point_segment_distance(p_m, &start, &end));
            true
        });
        nearest
    }

    /// Calls `visit` for every segment registered in a cell touching the box of `[a, b]` grown
    /// by `margin_m` (a segment may come more than once) until it returns false.
    fn for_each_candidate(
        &self,
        a: &Point2,
        b: &Point2,
        margin_m: f64,
        mut visit: impl FnMut(&IndexedSegment) -> bool,
    ) {
        if !(a.iter().chain(b.iter()).all(|v| v.is_finite()) && margin_m.is_finite()) {
            return;
        }
        let (c0, r0) = (
            self.clamped_column(a.x.min(b.x) - margin_m),
            self.clamped_row(a.y.min(b.y) - margin_m),
        );
        let (c1, r1) = (
            self.clamped_column(a.x.max(b.x) + margin_m),
            self.clamped_row(a.y.max(b.y) + margin_m),
        );
        for row in r0..=r1 {
            for column in c0..=c1 {
                let cell = row * self.columns + column;
                let (from, to) = (
                    self.cell_start[cell] as usize,
                    self.cell_start[cell + 1] as usize,
                );
                for &index in &self.cell_items[from..to] {
                    if !visit(&self.segments[index as usize]) {
                        return;
                    }
                }
            }
        }
    }

    fn for_each_cell_of_box(
        &self,
        a: &Point2,
        b: &Point2,
        margin_m: f64,
        mut visit: impl FnMut(usize),
    ) {
        let (c0, r0) = (
            self.clamped_column(a.x.min(b.x) - margin_m),
            self.clamped_row(a.y.min(b.y) - margin_m),
        );
        let (c1, r1) = (
            self.clamped_column(a.x.max(b.x) + margin_m),
            self.clamped_row(a.y.max(b.y) + margin_m),
        );
        for row in r0..=r1 {
            for column in c0..=c1 {
                visit(row * self.columns + column);
            }
        }
    }

    fn grid_box(&self) -> (Point2, Point2) {
        let size = Point2::new(self.columns as f64, self.rows as f64) * self.cell_m;
        (self.origin_m, self.origin_m + size)
    }

    fn clamped_column(&self, x_m: f64) -> usize {
        let column = ((x_m - self.origin_m.x) * self.inv_cell).floor();
        column.clamp(0.0, (self.columns - 1) as f64) as usize
    }

    fn clamped_row(&self, y_m: f64) -> usize {
        let row = ((y_m - self.origin_m.y) * self.inv_cell).floor();
        row.clamp(0.0, (self.rows - 1) as f64) as usize
    }
}

/// Amanatides & Woo's per-axis setup: step direction, ray length per cell, and the ray
/// parameter at the first cell border crossed.
fn axis_setup(
    origin: f64,
    dir: f64,
    grid_origin: f64,
    cell_m: f64,
    cell: usize,
) -> (i64, f64, f64) {
    if dir > 0.0 {
        let border = grid_origin + (cell + 1) as f64 * cell_m;
        (1, cell_m / dir, (border - origin) / dir)
    } else if dir < 0.0 {
        let border = grid_origin + cell as f64 * cell_m;
        (-1, -cell_m / dir, (border - origin) / dir)
    } else {
        (0, f64::INFINITY, f64::INFINITY)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn square_room() -> Vec<LineSegment> {
        let c = [
            Point2::new(0.0, 0.0),
            Point2::new(4.0, 0.0),
            Point2::new(4.0, 4.0),
            Point2::new(0.0, 4.0),
        ];
        (0..4)
            .map(|i| LineSegment::new(c[i], c[(i + 1) % 4]))
            .collect()
    }

    #[test]
    fn rays_from_the_centre_of_a_square() {
        for cell_m in [0.3, 1.0, 7.0] {
            let caster = RayCaster::from_segments(&square_room(), cell_m);
            let centre = Point2::new(2.0, 2.0);
            for i in 0..72 {
                let angle = -PI + i as f64 * 2.0 * PI / 72.0;
                let folded = (angle.rem_euclid(PI / 2.0) - PI / 4.0).abs();
                let expected = 2.0 / (PI / 4.0 - folded).cos();
                let got = caster.cast(&centre, angle, 30.0).unwrap();
                assert!(
                    (got - expected).abs() < 1e-9,
                    "cell {cell_m} angle {angle}: {got} vs {expected}"
                );
            }
            assert_eq!(caster.cast(&centre, 0.0, 1.5), None);
        }
    }

    #[test]
    fn rays_from_outside_the_grid_and_clearance() {
        let caster = RayCaster::from_segments(&square_room(), 1.0);
        let got = caster.cast(&Point2::new(-10.0, 2.0), 0.0, 30.0).unwrap();
        assert!((got - 10.0).abs() < 1e-9);
        assert_eq!(caster.cast(&Point2::new(-10.0, 2.0), PI, 30.0), None);
        let centre = Point2::new(2.0, 2.0);
        assert!((caster.clearance_m(&centre, 5.0) - 2.0).abs() < 1e-12);
        assert!(caster.is_clear(&centre, &Point2::new(3.0, 2.0), 0.9));
        assert!(!caster.is_clear(&centre, &Point2::new(3.5, 2.0), 0.9));
        assert!(caster.is_path_free(&centre, &Point2::new(3.9, 3.9)));
        assert!(!caster.is_path_free(&centre, &Point2::new(4.5, 2.0)));
    }
}
