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
    sigma_cells: f64,
    max_cells: u64,
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
        let mut grid = Self::empty(params)?;
        grid.insert(points_in_target, 0)?;
        if grid.cells.is_empty() {
            return Err(ScanMatchError::EmptyTarget);
        }
        Ok(grid)
    }

    /// Empties the grid, keeping its buffer for the next [`CorrelationGrid::insert`].
    pub(crate) fn clear(&mut self) {
        self.cells.clear();
        self.width = 0;
        self.height = 0;
        self.origin_m = Point2::zeros();
    }

    /// A grid without cells; [`CorrelationGrid::insert`] grows it.
    pub fn empty(params: &CorrelativeParams) -> Result<Self, ScanMatchError> {
        params.validate()?;
        Ok(Self {
            resolution_m: params.resolution_m,
            sigma_cells: params.kernel_sigma_cells,
            max_cells: params.max_grid_cells,
            origin_m: Point2::zeros(),
            width: 0,
            height: 0,
            cells: Vec::new(),
        })
    }

    /// True when nothing was inserted.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// Bytes its cells hold on the heap (their buffer's capacity).
    pub fn heap_bytes(&self) -> usize {
        self.cells.capacity() * std::mem::size_of::<u16>()
    }

    /// Kernel reach in cells (3σ).
    fn reach(&self) -> i64 {
        (3.0 * self.sigma_cells).ceil().max(1.0) as i64
    }

    /// Adds the finite `points_in_target` (the likelihood of a cell is the max over every
    /// point inserted so far). The grid grows to cover them plus the kernel's reach, plus
    /// `margin_cells` on each side that grows, so a map built scan by scan is not copied at
    /// every scan. Returns the inserted cell rectangle `(i_min, j_min, i_max, j_max)` in the
    /// grid's (possibly new) cell coordinates, `None` when no point was finite.
    pub fn insert(
        &mut self,
        points_in_target: &[Point2],
        margin_cells: usize,
    ) -> Result<Option<(i64, i64, i64, i64)>, ScanMatchError> {
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
            return Ok(None);
        };
        self.cover(
            Point2::new(min_x, min_y),
            Point2::new(max_x, max_y),
            margin_cells,
        )?;
        let resolution_m = self.resolution_m;
        let origin_m = self.origin_m;
        let reach = self.reach();
        let inv_two_sigma_sq = 1.0 / (2.0 * self.sigma_cells * self.sigma_cells);
        let side = (2 * reach + 1) as usize;
        let (mut along_x, mut along_y) = (vec![0.0; side], vec![0.0; side]);
        let mut row_values = vec![0u16; side];
        let width = self.width as i64;
        let height = self.height as i64;
        for p in finite {
            // Point position in cell units, relative to the grid corner.
            let u = (p.x - origin_m.x) / resolution_m;
            let v = (p.y - origin_m.y) / resolution_m;
            let (cu, cv) = (fast_floor(u), fast_floor(v));
            // The Gaussian is separable: exp(−(du² + dv²)/2σ²) = exp(−du²/2σ²)·exp(−dv²/2σ²).
            for (k, (gx, gy)) in along_x.iter_mut().zip(along_y.iter_mut()).enumerate() {
                let offset = k as i64 - reach;
                let du = (cu + offset) as f64 + 0.5 - u;
                let dv = (cv + offset) as f64 + 0.5 - v;
                *gx = (-du * du * inv_two_sigma_sq).exp();
                *gy = (-dv * dv * inv_two_sigma_sq).exp();
            }
            // `cover` made room for the whole kernel; a point on a cell border may still land
            // one cell further than `cover` reckoned (floating point), so the block is
            // clipped to the grid rather than skipped.
            let i0 = cu - reach;
            let first = (-i0).clamp(0, side as i64) as usize;
            let last = (width - i0).clamp(0, side as i64) as usize;
            if first >= last {
                continue;
            }
            for (b, gy) in along_y.iter().enumerate() {
                let j = cv + b as i64 - reach;
                if j < 0 || j >= height {
                    continue;
                }
                for (value, gx) in row_values.iter_mut().zip(&along_x) {
                    *value = round_likelihood(gx * gy * f64::from(LIKELIHOOD_MAX));
                }
                let start = j as usize * self.width + (i0 + first as i64) as usize;
                let values = row_values.get(first..last).unwrap_or_default();
                if let Some(row) = self.cells.get_mut(start..start + values.len()) {
                    for (cell, value) in row.iter_mut().zip(values) {
                        *cell = (*cell).max(*value);
                    }
                }
            }
        }
        let (i_min, j_min) = self.cell_of(&Point2::new(min_x, min_y));
        let (i_max, j_max) = self.cell_of(&Point2::new(max_x, max_y));
        Ok(Some((
            i_min - reach,
            j_min - reach,
            i_max + reach,
            j_max + reach,
        )))
    }

    /// Grows the grid (keeping its cells, on the same lattice) to cover `[min, max]` plus
    /// the kernel's reach; sides that grow get `margin_cells` more.
    fn cover(
        &mut self,
        min: Point2,
        max: Point2,
        margin_cells: usize,
    ) -> Result<(), ScanMatchError> {
        let reach = self.reach();
        let resolution_m = self.resolution_m;
        let too_large = |cells: f64| ScanMatchError::TargetTooLarge {
            cells: if cells.is_finite() {
                cells as u64
            } else {
                u64::MAX
            },
            resolution_m,
            max_cells: self.max_cells,
        };
        if self.cells.is_empty() {
            let span_x = ((max.x - min.x) / resolution_m).ceil() + 1.0 + 2.0 * reach as f64;
            let span_y = ((max.y - min.y) / resolution_m).ceil() + 1.0 + 2.0 * reach as f64;
            let margin = margin_cells as f64;
            let cells = (span_x + 2.0 * margin) * (span_y + 2.0 * margin);
            if !(cells.is_finite() && cells <= self.max_cells as f64) {
                return Err(too_large(cells));
            }
            self.width = (span_x + 2.0 * margin) as usize;
            self.height = (span_y + 2.0 * margin) as usize;
            let corner = (reach + margin_cells as i64) as f64 * resolution_m;
            self.origin_m = Point2::new(min.x - corner, min.y - corner);
            // Empty: a cleared grid's buffer is reused (no fresh pages to fault in).
            self.cells.clear();
            self.cells.resize(self.width * self.height, 0);
            return Ok(());
        }
        // Needed cell range in the current lattice.
        let inverse_resolution = 1.0 / resolution_m;
        let lo_x = ((min.x - self.origin_m.x) * inverse_resolution).floor() - reach as f64;
        let lo_y = ((min.y - self.origin_m.y) * inverse_resolution).floor() - reach as f64;
        let hi_x = ((max.x - self.origin_m.x) * inverse_resolution).floor() + reach as f64;
        let hi_y = ((max.y - self.origin_m.y) * inverse_resolution).floor() + reach as f64;
        let (w, h) = (self.width as f64, self.height as f64);
        if lo_x >= 0.0 && lo_y >= 0.0 && hi_x < w && hi_y < h {
            return Ok(());
        }
        let margin = margin_cells as f64;
        let grow_left = if lo_x < 0.0 { -lo_x + margin } else { 0.0 };
        let grow_down = if lo_y < 0.0 { -lo_y + margin } else { 0.0 };
        let grow_right = if hi_x >= w {
            hi_x - w + 1.0 + margin
        } else {
            0.0
        };
        let grow_up = if hi_y >= h {
            hi_y - h + 1.0 + margin
        } else {
            0.0
        };
        let new_w = w + grow_left + grow_right;
        let new_h = h + grow_down + grow_up;
        let cells = new_w * new_h;
        if !(cells.is_finite() && cells <= self.max_cells as f64) {
            return Err(too_large(cells));
        }
        let (new_w, new_h) = (new_w as usize, new_h as usize);
        let (left, down) = (grow_left as usize, grow_down as usize);
        let mut grown = vec![0u16; new_w * new_h];
        for (j, row) in self.cells.chunks_exact(self.width).enumerate() {
            let start = (j + down) * new_w + left;
            if let Some(slot) = grown.get_mut(start..start + self.width) {
                slot.copy_from_slice(row);
            }
        }
        self.origin_m -= Point2::new(left as f64, down as f64) * resolution_m;
        self.width = new_w;
        self.height = new_h;
        self.cells = grown;
        Ok(())
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

    /// The cells as the search reads them (offset 0).
    pub(crate) fn view(&self) -> CellView<'_> {
        CellView {
            cells: &self.cells,
            width: self.width as i64,
            height: self.height as i64,
            offset: 0,
        }
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

/// `v.round()` (half away from zero) as a likelihood, for `v` in `[0, LIKELIHOOD_MAX]`,
/// without a libm call: the grid's rasterisation rounds every cell of every kernel.
#[inline]
fn round_likelihood(v: f64) -> u16 {
    let whole = v as u16;
    // `v − whole` is exact here, so this is `round` exactly (and branch-free).
    whole.saturating_add(u16::from(v - f64::from(whole) >= 0.5))
}

/// Appends `new[k] = max(old[k − shift], old[k])` for `k ∈ [0, old.len() + shift)`, missing
/// entries 0, to `out`. Appended, not written over zeros, so each cell is written once; the
/// slice iterators carry no bounds checks, so the compiler vectorises them.
fn extend_max_of_shifted(old: &[u16], out: &mut Vec<u16>, shift: usize) {
    let n = old.len();
    if shift >= n {
        // Only old[k] for k < n, nothing for n ≤ k < shift, only old[k − shift] after.
        out.extend_from_slice(old);
        out.resize(out.len() + (shift - n), 0);
        out.extend_from_slice(old);
        return;
    }
    // k < shift: only old[k]; shift ≤ k < n: both; n ≤ k: only old[k − shift].
    out.extend_from_slice(&old[..shift]);
    out.extend(
        old[..n - shift]
            .iter()
            .zip(&old[shift..])
            .map(|(a, b)| (*a).max(*b)),
    );
    out.extend_from_slice(&old[n - shift..]);
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
    /// An empty level (filled by [`PrecomputedGrid::levels_into`]).
    fn empty() -> Self {
        Self {
            offset: 0,
            width: 0,
            height: 0,
            cells: Vec::new(),
        }
    }

    /// Heights 1 ..= `depth`, each from the one below: a `2^h` block is two `2^(h−1)` blocks
    /// side by side, so `M_h(i, j) = max` of `M_(h−1)` at `i, i + 2^(h−1)` (then the same in
    /// `j`), two passes of one comparison per cell.
    #[cfg(test)]
    pub(crate) fn levels(base: &CorrelationGrid, depth: usize) -> Vec<Self> {
        let mut levels = Vec::new();
        let mut scratch = Vec::new();
        Self::levels_into(base, depth, &mut levels, &mut scratch);
        levels
    }

    /// As [`PrecomputedGrid::levels`], into `levels`, reusing its buffers (and `scratch` for
    /// the first pass): a map matched after every insertion recomputes its levels often, and
    /// fresh allocations of this size cost more in page faults than the max passes.
    pub(crate) fn levels_into(
        base: &CorrelationGrid,
        depth: usize,
        levels: &mut Vec<Self>,
        scratch: &mut Vec<u16>,
    ) {
        levels.truncate(depth);
        while levels.len() < depth {
            levels.push(Self::empty());
        }
        for height_level in 1..=depth {
            let (below, rest) = levels.split_at_mut(height_level - 1);
            let Some(out) = rest.first_mut() else {
                return;
            };
            match below.last() {
                None => Self::coarser_into(
                    (&base.cells, base.width, base.height, 0),
                    height_level,
                    out,
                    scratch,
                ),
                Some(previous) => Self::coarser_into(
                    (
                        &previous.cells,
                        previous.width,
                        previous.height,
                        previous.offset,
                    ),
                    height_level,
                    out,
                    scratch,
                ),
            }
        }
    }

    /// Level `height_level` into `out` from the level below, given as
    /// `(cells, width, height, offset)`.
    fn coarser_into(
        (cells, old_width, old_height, old_offset): (&[u16], usize, usize, i64),
        height_level: usize,
        out: &mut Self,
        rows: &mut Vec<u16>,
    ) {
        let half = 1usize << (height_level - 1);
        // offset(h) − offset(h − 1) = 2^(h−1): new index k is old index k − half.
        let (width, height) = (old_width + half, old_height + half);
        // Pass 1, along x: row[k] = max(old[k − half], old[k]).
        rows.clear();
        rows.reserve(width * old_height);
        for old in cells.chunks_exact(old_width.max(1)).take(old_height) {
            extend_max_of_shifted(old, rows, half);
        }
        rows.resize(width * old_height, 0);
        // Pass 2, along y, whole rows at a time.
        out.cells.clear();
        out.cells.reserve(width * height);
        for k in 0..height {
            let row = |index: Option<usize>| {
                index
                    .filter(|&j| j < old_height)
                    .and_then(|j| rows.get(j * width..(j + 1) * width))
            };
            match (row(k.checked_sub(half)), row(Some(k))) {
                (Some(a), Some(b)) => out.cells.extend(a.iter().zip(b).map(|(x, y)| (*x).max(*y))),
                (Some(a), None) | (None, Some(a)) => out.cells.extend_from_slice(a),
                (None, None) => out.cells.resize(out.cells.len() + width, 0),
            }
        }
        out.offset = old_offset + half as i64;
        out.width = width;
        out.height = height;
    }

    /// Bytes its cells hold on the heap.
    pub(crate) fn heap_bytes(&self) -> usize {
        self.cells.capacity() * std::mem::size_of::<u16>()
    }

    /// The cells as the search reads them: index (i, j) is the block with lower-left corner
    /// (i, j).
    pub(crate) fn view(&self) -> CellView<'_> {
        CellView {
            cells: &self.cells,
            width: self.width as i64,
            height: self.height as i64,
            offset: self.offset,
        }
    }

    /// Max of the base block whose lower-left corner is (i, j); 0 where the block misses the
    /// grid.
    #[cfg(test)]
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

/// Cells of a grid or level as the branch-and-bound reads them: cell (i, j) is
/// `cells[(j + offset) · width + i + offset]`, 0 outside.
#[derive(Clone, Copy, Debug)]
pub(crate) struct CellView<'a> {
    cells: &'a [u16],
    width: i64,
    height: i64,
    offset: i64,
}

/// Cells `(i, j)` of a discretised scan with their bounding box, so that a shifted scan known
/// to lie inside a grid is summed without a bounds test per point.
#[derive(Clone, Debug, Default)]
pub(crate) struct CellScan {
    cells: Vec<(i32, i32)>,
    /// `(min_i, min_j, max_i, max_j)`; empty scans have none.
    bounds: Option<(i64, i64, i64, i64)>,
}

/// Cells farther than this from the origin are clamped to it: at any shift of a search (at
/// most 2^20 cells) they lie outside any grid whose sides are shorter than 2^29 cells (one
/// such row alone is a gigabyte per level, far past `max_grid_cells`' default), so they score
/// 0 either way, and the rest fit in `i32`.
const FAR_CELL: i64 = 1 << 30;

impl CellScan {
    /// The scan of `cells` (any `i64`; see [`FAR_CELL`]).
    pub(crate) fn new(cells: impl Iterator<Item = (i64, i64)>) -> Self {
        let clamp = |v: i64| v.clamp(-FAR_CELL, FAR_CELL) as i32;
        let cells: Vec<(i32, i32)> = cells.map(|(i, j)| (clamp(i), clamp(j))).collect();
        let bounds = cells
            .iter()
            .fold(None, |b: Option<(i64, i64, i64, i64)>, &(i, j)| {
                let (i, j) = (i64::from(i), i64::from(j));
                Some(match b {
                    None => (i, j, i, j),
                    Some((a, b, c, d)) => (a.min(i), b.min(j), c.max(i), d.max(j)),
                })
            });
        Self { cells, bounds }
    }

    /// Number of cells.
    pub(crate) fn len(&self) -> usize {
        self.cells.len()
    }

    /// How many cells each run of [`CELLS_PER_RUN`] holds.
    pub(crate) fn cells_by_run(&self) -> impl Iterator<Item = usize> + '_ {
        self.cells.chunks(CELLS_PER_RUN).map(<[_]>::len)
    }

    /// The cells.
    pub(crate) fn cells(&self) -> impl Iterator<Item = (i64, i64)> + '_ {
        self.cells
            .iter()
            .map(|&(i, j)| (i64::from(i), i64::from(j)))
    }

    /// Σ over the scan's cells shifted by (x, y) of `view`'s values (0 outside).
    #[cfg(test)]
    pub(crate) fn sum(&self, view: &CellView<'_>, x: i64, y: i64) -> u64 {
        self.sum_under(view, x, y, &Ceiling::Max, 0, None)
    }

    /// As [`CellScan::sum`] when the sum reaches `cutoff`; otherwise some value below
    /// `cutoff` (an upper bound of the sum), returned as soon as the cells left cannot lift
    /// the partial sum to `cutoff` by their `ceiling`: a branch-and-bound node that cannot
    /// beat the incumbent is dropped after part of its cells. With `run_sums`, the sums of
    /// its cells in runs of [`CELLS_PER_RUN`] are written there (all of them when the sum
    /// reaches `cutoff`): the ceiling of the node's children.
    #[inline]
    pub(crate) fn sum_under(
        &self,
        view: &CellView<'_>,
        x: i64,
        y: i64,
        ceiling: &Ceiling<'_>,
        cutoff: u64,
        mut run_sums: Option<&mut Vec<u32>>,
    ) -> u64 {
        if let Some(run_sums) = run_sums.as_deref_mut() {
            run_sums.clear();
        }
        let n = self.cells.len();
        let (dx, dy) = (x + view.offset, y + view.offset);
        let (cells, width) = (view.cells, view.width);
        let inside = match self.bounds {
            None => return 0,
            Some((min_i, min_j, max_i, max_j)) => {
                let (lo_a, lo_b, hi_a, hi_b) = (min_i + dx, min_j + dy, max_i + dx, max_j + dy);
                if hi_a < 0 || hi_b < 0 || lo_a >= view.width || lo_b >= view.height {
                    if let Some(run_sums) = run_sums {
                        run_sums.resize(n.div_ceil(CELLS_PER_RUN), 0);
                    }
                    return 0;
                }
                lo_a >= 0 && lo_b >= 0 && hi_a < view.width && hi_b < view.height
            }
        };
        let base = dy * width + dx;
        let (width_u, height_u) = (width as u64, view.height as u64);
        let mut sum = 0u64;
        // The most the cells not yet summed can add.
        let mut left = ceiling.total(n);
        for (k, run) in self.cells.chunks(CELLS_PER_RUN).enumerate() {
            let run_sum: u32 = if inside {
                // Every shifted cell is inside: one index per point (`get` never misses).
                run.iter()
                    .map(|&(i, j)| {
                        let index = (base + i64::from(j) * width + i64::from(i)) as usize;
                        u32::from(cells.get(index).copied().unwrap_or(0))
                    })
                    .sum()
            } else {
                // Negative offsets wrap to huge unsigned ones: one comparison per axis.
                run.iter()
                    .map(|&(i, j)| {
                        let (a, b) = (i64::from(i) + dx, i64::from(j) + dy);
                        if (a as u64) < width_u && (b as u64) < height_u {
                            u32::from(cells.get((b * width + a) as usize).copied().unwrap_or(0))
                        } else {
                            0
                        }
                    })
                    .sum()
            };
            if let Some(run_sums) = run_sums.as_deref_mut() {
                run_sums.push(run_sum);
            }
            sum += u64::from(run_sum);
            left = left.saturating_sub(ceiling.of_run(k, run.len()));
            if sum + left < cutoff {
                return sum + left;
            }
        }
        sum
    }
}

/// Cells per run of a [`CellScan`] between two tests of a sum against its cutoff (a run of
/// `u16` values sums within a `u32`).
pub(crate) const CELLS_PER_RUN: usize = 16;

/// The most each run of [`CELLS_PER_RUN`] cells of a [`CellScan`] can add to a sum: every
/// likelihood at most [`LIKELIHOOD_MAX`], or the run's sum one level up (Hess et al. 2016,
/// Sec. V-C: a child's block lies within its parent's, so no cell scores more in the child).
pub(crate) enum Ceiling<'a> {
    /// Every cell at most [`LIKELIHOOD_MAX`].
    Max,
    /// The parent's sums, run by run, and their total.
    Parent(&'a [u32], u64),
}

impl Ceiling<'_> {
    /// The ceiling of all `n` cells.
    fn total(&self, n: usize) -> u64 {
        match self {
            Ceiling::Max => n as u64 * u64::from(LIKELIHOOD_MAX),
            Ceiling::Parent(_, total) => *total,
        }
    }

    /// The ceiling of run `index`, of `len` cells.
    #[inline]
    fn of_run(&self, index: usize, len: usize) -> u64 {
        match self {
            Ceiling::Max => len as u64 * u64::from(LIKELIHOOD_MAX),
            // A missing run lowers nothing: the bound stays valid, only looser.
            Ceiling::Parent(sums, _) => sums.get(index).map_or(0, |&s| u64::from(s)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` points on the curve `(sin(k·fx)·ax, cos(k·fy)·ay)`, their grid and its first
    /// `depth` levels.
    fn curve_grid(
        n: usize,
        (fx, ax): (f64, f64),
        (fy, ay): (f64, f64),
        depth: usize,
    ) -> (Vec<Point2>, CorrelationGrid, Vec<PrecomputedGrid>) {
        let points: Vec<Point2> = (0..n)
            .map(|k| Point2::new((k as f64 * fx).sin() * ax, (k as f64 * fy).cos() * ay))
            .collect();
        let base = CorrelationGrid::new(&points, &CorrelativeParams::default()).unwrap();
        let levels = PrecomputedGrid::levels(&base, depth);
        (points, base, levels)
    }

    #[test]
    fn precomputed_levels_hold_block_maxima() {
        let (_, base, levels) = curve_grid(40, (0.37, 1.3), (0.71, 0.9), 4);
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
    fn a_shifted_scan_sums_the_cells_it_lands_on_inside_partly_and_outside_the_grid() {
        let (points, base, levels) = curve_grid(60, (0.41, 1.7), (0.23, 1.1), 3);
        let cells: Vec<(i64, i64)> = points
            .iter()
            .map(|p| base.cell_of(p))
            .chain([(1 << 50, -5), (3, 1 << 40)])
            .collect();
        let scan = CellScan::new(cells.iter().copied());
        let (w, h) = base.size();
        for y in (-(h as i64) - 10..h as i64 + 10).step_by(3) {
            for x in (-(w as i64) - 10..w as i64 + 10).step_by(3) {
                let expected: u64 = cells
                    .iter()
                    .map(|&(i, j)| u64::from(base.value(i.saturating_add(x), j.saturating_add(y))))
                    .sum();
                assert_eq!(scan.sum(&base.view(), x, y), expected, "shift ({x}, {y})");
                for grid in &levels {
                    let expected: u64 = cells
                        .iter()
                        .map(|&(i, j)| {
                            u64::from(grid.value(i.saturating_add(x), j.saturating_add(y)))
                        })
                        .sum();
                    assert_eq!(scan.sum(&grid.view(), x, y), expected, "shift ({x}, {y})");
                }
            }
        }
        assert_eq!(CellScan::new(std::iter::empty()).sum(&base.view(), 0, 0), 0);
    }

    /// Below its cutoff a sum may stop early, but only at an upper bound that is itself below
    /// the cutoff; at or above it, it is exact with every run's sum. A child under its
    /// parent's run sums (Hess et al.: its block lies within the parent's) obeys the same.
    #[test]
    fn a_sum_under_a_cutoff_is_exact_above_it_and_a_bound_below_it() {
        let (points, base, levels) = curve_grid(150, (0.41, 1.7), (0.23, 1.1), 3);
        let scan = CellScan::new(points.iter().map(|p| base.cell_of(p)));
        let full = scan.len() as u64 * u64::from(LIKELIHOOD_MAX);
        let (mut parent_runs, mut child_runs) = (Vec::new(), Vec::new());
        let mut stopped_early = 0;
        for (x, y) in [(0, 0), (3, -2), (-7, 5), (12, 12), (-40, 1)] {
            let parent = scan.sum_under(
                &levels[2].view(),
                x,
                y,
                &Ceiling::Max,
                0,
                Some(&mut parent_runs),
            );
            assert_eq!(parent, scan.sum(&levels[2].view(), x, y));
            assert_eq!(parent_runs.len(), scan.len().div_ceil(CELLS_PER_RUN));
            assert_eq!(
                parent_runs.iter().map(|&r| u64::from(r)).sum::<u64>(),
                parent
            );
            for (dx, dy) in [(0, 0), (0, 4), (4, 0), (4, 4)] {
                let exact = scan.sum(&levels[1].view(), x + dx, y + dy);
                assert!(exact <= parent);
                for cutoff in [0, exact / 2, exact, exact + 1, (exact + parent) / 2, full] {
                    for ceiling in [Ceiling::Max, Ceiling::Parent(&parent_runs, parent)] {
                        let view = levels[1].view();
                        let got = scan.sum_under(
                            &view,
                            x + dx,
                            y + dy,
                            &ceiling,
                            cutoff,
                            Some(&mut child_runs),
                        );
                        if exact >= cutoff {
                            assert_eq!(
                                got, exact,
                                "shift ({x}, {y}) + ({dx}, {dy}), cutoff {cutoff}"
                            );
                            assert_eq!(
                                child_runs.iter().map(|&r| u64::from(r)).sum::<u64>(),
                                exact
                            );
                        } else {
                            assert!(
                                got < cutoff && got >= exact,
                                "{got} against {exact}, cutoff {cutoff}"
                            );
                            stopped_early += usize::from(got > exact);
                        }
                    }
                }
            }
        }
        assert!(stopped_early > 0, "no sum stopped early");
    }

    #[test]
    fn a_likelihood_rounds_as_f64_round() {
        let halves = (0..=2 * u32::from(LIKELIHOOD_MAX)).map(|k| f64::from(k) * 0.5);
        let near = (0..20_000).flat_map(|k| {
            let v = f64::from(k) * 3.2767 + 0.5;
            [v, v.next_down(), v.next_up(), v - 0.25]
        });
        for v in halves
            .chain(near)
            .filter(|v| (0.0..=f64::from(LIKELIHOOD_MAX)).contains(v))
        {
            assert_eq!(round_likelihood(v), v.round() as u16, "{v}");
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
