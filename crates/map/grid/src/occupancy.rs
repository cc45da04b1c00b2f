//! The log-odds occupancy grid (Moravec & Elfes 1985; Thrun et al., *Probabilistic Robotics*,
//! Table 9.1): every cell holds `l = log(p / (1 − p))`, 0 meaning unknown.

use mapmerge_params::{Checker, Real, Validate};
use serde::{Deserialize, Serialize};

use crate::{Cell, GridError, GridGeometry, Point2};

/// Cells added on each side when a grid has to grow (amortises repeated growth).
const GROWTH_MARGIN_CELLS: usize = 64;

/// Largest grid this crate creates (cells); growth beyond it is an error, not an abort.
pub const MAX_CELLS: usize = 1 << 31;

/// `log(p / (1 − p))`.
pub fn log_odds_of(probability: f64) -> f32 {
    (probability / (1.0 - probability)).ln() as f32
}

/// `1 / (1 + exp(−l))`.
pub fn probability_of(log_odds: f32) -> f64 {
    1.0 / (1.0 + (-f64::from(log_odds)).exp())
}

/// What a cell is, after thresholding its occupancy probability.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum CellClass {
    /// Never observed, or observed with too little evidence either way.
    Unknown,
    /// Observed empty.
    Free,
    /// Observed occupied.
    Occupied,
}

/// Probability thresholds for [`CellClass`]: occupied at or above `occupied_min`, free at or
/// below `free_max`, unknown in between (ROS map_server's `occupied_thresh` / `free_thresh`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClassThresholds {
    /// Smallest probability that counts as occupied.
    pub occupied_min: f64,
    /// Largest probability that counts as free.
    pub free_max: f64,
}

impl Default for ClassThresholds {
    /// 0.65 / 0.35: one hit (p = 0.7) makes a cell occupied, two misses make it free.
    fn default() -> Self {
        Self {
            occupied_min: 0.65,
            free_max: 0.35,
        }
    }
}

impl Validate for ClassThresholds {
    /// Both probabilities in [0, 1], `free_max` below `occupied_min`.
    fn check(&self, check: &mut Checker) {
        check
            .real("occupied_min", self.occupied_min, Real::fraction())
            .real("free_max", self.free_max, Real::fraction())
            .rule(
                "free_max",
                self.free_max,
                self.free_max < self.occupied_min,
                "must be below occupied_min",
            );
    }
}

impl ClassThresholds {
    /// The class of a cell with log-odds `log_odds`.
    pub fn classify(&self, log_odds: f32) -> CellClass {
        let p = probability_of(log_odds);
        if p >= self.occupied_min {
            CellClass::Occupied
        } else if p <= self.free_max {
            CellClass::Free
        } else {
            CellClass::Unknown
        }
    }

    /// [`Self::classify`] for many cells in a row: a grid's log-odds come in runs of one
    /// value (unknown, clamped free), so the last value's class is kept and its probability
    /// (an `exp`) not computed again.
    pub fn classifier(&self) -> impl FnMut(f32) -> CellClass + '_ {
        let mut last: Option<(u32, CellClass)> = None;
        move |log_odds| match last {
            Some((bits, class)) if bits == log_odds.to_bits() => class,
            _ => {
                let class = self.classify(log_odds);
                last = Some((log_odds.to_bits(), class));
                class
            }
        }
    }
}

/// The inverse sensor model: log-odds added for a beam ending in a cell (hit) or passing
/// through it (miss), and the clamping bounds that keep cells able to change (OctoMap's
/// defaults, Hornung et al. 2013: 0.7 / 0.4, clamped to [0.12, 0.97]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SensorModel {
    /// Log-odds added where a beam ends.
    pub hit_log_odds: f32,
    /// Log-odds added where a beam passes (negative).
    pub miss_log_odds: f32,
    /// Lower clamp.
    pub min_log_odds: f32,
    /// Upper clamp.
    pub max_log_odds: f32,
}

impl Default for SensorModel {
    fn default() -> Self {
        Self::from_probabilities(0.7, 0.4, 0.12, 0.97)
    }
}

impl SensorModel {
    /// A model from probabilities: hit, miss, clamp minimum, clamp maximum.
    pub fn from_probabilities(hit: f64, miss: f64, clamp_min: f64, clamp_max: f64) -> Self {
        Self {
            hit_log_odds: log_odds_of(hit),
            miss_log_odds: log_odds_of(miss),
            min_log_odds: log_odds_of(clamp_min),
            max_log_odds: log_odds_of(clamp_max),
        }
    }
}

/// A log-odds occupancy grid in some frame (the grid's frame is whatever its user says:
/// `map`, or a node's frame for a local map). Grows on demand; cells outside read unknown.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct OccupancyGrid {
    geometry: GridGeometry,
    log_odds: Vec<f32>,
    /// Scratch for scan insertion: the scan generation that last changed each cell (empty
    /// until the first insertion), a byte per cell that wraps every 255 insertions. Not part
    /// of the grid's value.
    #[serde(skip)]
    marks: Vec<u8>,
    #[serde(skip)]
    generation: u8,
}

impl PartialEq for OccupancyGrid {
    fn eq(&self, other: &Self) -> bool {
        self.geometry == other.geometry && self.log_odds == other.log_odds
    }
}

impl OccupancyGrid {
    /// An empty (zero-cell) grid of `resolution_m` whose cell corners sit on multiples of
    /// the resolution.
    pub fn new(resolution_m: f64) -> Result<Self, GridError> {
        Self::with_geometry(GridGeometry {
            resolution_m,
            origin_m: Point2::zeros(),
            width: 0,
            height: 0,
        })
    }

    /// An all-unknown grid with the given geometry.
    pub fn with_geometry(geometry: GridGeometry) -> Result<Self, GridError> {
        check_geometry(&geometry)?;
        Ok(Self::from_parts(geometry, vec![0.0; geometry.len()]))
    }

    /// A grid from its geometry and row-major log-odds (row 0 at the bottom).
    pub fn from_log_odds(geometry: GridGeometry, log_odds: Vec<f32>) -> Result<Self, GridError> {
        check_geometry(&geometry)?;
        if log_odds.len() != geometry.len() {
            return Err(GridError::SizeMismatch {
                expected: geometry.len(),
                found: log_odds.len(),
            });
        }
        if let Some(index) = log_odds.iter().position(|l| l.is_nan()) {
            return Err(GridError::NotANumber { index });
        }
        Ok(Self::from_parts(geometry, log_odds))
    }

    fn from_parts(geometry: GridGeometry, log_odds: Vec<f32>) -> Self {
        Self {
            geometry,
            log_odds,
            marks: Vec::new(),
            generation: 0,
        }
    }

    /// Starts a new insertion: returns a generation number no cell is marked with yet.
    pub(crate) fn next_generation(&mut self) -> u8 {
        if self.marks.len() != self.log_odds.len() {
            self.marks = vec![0; self.log_odds.len()];
            self.generation = 0;
        } else if self.generation == u8::MAX {
            self.marks.fill(0);
            self.generation = 0;
        }
        self.generation += 1;
        self.generation
    }

    /// The cells and their insertion marks, for [`crate::raycast`].
    pub(crate) fn cells_and_marks(&mut self) -> (&mut [f32], &mut [u8]) {
        (&mut self.log_odds, &mut self.marks)
    }

    /// Frees the insertion scratch (a byte per cell); the next insertion makes it again.
    pub fn release_scratch(&mut self) {
        self.marks = Vec::new();
    }

    /// Size and placement.
    pub fn geometry(&self) -> &GridGeometry {
        &self.geometry
    }

    /// Cell side (m).
    pub fn resolution_m(&self) -> f64 {
        self.geometry.resolution_m
    }

    /// Row-major log-odds (row 0 at the bottom).
    pub fn log_odds(&self) -> &[f32] {
        &self.log_odds
    }

    /// Mutable row-major log-odds.
    pub fn log_odds_mut(&mut self) -> &mut [f32] {
        &mut self.log_odds
    }

    /// Log-odds of `cell`; 0 (unknown) outside the grid.
    pub fn cell_log_odds(&self, cell: Cell) -> f32 {
        self.geometry
            .index_of(cell)
            .and_then(|i| self.log_odds.get(i).copied())
            .unwrap_or(0.0)
    }

    /// Log-odds of the cell containing `p` (0 outside).
    pub fn log_odds_at(&self, p: &Point2) -> f32 {
        self.cell_log_odds(self.geometry.cell_of(p))
    }

    /// Occupancy probability of `cell` (0.5 outside).
    pub fn probability(&self, cell: Cell) -> f64 {
        probability_of(self.cell_log_odds(cell))
    }

    /// Class of `cell` (unknown outside).
    pub fn class(&self, cell: Cell, thresholds: &ClassThresholds) -> CellClass {
        thresholds.classify(self.cell_log_odds(cell))
    }

    /// Class of every cell, row-major.
    pub fn classes(&self, thresholds: &ClassThresholds) -> Vec<CellClass> {
        let mut classify = thresholds.classifier();
        self.log_odds.iter().map(|&l| classify(l)).collect()
    }

    /// Sets the log-odds of `cell`, growing the grid if needed.
    pub fn set(&mut self, cell: Cell, log_odds: f32) -> Result<(), GridError> {
        let index = self.grow_to_cell(cell)?;
        if let Some(slot) = self.log_odds.get_mut(index) {
            *slot = log_odds;
        }
        Ok(())
    }

    /// Every cell as `(cell, centre in the grid frame, log-odds)`, row-major from the bottom.
    pub fn cells(&self) -> impl ExactSizeIterator<Item = (Cell, Point2, f32)> + '_ {
        self.log_odds.iter().enumerate().map(|(index, &l)| {
            let cell = self.geometry.cell_at(index);
            (cell, self.geometry.center_of(cell), l)
        })
    }

    /// Cells whose log-odds is not 0 (observed at least once), as in [`Self::cells`].
    pub fn known_cells(&self) -> impl Iterator<Item = (Cell, Point2, f32)> + '_ {
        self.cells().filter(|&(_, _, l)| l != 0.0)
    }

    /// Grows the grid (keeping every cell's world position) so that it contains the box
    /// `[min_m, max_m]`, with a margin. Returns the shift of old cell coordinates
    /// (`new = old + shift`).
    pub fn grow_to_contain(&mut self, min_m: &Point2, max_m: &Point2) -> Result<Cell, GridError> {
        if !(min_m.iter().chain(max_m.iter()).all(|v| v.is_finite())) {
            return Err(GridError::NotFinite);
        }
        let lo = self.geometry.cell_of(min_m);
        let hi = self.geometry.cell_of(max_m);
        self.grow_to_cells(lo, hi)
    }

    /// Grows so that `cell` (in the current coordinates) is inside; returns its new index.
    fn grow_to_cell(&mut self, cell: Cell) -> Result<usize, GridError> {
        let shift = self.grow_to_cells(cell, cell)?;
        let moved = Cell::new(cell.x + shift.x, cell.y + shift.y);
        self.geometry.index_of(moved).ok_or(GridError::TooLarge)
    }

    /// Grows so that cells `lo..=hi` (current coordinates) are inside; returns the shift.
    pub(crate) fn grow_to_cells(&mut self, lo: Cell, hi: Cell) -> Result<Cell, GridError> {
        let g = self.geometry;
        let Some((grown, shift)) = grown_to_cells(&g, lo, hi)? else {
            return Ok(Cell::new(0, 0));
        };
        let width = grown.width;
        let mut log_odds = vec![0.0f32; grown.len()];
        if !g.is_empty() {
            for row in 0..g.height {
                let dst = (row as i64 + shift.y) as usize * width + shift.x as usize;
                let src = row * g.width;
                if let (Some(dst), Some(src)) = (
                    log_odds.get_mut(dst..dst + g.width),
                    self.log_odds.get(src..src + g.width),
                ) {
                    dst.copy_from_slice(src);
                }
            }
        }
        self.geometry = grown;
        self.log_odds = log_odds;
        self.marks = Vec::new();
        Ok(shift)
    }
}

/// The geometry `g` grows to so that cells `lo..=hi` (its coordinates) are inside, with
/// [`GROWTH_MARGIN_CELLS`] beyond every side that grows, and the shift of its cells; `None`
/// when they are inside already.
pub(crate) fn grown_to_cells(
    g: &GridGeometry,
    lo: Cell,
    hi: Cell,
) -> Result<Option<(GridGeometry, Cell)>, GridError> {
    if g.contains(lo) && g.contains(hi) {
        return Ok(None);
    }
    let margin = GROWTH_MARGIN_CELLS as i64;
    let (old_w, old_h) = (g.width as i64, g.height as i64);
    let (new_lo, new_hi) = if g.is_empty() {
        (
            Cell::new(lo.x - margin, lo.y - margin),
            Cell::new(hi.x + margin, hi.y + margin),
        )
    } else {
        let below = |v: i64| if v < 0 { v - margin } else { 0 };
        let above = |v: i64, size: i64| if v >= size { v + margin } else { size - 1 };
        (
            Cell::new(below(lo.x), below(lo.y)),
            Cell::new(above(hi.x, old_w), above(hi.y, old_h)),
        )
    };
    let width = new_hi
        .x
        .checked_sub(new_lo.x)
        .and_then(|w| w.checked_add(1));
    let height = new_hi
        .y
        .checked_sub(new_lo.y)
        .and_then(|h| h.checked_add(1));
    let (Some(width), Some(height)) = (width, height) else {
        return Err(GridError::TooLarge);
    };
    let cells = (width as u128).saturating_mul(height as u128);
    if width <= 0 || height <= 0 || cells > MAX_CELLS as u128 {
        return Err(GridError::TooLarge);
    }
    let grown = GridGeometry {
        resolution_m: g.resolution_m,
        origin_m: g.origin_m + Point2::new(new_lo.x as f64, new_lo.y as f64) * g.resolution_m,
        width: width as usize,
        height: height as usize,
    };
    Ok(Some((grown, Cell::new(-new_lo.x, -new_lo.y))))
}

fn check_geometry(geometry: &GridGeometry) -> Result<(), GridError> {
    if !(geometry.resolution_m.is_finite() && geometry.resolution_m > 0.0) {
        return Err(GridError::BadResolution(geometry.resolution_m));
    }
    if !geometry.origin_m.iter().all(|v| v.is_finite()) {
        return Err(GridError::NotFinite);
    }
    let cells = (geometry.width as u128).saturating_mul(geometry.height as u128);
    if cells > MAX_CELLS as u128 {
        return Err(GridError::TooLarge);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// The run-keeping classifier gives every cell the class `classify` gives it.
        #[test]
        fn the_classifier_agrees_with_classify(
            values in proptest::collection::vec(
                prop_oneof![Just(0.0f32), Just(-2.0f32), Just(3.5f32), Just(f32::NAN), -5.0f32..5.0],
                0..64,
            ),
            occupied_min in 0.5f64..1.0,
            free_max in 0.0f64..0.5,
        ) {
            let thresholds = ClassThresholds { occupied_min, free_max };
            let mut classify = thresholds.classifier();
            for l in values {
                prop_assert_eq!(classify(l), thresholds.classify(l), "log-odds {}", l);
            }
        }
    }

    #[test]
    fn class_thresholds_are_probabilities_free_below_occupied() {
        assert_eq!(ClassThresholds::default().validate(), Ok(()));
        let field = |t: ClassThresholds| t.validate().map_err(|e| e.field);
        let occupied = |occupied_min| ClassThresholds {
            occupied_min,
            ..ClassThresholds::default()
        };
        assert_eq!(field(occupied(1.5)), Err("occupied_min".into()));
        assert_eq!(field(occupied(f64::NAN)), Err("occupied_min".into()));
        let free = |free_max| ClassThresholds {
            free_max,
            ..ClassThresholds::default()
        };
        assert_eq!(field(free(-0.1)), Err("free_max".into()));
        assert_eq!(field(free(0.65)), Err("free_max".into()));
        assert_eq!(field(free(0.0)), Ok(()));
    }
}
