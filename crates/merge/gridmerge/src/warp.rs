//! Resampling map B through `a_from_b` onto A's cells (Andersone, Sec. 4.1: "a map resolution
//! transformation was performed before the merging"), in one pass for any resolution ratio
//! and rotation.
//!
//! Every target cell is sampled on a regular `k × k` sub-grid, `k = ⌈res_a / res_b⌉`, so the
//! samples are never further apart than B's cells and no target cell is left out (no holes):
//! * A finer than or as fine as B (`k = 1`): nearest neighbour at the cell centre;
//! * A coarser: the samples are combined as [`mapmerge_grid::OccupancyGrid::resample`]
//!   combines cells — the strongest occupied evidence if any sample has some (thin walls
//!   survive coarsening), else the mean of the observed samples, unknown when fewer than half
//!   of the samples are observed.

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{Cell, GridGeometry, OccupancyGrid, Point2};

use crate::quality::{QualityMap, NO_ESTIMATE};
use crate::MergeError;

/// Largest `k` (samples per axis per target cell): a 64:1 coarsening samples 4096 times.
const MAX_SAMPLES_PER_AXIS: usize = 64;

/// Side of the square tiles the target is visited in (cells).
const TILE_CELLS: usize = 32;

/// The smallest box of cells holding every observed (non-zero) cell, `None` if there is none.
pub(crate) fn known_bounds(grid: &OccupancyGrid) -> Option<(Cell, Cell)> {
    let width = grid.geometry().width;
    if width == 0 {
        return None;
    }
    let mut bounds: Option<(Cell, Cell)> = None;
    for (y, row) in grid.log_odds().chunks_exact(width).enumerate() {
        let first = row.iter().position(|&l| l != 0.0);
        let last = row.iter().rposition(|&l| l != 0.0);
        if let (Some(first), Some(last)) = (first, last) {
            let (lo, hi) = (
                Cell::new(first as i64, y as i64),
                Cell::new(last as i64, y as i64),
            );
            bounds = Some(match bounds {
                None => (lo, hi),
                Some((l, h)) => (
                    Cell::new(l.x.min(lo.x), l.y.min(lo.y)),
                    Cell::new(h.x.max(hi.x), h.y.max(hi.y)),
                ),
            });
        }
    }
    bounds
}

/// The axis-aligned box (in A's frame, m) covering B's cells `lo..=hi` after `a_from_b`.
pub(crate) fn footprint_in_a(
    b: &GridGeometry,
    lo: Cell,
    hi: Cell,
    a_from_b: &Se2,
) -> (Point2, Point2) {
    let r = b.resolution_m;
    let min = b.origin_m + Point2::new(lo.x as f64, lo.y as f64) * r;
    let max = b.origin_m + Point2::new((hi.x + 1) as f64, (hi.y + 1) as f64) * r;
    let corners = [
        min,
        Point2::new(max.x, min.y),
        max,
        Point2::new(min.x, max.y),
    ];
    let mut lo_a = a_from_b.transform_point(&min);
    let mut hi_a = lo_a;
    for c in &corners {
        let p = a_from_b.transform_point(c);
        lo_a = lo_a.inf(&p);
        hi_a = hi_a.sup(&p);
    }
    (lo_a, hi_a)
}

pub(crate) fn check_transform(a_from_b: &Se2) -> Result<(), MergeError> {
    if a_from_b.x_m.is_finite() && a_from_b.y_m.is_finite() && a_from_b.theta_rad.is_finite() {
        Ok(())
    } else {
        Err(MergeError::NotFiniteTransform {
            x_m: a_from_b.x_m,
            y_m: a_from_b.y_m,
            yaw_rad: a_from_b.theta_rad,
        })
    }
}

/// One sampled cell of B on the target grid.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sample {
    /// Row-major index in the target grid.
    pub index: usize,
    /// Target column and row.
    pub x: usize,
    pub y: usize,
    /// B's log-odds there (never 0: unknown cells are not visited).
    pub value: f32,
    /// B's block quality at the cell's centre ([`NO_ESTIMATE`] if none or not asked for).
    pub quality: f32,
}

/// Samples per axis per target cell for these resolutions (see the module doc).
pub(crate) fn samples_per_axis(target_resolution_m: f64, b_resolution_m: f64) -> usize {
    let ratio = target_resolution_m / b_resolution_m;
    // Tolerate rounding in equal resolutions (0.1 / 0.1 · (1 + ε) must stay 1 sample).
    ((ratio - 1e-9).ceil().max(1.0) as usize).min(MAX_SAMPLES_PER_AXIS)
}

/// Samples `b` (through `a_from_b`) on the cells of `target` that B's observed box
/// `b_known` can reach, calling `visit` for every cell where B has evidence, tile by tile.
/// Allocation-free apart from the `k²` sample offsets.
pub(crate) fn sample_into(
    target: &GridGeometry,
    b: &OccupancyGrid,
    b_known: Option<(Cell, Cell)>,
    a_from_b: &Se2,
    b_quality: Option<&QualityMap>,
    mut visit: impl FnMut(Sample),
) {
    let k = samples_per_axis(target.resolution_m, b.resolution_m());
    let Some((lo, hi)) = b_known else {
        return;
    };
    // 1. The window: target cells overlapping B's observed box, one cell of margin.
    let (lo_a, hi_a) = footprint_in_a(b.geometry(), lo, hi, a_from_b);
    let (c_lo, c_hi) = (target.cell_of(&lo_a), target.cell_of(&hi_a));
    let (tw, th) = (target.width as i64, target.height as i64);
    let x0 = c_lo.x.saturating_sub(1).clamp(0, tw);
    let y0 = c_lo.y.saturating_sub(1).clamp(0, th);
    let x1 = c_hi.x.saturating_add(2).clamp(0, tw);
    let y1 = c_hi.y.saturating_add(2).clamp(0, th);
    if x1 <= x0 || y1 <= y0 {
        return;
    }
    let (x0, y0) = (x0 as usize, y0 as usize);
    let (width, height) = (x1 as usize - x0, y1 as usize - y0);

    // 2. B's continuous cell coordinates are affine in the target's: for target coordinates
    //    (u, v) in cells, uv_b = c0 + u·du + v·dv.
    let b_from_a = a_from_b.inverse();
    let rotation = b_from_a.rotation_matrix();
    let bg = *b.geometry();
    let scale = target.resolution_m / bg.resolution_m;
    let du = rotation.column(0) * scale;
    let dv = rotation.column(1) * scale;
    let c0 = (b_from_a.transform_point(&target.origin_m) - bg.origin_m) / bg.resolution_m;
    let (bw, bh) = (bg.width as f64, bg.height as f64);
    let b_cells = b.log_odds();
    // B's cell at continuous cell coordinates p, if inside. Truncation is floor for p ≥ 0 and
    // avoids a libm call per sample.
    let at = |p: nalgebra::Vector2<f64>| -> Option<(usize, usize, f32)> {
        if !(p.x >= 0.0 && p.y >= 0.0 && p.x < bw && p.y < bh) {
            return None;
        }
        let (x, y) = (p.x as usize, p.y as usize);
        b_cells.get(y * bg.width + x).map(|&l| (x, y, l))
    };
    let offsets: Vec<nalgebra::Vector2<f64>> = (0..k * k)
        .map(|i| {
            let (fx, fy) = ((i % k) as f64 + 0.5, (i / k) as f64 + 0.5);
            du * (fx / k as f64) + dv * (fy / k as f64)
        })
        .collect();
    let half_samples = (k * k).div_ceil(2);
    let centre = (du + dv) * 0.5;

    // 3. Sample every window cell: its corner in B's cell coordinates is
    //    c0 + x·du + y·dv, the samples sit at fixed offsets from it.
    //    Only the span of each row whose samples can reach B's observed box is visited;
    //    the rest of the window stays unknown.
    let reach = (du.abs() + dv.abs()) * 0.5 + nalgebra::Vector2::repeat(1e-6);
    let box_lo = nalgebra::Vector2::new(lo.x as f64, lo.y as f64) - reach;
    let box_hi = nalgebra::Vector2::new((hi.x + 1) as f64, (hi.y + 1) as f64) + reach;
    // Square tiles keep B's cells of neighbouring samples in cache under rotation.
    for tile_y in (0..height).step_by(TILE_CELLS) {
        for tile_x in (0..width).step_by(TILE_CELLS) {
            let tile_end_x = (tile_x + TILE_CELLS).min(width);
            for wy in tile_y..(tile_y + TILE_CELLS).min(height) {
                let y = y0 + wy;
                let row_start = c0 + du * (x0 as f64) + dv * (y as f64);
                let Some((first, last)) = span(&(row_start + centre), &du, &box_lo, &box_hi, width)
                else {
                    continue;
                };
                let (first, last) = (first.max(tile_x), last.min(tile_end_x));
                for wx in first..last {
                    let corner = row_start + du * (wx as f64);
                    let value = if k == 1 {
                        at(corner + centre).map_or(0.0, |(_, _, l)| l)
                    } else {
                        let (mut strongest, mut known, mut sum) = (0.0f32, 0usize, 0.0f64);
                        for offset in &offsets {
                            if let Some((_, _, l)) = at(corner + offset) {
                                if l != 0.0 {
                                    strongest = strongest.max(l);
                                    known += 1;
                                    sum += f64::from(l);
                                }
                            }
                        }
                        if strongest > 0.0 {
                            strongest
                        } else if known > 0 && known >= half_samples {
                            (sum / known as f64) as f32
                        } else {
                            0.0
                        }
                    };
                    if value == 0.0 {
                        continue;
                    }
                    let quality = match (b_quality, at(corner + centre)) {
                        (Some(q), Some((bx, by, _))) => q.raw_at(bx as i64, by as i64),
                        _ => NO_ESTIMATE,
                    };
                    let x = x0 + wx;
                    visit(Sample {
                        index: y * target.width + x,
                        x,
                        y,
                        value,
                        quality,
                    });
                }
            }
        }
    }
}

/// The range `first..last` of `i` in `0..width` for which `start + step·i` may lie in the box
/// `[lo, hi]` (a superset: one cell of slack on each side), `None` if empty.
fn span(
    start: &nalgebra::Vector2<f64>,
    step: &nalgebra::Vector2<f64>,
    lo: &nalgebra::Vector2<f64>,
    hi: &nalgebra::Vector2<f64>,
    width: usize,
) -> Option<(usize, usize)> {
    let (mut from, mut to) = (0.0f64, width as f64);
    for axis in 0..2 {
        let (a, b) = (start[axis], step[axis]);
        let (l, h) = (lo[axis], hi[axis]);
        if b.abs() < 1e-12 {
            if a < l || a > h {
                return None;
            }
            continue;
        }
        let (t0, t1) = ((l - a) / b, (h - a) / b);
        from = from.max(t0.min(t1) - 1.0);
        to = to.min(t0.max(t1) + 1.0);
    }
    if !(from.is_finite() && to.is_finite()) || to <= from {
        return None;
    }
    let first = from.floor().max(0.0) as usize;
    let last = (to.ceil().max(0.0) as usize).min(width);
    (first < last).then_some((first, last))
}

/// Map `b` seen in A's frame: its values resampled through `a_from_b` onto the cells of
/// `target` (a geometry in A's frame, usually A's own or the merged map's); cells B does not
/// reach are unknown. See the module doc for how resolutions are handled.
pub fn resample_into(
    b: &OccupancyGrid,
    a_from_b: &Se2,
    target: &GridGeometry,
) -> Result<OccupancyGrid, MergeError> {
    check_transform(a_from_b)?;
    let mut out = OccupancyGrid::with_geometry(*target)?;
    let cells = out.log_odds_mut();
    sample_into(target, b, known_bounds(b), a_from_b, None, |sample| {
        if let Some(cell) = cells.get_mut(sample.index) {
            *cell = sample.value;
        }
    });
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geometry(resolution_m: f64, x: f64, y: f64, width: usize, height: usize) -> GridGeometry {
        GridGeometry {
            resolution_m,
            origin_m: Point2::new(x, y),
            width,
            height,
        }
    }

    #[test]
    fn equal_aligned_grids_copy_exactly() {
        let g = geometry(0.1, -1.0, -1.0, 20, 10);
        let values: Vec<f32> = (0..200).map(|i| (i % 7) as f32 - 3.0).collect();
        let b = OccupancyGrid::from_log_odds(g, values).unwrap();
        let out = resample_into(&b, &Se2::new(0.0, 0.0, 0.0), &g).unwrap();
        assert_eq!(out, b);
        // Shifted by whole cells: the values shift with it.
        let out = resample_into(
            &b,
            &Se2::new(0.3, -0.2, 0.0),
            &geometry(0.1, -1.0, -1.0, 30, 30),
        )
        .unwrap();
        let c = Cell::new(4, 5);
        assert_eq!(
            out.cell_log_odds(Cell::new(c.x + 3, c.y - 2)),
            b.cell_log_odds(c)
        );
    }

    #[test]
    fn a_quarter_turn_maps_cells_where_expected() {
        let g = geometry(0.1, 0.0, 0.0, 10, 10);
        let mut b = OccupancyGrid::with_geometry(g).unwrap();
        b.set(Cell::new(7, 2), 2.0).unwrap();
        // 90° about the origin: B's (0.75, 0.25) lands at A's (-0.25, 0.75).
        let target = geometry(0.1, -1.0, 0.0, 10, 10);
        let out = resample_into(
            &b,
            &Se2::new(0.0, 0.0, core::f64::consts::FRAC_PI_2),
            &target,
        )
        .unwrap();
        assert_eq!(out.log_odds_at(&Point2::new(-0.25, 0.75)), 2.0);
        assert_eq!(out.log_odds().iter().filter(|&&l| l != 0.0).count(), 1);
    }

    #[test]
    fn coarsening_keeps_walls_and_averages_free_space() {
        // B at 0.05: a one-cell wall at x = 3, free elsewhere; A at 0.1: 2 × 2 samples.
        let g = geometry(0.05, 0.0, 0.0, 8, 8);
        let values: Vec<f32> = (0..64)
            .map(|i| if i % 8 == 3 { 2.0 } else { -1.0 })
            .collect();
        let b = OccupancyGrid::from_log_odds(g, values).unwrap();
        let out =
            resample_into(&b, &Se2::new(0.0, 0.0, 0.0), &geometry(0.1, 0.0, 0.0, 4, 4)).unwrap();
        for y in 0..4 {
            assert_eq!(out.cell_log_odds(Cell::new(0, y)), -1.0);
            assert_eq!(out.cell_log_odds(Cell::new(1, y)), 2.0, "the wall survives");
            assert_eq!(out.cell_log_odds(Cell::new(2, y)), -1.0);
        }
    }
}
