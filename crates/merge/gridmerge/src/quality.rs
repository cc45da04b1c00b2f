//! Per-region quality of an occupancy grid, for quality-weighted fusion (Andersone, Sec. 2.2
//! and 4.1).
//!
//! Andersone (2020) classifies map fragments with a CNN; this crate uses a deterministic,
//! hand-made estimate instead, per square block of cells:
//!
//! * **certainty** — the mean over observed cells (log-odds ≠ 0) of
//!   `min(|l| / saturation_log_odds, 1)`. With a fixed inverse sensor model, `|l|` grows with
//!   the number of consistent observations, so this is an observation-count proxy: a region
//!   seen once scores low, a region seen many times scores high.
//! * **structure** — how crisp the occupied structure is: the mean of *thinness* (fraction of
//!   occupied cells with a non-occupied 4-neighbour: smeared, multi-cell-thick walls from pose
//!   error have interior cells) and *support* (fraction of occupied cells with an occupied
//!   8-neighbour: isolated speckles are noise). 1 when the block has no occupied cell.
//!
//! The block's score is `certainty × structure` in [0, 1]; blocks with too few observed cells
//! have no estimate.

use mapmerge_grid::{log_odds_of, Cell, ClassThresholds, GridGeometry, OccupancyGrid};
use serde::{Deserialize, Serialize};

use crate::MergeError;

/// Marks a block without an estimate in [`QualityMap`]'s scores.
pub(crate) const NO_ESTIMATE: f32 = -1.0;

/// How the per-block quality is estimated.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct QualityParams {
    /// Side of a quality block (m). Larger blocks give steadier estimates but blur the
    /// difference between good and bad regions (default 2.0).
    pub block_m: f64,
    /// `|log-odds|` at which a cell counts as fully certain (default 2.0, p ≈ 0.88: about
    /// two consistent hits or five misses with the default sensor model).
    pub saturation_log_odds: f32,
    /// Fraction of a block's cells that must be observed for an estimate (default 0.1);
    /// sparser blocks report none.
    pub min_known_fraction: f64,
    /// Which cells count as occupied (default: the grid crate's 0.65 / 0.35).
    pub thresholds: ClassThresholds,
}

impl Default for QualityParams {
    fn default() -> Self {
        Self {
            block_m: 2.0,
            saturation_log_odds: 2.0,
            min_known_fraction: 0.1,
            thresholds: ClassThresholds::default(),
        }
    }
}

impl QualityParams {
    pub(crate) fn validate(&self) -> Result<(), MergeError> {
        if !(self.block_m.is_finite() && self.block_m > 0.0) {
            return Err(MergeError::BadParams {
                name: "quality.block_m",
                reason: format!("must be positive and finite, got {}", self.block_m),
            });
        }
        if !(self.saturation_log_odds.is_finite() && self.saturation_log_odds > 0.0) {
            return Err(MergeError::BadParams {
                name: "quality.saturation_log_odds",
                reason: format!(
                    "must be positive and finite, got {}",
                    self.saturation_log_odds
                ),
            });
        }
        if !(0.0..=1.0).contains(&self.min_known_fraction) {
            return Err(MergeError::BadParams {
                name: "quality.min_known_fraction",
                reason: format!("must lie in [0, 1], got {}", self.min_known_fraction),
            });
        }
        let t = &self.thresholds;
        if !(t.occupied_min > 0.0 && t.occupied_min < 1.0) {
            return Err(MergeError::BadParams {
                name: "quality.thresholds.occupied_min",
                reason: format!("must lie in (0, 1), got {}", t.occupied_min),
            });
        }
        Ok(())
    }
}

/// Quality scores of a grid's square blocks (see the module doc).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct QualityMap {
    geometry: GridGeometry,
    block_cells: usize,
    blocks_x: usize,
    blocks_y: usize,
    /// Block column of every cell column (lookups without division).
    column_block: Vec<usize>,
    /// Index of the first block of every cell row's block row.
    row_block: Vec<usize>,
    /// Row-major block scores in [0, 1], [`NO_ESTIMATE`] where there is none.
    scores: Vec<f32>,
}

impl QualityMap {
    /// Estimates the quality of every block of `grid`. Blocks start at cell (0, 0).
    pub fn estimate(grid: &OccupancyGrid, params: &QualityParams) -> Result<Self, MergeError> {
        params.validate()?;
        let geometry = *grid.geometry();
        let (width, height) = (geometry.width, geometry.height);
        let block_cells = (params.block_m / geometry.resolution_m)
            .round()
            .clamp(1.0, (width.max(height).max(1)) as f64) as usize;
        let blocks_x = width.div_ceil(block_cells);
        let blocks_y = height.div_ceil(block_cells);
        let blocks = blocks_x * blocks_y;
        let mut known = vec![0u32; blocks];
        let mut certainty = vec![0.0f64; blocks];
        let mut occupied = vec![0u32; blocks];
        let mut thin = vec![0u32; blocks];
        let mut supported = vec![0u32; blocks];
        // Monotone in the probability, so the same cells as ClassThresholds::classify up to
        // rounding at the threshold itself.
        let occupied_min = log_odds_of(params.thresholds.occupied_min);
        let cells = grid.log_odds();
        let is_occupied = |x: i64, y: i64| -> bool {
            if x < 0 || y < 0 || x as usize >= width || y as usize >= height {
                return false;
            }
            cells
                .get(y as usize * width + x as usize)
                .is_some_and(|&l| l != 0.0 && l >= occupied_min)
        };
        let inv_saturation = 1.0 / f64::from(params.saturation_log_odds);
        for y in 0..height {
            let block_row = (y / block_cells) * blocks_x;
            let row = cells.get(y * width..(y + 1) * width).unwrap_or(&[]);
            // One block-wide chunk at a time: no division per cell.
            for (chunk_index, chunk) in row.chunks(block_cells).enumerate() {
                let x_start = chunk_index * block_cells;
                let (mut k, mut c, mut o, mut t, mut s) = (0u32, 0.0f64, 0u32, 0u32, 0u32);
                for (dx, &l) in chunk.iter().enumerate() {
                    if l == 0.0 {
                        continue;
                    }
                    k += 1;
                    c += (f64::from(l.abs()) * inv_saturation).min(1.0);
                    if l < occupied_min {
                        continue;
                    }
                    let (xi, yi) = ((x_start + dx) as i64, y as i64);
                    let four = [(xi - 1, yi), (xi + 1, yi), (xi, yi - 1), (xi, yi + 1)];
                    let diagonal = [
                        (xi - 1, yi - 1),
                        (xi + 1, yi - 1),
                        (xi - 1, yi + 1),
                        (xi + 1, yi + 1),
                    ];
                    o += 1;
                    t += u32::from(four.iter().any(|&(nx, ny)| !is_occupied(nx, ny)));
                    s += u32::from(
                        four.iter()
                            .chain(diagonal.iter())
                            .any(|&(nx, ny)| is_occupied(nx, ny)),
                    );
                }
                let b = block_row + chunk_index;
                if let (Some(kb), Some(cb), Some(ob), Some(tb), Some(sb)) = (
                    known.get_mut(b),
                    certainty.get_mut(b),
                    occupied.get_mut(b),
                    thin.get_mut(b),
                    supported.get_mut(b),
                ) {
                    *kb += k;
                    *cb += c;
                    *ob += o;
                    *tb += t;
                    *sb += s;
                }
            }
        }
        let scores = (0..blocks)
            .map(|b| {
                let (bx, by) = (b % blocks_x.max(1), b / blocks_x.max(1));
                let w = block_cells.min(width - (bx * block_cells).min(width));
                let h = block_cells.min(height - (by * block_cells).min(height));
                let k = known.get(b).copied().unwrap_or(0);
                if k == 0 || f64::from(k) < params.min_known_fraction * (w * h) as f64 {
                    return NO_ESTIMATE;
                }
                let cert = certainty.get(b).copied().unwrap_or(0.0) / f64::from(k);
                let occ = occupied.get(b).copied().unwrap_or(0);
                let structure = if occ == 0 {
                    1.0
                } else {
                    let t = f64::from(thin.get(b).copied().unwrap_or(0));
                    let s = f64::from(supported.get(b).copied().unwrap_or(0));
                    0.5 * (t + s) / f64::from(occ)
                };
                (cert * structure) as f32
            })
            .collect();
        Ok(Self {
            geometry,
            block_cells,
            blocks_x,
            blocks_y,
            column_block: (0..width).map(|x| x / block_cells).collect(),
            row_block: (0..height).map(|y| (y / block_cells) * blocks_x).collect(),
            scores,
        })
    }

    /// Geometry of the grid the estimate was made on.
    pub fn geometry(&self) -> &GridGeometry {
        &self.geometry
    }

    /// Side of a block (cells).
    pub fn block_cells(&self) -> usize {
        self.block_cells
    }

    /// Number of blocks along x and y.
    pub fn blocks(&self) -> (usize, usize) {
        (self.blocks_x, self.blocks_y)
    }

    /// Score of block `(bx, by)`, if it has one.
    pub fn block_score(&self, bx: usize, by: usize) -> Option<f32> {
        if bx >= self.blocks_x {
            return None;
        }
        self.scores
            .get(by * self.blocks_x + bx)
            .copied()
            .filter(|&s| s >= 0.0)
    }

    /// Score of the block holding `cell` of the estimated grid, if it has one.
    pub fn at_cell(&self, cell: Cell) -> Option<f32> {
        let s = self.raw_at(cell.x, cell.y);
        (s >= 0.0).then_some(s)
    }

    /// Like [`Self::at_cell`], [`NO_ESTIMATE`] for none (the fusion's hot path).
    pub(crate) fn raw_at(&self, x: i64, y: i64) -> f32 {
        if x < 0 || y < 0 {
            return NO_ESTIMATE;
        }
        match (
            self.column_block.get(x as usize),
            self.row_block.get(y as usize),
        ) {
            (Some(&column), Some(&row)) => self
                .scores
                .get(row + column)
                .copied()
                .unwrap_or(NO_ESTIMATE),
            _ => NO_ESTIMATE,
        }
    }

    /// Mean score of the blocks that have one: a whole-map quality for
    /// [`crate::MapMetadata::quality`].
    pub fn overall(&self) -> Option<f64> {
        let (sum, n) = self
            .scores
            .iter()
            .filter(|&&s| s >= 0.0)
            .fold((0.0f64, 0usize), |(sum, n), &s| (sum + f64::from(s), n + 1));
        (n > 0).then(|| sum / n as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapmerge_grid::Point2;

    const RES: f64 = 0.05;

    /// A 40 × 40 grid (2 m: one block): free everywhere, with `wall(x, y)` cells occupied.
    fn room(free: f32, occ: f32, wall: impl Fn(i64, i64) -> bool) -> OccupancyGrid {
        let geometry = GridGeometry {
            resolution_m: RES,
            origin_m: Point2::zeros(),
            width: 40,
            height: 40,
        };
        let mut g = OccupancyGrid::with_geometry(geometry).unwrap();
        for y in 0..40 {
            for x in 0..40 {
                let l = if wall(x, y) { occ } else { free };
                g.set(Cell::new(x, y), l).unwrap();
            }
        }
        g
    }

    fn score(g: &OccupancyGrid) -> f32 {
        let q = QualityMap::estimate(g, &QualityParams::default()).unwrap();
        assert_eq!(q.blocks(), (1, 1));
        q.block_score(0, 0).unwrap()
    }

    #[test]
    fn a_thin_certain_wall_scores_one() {
        let g = room(-2.0, 2.0, |x, _| x == 20);
        assert_eq!(score(&g), 1.0);
    }

    #[test]
    fn smeared_walls_and_speckles_score_lower() {
        let sharp = score(&room(-2.0, 2.0, |x, _| x == 20));
        // A wall smeared over 5 cells (pose error): 3 of 5 columns are interior except at
        // the grid's top and bottom rows, so 86 of 200 wall cells are thin.
        let smeared = score(&room(-2.0, 2.0, |x, _| (18..=22).contains(&x)));
        // The same wall plus isolated speckles in free space (spurious returns).
        let speckled = score(&room(-2.0, 2.0, |x, y| {
            x == 20 || (x % 6 == 2 && y % 6 == 2)
        }));
        assert!(smeared < sharp, "{smeared} vs {sharp}");
        assert!(
            (smeared - 0.5 * (86.0 / 200.0 + 1.0)).abs() < 1e-6,
            "{smeared}"
        );
        assert!(speckled < sharp, "{speckled} vs {sharp}");
    }

    #[test]
    fn fewer_observations_score_lower() {
        // One miss per free cell and one hit per wall cell versus saturated evidence.
        let once = score(&room(-0.405, 0.847, |x, _| x == 20));
        let many = score(&room(-2.0, 3.0, |x, _| x == 20));
        assert!(once < 0.5 * many, "{once} vs {many}");
        assert!((once - (39.0 * 0.405 / 2.0 + 0.847 / 2.0) / 40.0).abs() < 1e-4);
    }

    #[test]
    fn sparse_blocks_have_no_estimate_and_blocks_are_in_metres() {
        let geometry = GridGeometry {
            resolution_m: 0.1,
            origin_m: Point2::new(-3.0, 5.0),
            width: 45,
            height: 20,
        };
        let mut g = OccupancyGrid::with_geometry(geometry).unwrap();
        // Block (0, 0): fully observed; block (1, 0): 3 cells of 400; block (2, 0): partial.
        for y in 0..20 {
            for x in 0..20 {
                g.set(Cell::new(x, y), -1.0).unwrap();
            }
        }
        for x in 20..23 {
            g.set(Cell::new(x, 0), -1.0).unwrap();
        }
        for x in 40..45 {
            g.set(Cell::new(x, 3), -1.0).unwrap();
        }
        let q = QualityMap::estimate(&g, &QualityParams::default()).unwrap();
        assert_eq!(q.block_cells(), 20);
        assert_eq!(q.blocks(), (3, 1));
        assert_eq!(q.block_score(0, 0), Some(0.5));
        assert_eq!(q.block_score(1, 0), None);
        // The last block is 5 × 20 cells; 5 observed is 5 %, below 10 %.
        assert_eq!(q.block_score(2, 0), None);
        assert_eq!(q.at_cell(Cell::new(19, 19)), Some(0.5));
        assert_eq!(q.at_cell(Cell::new(-1, 0)), None);
        assert_eq!(q.overall(), Some(0.5));
        // Deterministic: the same grid gives the same map.
        assert_eq!(
            QualityMap::estimate(&g, &QualityParams::default()).unwrap(),
            q
        );
    }

    #[test]
    fn bad_params_and_empty_grids_do_not_panic() {
        let g = OccupancyGrid::new(0.05).unwrap();
        let q = QualityMap::estimate(&g, &QualityParams::default()).unwrap();
        assert_eq!(q.overall(), None);
        for params in [
            QualityParams {
                block_m: 0.0,
                ..QualityParams::default()
            },
            QualityParams {
                saturation_log_odds: f32::NAN,
                ..QualityParams::default()
            },
            QualityParams {
                min_known_fraction: 2.0,
                ..QualityParams::default()
            },
        ] {
            assert!(matches!(
                QualityMap::estimate(&g, &params),
                Err(MergeError::BadParams { .. })
            ));
        }
    }
}
