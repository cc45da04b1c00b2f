//! The correlation lookup table and its coarse max-pooled levels.
//!
//! Olson 2009, Sec. III-B: a rasterised likelihood of a query point given the target; Hess et
//! al. 2016, Sec. V-C: precomputed grids whose cell at height `h` holds the maximum of the
//! `2^h × 2^h` block whose lower-left corner it is.

use mapmerge_scan::Point2;

use crate::error::ScanMatchError;
use crate::params::CorrelativeParams;

/// Likelihood value of a cell that holds a target point exactly at its centre.
pub(crate) const LIKELIHOOD_MAX: u16 = u16::MAX;

/// A grid of match likelihoods, `exp(−d² / 2σ²)` of the distance `d` from a cell's centre to
/// the nearest target point (Olson 2009, Sec. III: the rasterised cost), quantised to `u16` so that
/// sums are exact integers and branch-and-bound can compare bounds without rounding.
#[derive(Clone, Debug)]
pub struct CorrelationGrid {
    resolution_m: f64,
    /// Corner (not centre) of cell (0, 0), in the target frame (m).
    origin_m: Point2,
    width: usize,
    height: usize,
    cells: Vec<u16>,
}

impl CorrelationGrid {
    /// Rasterises the finite `points_in_target`. The grid covers their bounding box plus the
    /// kernel's reach (3σ).
    pub fn new(
        points_in_target: &[Point2],
        params: &CorrelativeParams,
    ) -> Result<Self, ScanMatchError> {
        params.validate()?;
        let finite: Vec<&Point2> = points_in_target
            .iter()
            .filter(|p| p.x.is_finite() && p.y.is_finite())
            .collect();
        let (Some(min_x), Some(min_y), Some(max_x), Some(max_y)) = (
            finite.iter().map(|p| p.x).reduce(f64::min),
            finite.iter().map(|p| p.y).reduce(f64::min),
            finite.iter().map(|p| p.x).reduce(f64::max),
            finite.iter().map(|p| p.y).reduce(f64::max),
        ) else {
            return Err(ScanMatchError::EmptyTarget);
        };
        let resolution_m = params.resolution_m;
        let sigma_cells = params.kernel_sigma_cells;
        let reach = (3.0 * sigma_cells).ceil().max(1.0) as i64;
        let span_x = ((max_x - min_x) / resolution_m).ceil() + 1.0 + 2.0 * reach as f64;
        let span_y = ((max_y - min_y) / resolution_m).ceil() + 1.0 + 2.0 * reach as f64;
        let cells = span_x * span_y;
        if !(cells.is_finite() && cells <= params.max_grid_cells as f64) {
            return Err(ScanMatchError::TargetTooLarge {
                cells: if cells.is_finite() {
                    cells as u64
                } else {
                    u64::MAX
                },
                resolution_m,
                max_cells: params.max_grid_cells,
            });
        }
        let (width, height) = (span_x as usize, span_y as usize);
        let origin_m = Point2::new(
            min_x - reach as f64 * resolution_m,
            min_y - reach as f64 * resolution_m,
        );
        let mut grid = Self {
            resolution_m,
            origin_m,
            width,
            height,
            cells: vec![0; width * height],
        };
        let inv_two_sigma_sq = 1.0 / (2.0 * sigma_cells * sigma_cells);
        let side = (2 * reach + 1) as usize;
        let (mut along_x, mut along_y) = (vec![0.0; side], vec![0.0; side]);
        for p in finite {
            // Point position in cell units, relative to the grid corner.
            let u = (p.x - origin_m.x) / resolution_m;
            let v = (p.y - origin_m.y) / resolution_m;
            let (cu, cv) = (u.floor() as i64, v.floor() as i64);
            // The Gaussian is separable: exp(−(du² + dv²)/2σ²) = exp(−du²/2σ²)·exp(−dv²/2σ²).
            for (k, (gx, gy)) in along_x.iter_mut().zip(along_y.iter_mut()).enumerate() {
                let offset = k as i64 - reach;
                let du = (cu + offset) as f64 + 0.5 - u;
                let dv = (cv + offset) as f64 + 0.5 - v;
                *gx = (-du * du * inv_two_sigma_sq).exp();
                *gy = (-dv * dv * inv_two_sigma_sq).exp();
            }
            for (b, gy) in along_y.iter().enumerate() {
                let j = cv + b as i64 - reach;
                for (a, gx) in along_x.iter().enumerate() {
                    let i = cu + a as i64 - reach;
                    let Some(index) = grid.index(i, j) else {
                        continue;
                    };
                    let value = (gx * gy * f64::from(LIKELIHOOD_MAX)).round() as u16;
                    if let Some(cell) = grid.cells.get_mut(index) {
                        *cell = (*cell).max(value);
                    }
                }
            }
        }
        Ok(grid)
    }

    /// Cell size (m).
    pub fn resolution_m(&self) -> f64 {
        self.resolution_m
    }

    /// Corner of cell (0, 0) in the target frame (m).
    pub fn origin_m(&self) -> Point2 {
        self.origin_m
    }

    /// (width, height) in cells.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// The cell that contains `p_in_target` (may lie outside the grid).
    pub fn cell_of(&self, p_in_target: &Point2) -> (i64, i64) {
        let inverse_resolution = 1.0 / self.resolution_m;
        (
            fast_floor((p_in_target.x - self.origin_m.x) * inverse_resolution),
            fast_floor((p_in_target.y - self.origin_m.y) * inverse_resolution),
        )
    }

    fn index(&self, i: i64, j: i64) -> Option<usize> {
        if i < 0 || j < 0 || i >= self.width as i64 || j >= self.height as i64 {
            return None;
        }
        Some(j as usize * self.width + i as usize)
    }

    /// The quantised likelihood of cell (i, j), 0 outside the grid.
    pub(crate) fn value(&self, i: i64, j: i64) -> u16 {
        self.index(i, j)
            .and_then(|index| self.cells.get(index).copied())
            .unwrap_or(0)
    }

    /// The likelihood in [0, 1] of a point at `p_in_target` (nearest cell).
    pub fn likelihood(&self, p_in_target: &Point2) -> f64 {
        let (i, j) = self.cell_of(p_in_target);
        f64::from(self.value(i, j)) / f64::from(LIKELIHOOD_MAX)
    }
}

/// `⌊v⌋` as an integer without a libm call, clamped far outside any grid (NaN too) so that
/// offsets added later cannot overflow.
#[inline]
pub(crate) fn fast_floor(v: f64) -> i64 {
    const FAR: f64 = 1e15;
    let v = if v.is_nan() { FAR } else { v.clamp(-FAR, FAR) };
    let truncated = v as i64;
    if (truncated as f64) > v {
        truncated - 1
    } else {
        truncated
    }
}

/// One precomputed level: cell (i, j) holds the max of the base cells
/// `[i, i + 2^h) × [j, j + 2^h)`; it is stored for `i ∈ [−(2^h − 1), width)` (Hess et al.
/// 2016, Sec. V-C: "the lower-left corner").
#[derive(Clone, Debug)]
pub(crate) struct PrecomputedGrid {
    offset: i64,
    width: usize,
    height: usize,
    cells: Vec<u16>,
}

impl PrecomputedGrid {
    /// Height 0: the base grid itself.
    fn from_base(base: &CorrelationGrid) -> Self {
        Self {
            offset: 0,
            width: base.width,
            height: base.height,
            cells: base.cells.clone(),
        }
    }

    /// Heights 1 ..= `depth`, each from the one below: a `2^h` block is two `2^(h−1)` blocks
    /// side by side, so `M_h(i, j) = max` of `M_(h−1)` at `i, i + 2^(h−1)` (then the same in
    /// `j`), two passes of one comparison per cell.
    pub(crate) fn levels(base: &CorrelationGrid, depth: usize) -> Vec<Self> {
        let mut levels: Vec<Self> = Vec::with_capacity(depth);
        let mut previous = Self::from_base(base);
        for height_level in 1..=depth {
            let next = previous.coarser(height_level);
            levels.push(std::mem::replace(&mut previous, next));
        }
        levels.push(previous);
        // `levels[0]` is the base copy; drop it.
        levels.remove(0);
        levels
    }

    /// Level `height_level` from this one (level `height_level − 1`).
    fn coarser(&self, height_level: usize) -> Self {
        let half = 1usize << (height_level - 1);
        let grow = half; // offset(h) − offset(h − 1) = 2^(h−1)
        let (width, height) = (self.width + grow, self.height + grow);
        let at = |cells: &[u16], stride: usize, len: usize, k: usize, other: usize| -> u16 {
            // Index k of the new axis is index k − grow of the old one.
            let get = |index: Option<usize>| {
                index
                    .filter(|&i| i < len)
                    .and_then(|i| cells.get(i * stride + other))
                    .copied()
                    .unwrap_or(0)
            };
            // X and X + 2^(h−1) are old indices k − grow and k.
            get(k.checked_sub(grow)).max(get(Some(k)))
        };
        // Pass 1: along x (rows of the old height).
        let mut rows = vec![0u16; width * self.height];
        for j in 0..self.height {
            let Some(row) = self.cells.get(j * self.width..(j + 1) * self.width) else {
                continue;
            };
            for (i, slot) in rows.iter_mut().skip(j * width).take(width).enumerate() {
                *slot = at(row, 1, self.width, i, 0);
            }
        }
        // Pass 2: along y.
        let mut cells = vec![0u16; width * height];
        for (j, out_row) in cells.chunks_mut(width).enumerate() {
            for (i, slot) in out_row.iter_mut().enumerate() {
                *slot = at(&rows, width, self.height, j, i);
            }
        }
        Self {
            offset: self.offset + grow as i64,
            width,
            height,
            cells,
        }
    }

    /// Max of the base block whose lower-left corner is (i, j); 0 where the block misses the
    /// grid.
    #[inline]
    pub(crate) fn value(&self, i: i64, j: i64) -> u16 {
        let (a, b) = (i + self.offset, j + self.offset);
        if a < 0 || b < 0 || a >= self.width as i64 || b >= self.height as i64 {
            return 0;
        }
        self.cells
            .get(b as usize * self.width + a as usize)
            .copied()
            .unwrap_or(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn precomputed_levels_hold_block_maxima() {
        let points: Vec<Point2> = (0..40)
            .map(|k| Point2::new((k as f64 * 0.37).sin() * 1.3, (k as f64 * 0.71).cos() * 0.9))
            .collect();
        let base = CorrelationGrid::new(&points, &CorrelativeParams::default()).unwrap();
        let levels = PrecomputedGrid::levels(&base, 4);
        assert_eq!(levels.len(), 4);
        for (index, grid) in levels.iter().enumerate() {
            let level = index + 1;
            let block = 1i64 << level;
            let (w, h) = base.size();
            for j in -block..(h as i64 + 1) {
                for i in -block..(w as i64 + 1) {
                    let mut expected = 0;
                    for b in j..j + block {
                        for a in i..i + block {
                            expected = expected.max(base.value(a, b));
                        }
                    }
                    assert_eq!(grid.value(i, j), expected, "level {level} cell ({i}, {j})");
                }
            }
        }
    }

    #[test]
    fn cell_with_a_point_is_likely_and_far_cells_are_zero() {
        let base =
            CorrelationGrid::new(&[Point2::new(1.0, 2.0)], &CorrelativeParams::default()).unwrap();
        assert!(base.likelihood(&Point2::new(1.0, 2.0)) > 0.8);
        assert_eq!(base.likelihood(&Point2::new(3.0, 2.0)), 0.0);
        assert_eq!(base.likelihood(&Point2::new(f64::NAN, 2.0)), 0.0);
        assert!(CorrelationGrid::new(&[], &CorrelativeParams::default()).is_err());
    }
}
