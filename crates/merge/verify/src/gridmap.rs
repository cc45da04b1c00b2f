//! Gridmap comparison (Holoch et al., Sec. IV-B): a three-state grid of the `n` most recent
//! current-epoch keyframes against one of the other epochs, occupied cells of both dilated
//! by a 7 × 7 square, and `r = |C_contradictions| / |C_overlap|` once the overlap reaches `τ`.
//!
//! The paper builds both grids in the window's bounding box per vertex (42 ms). Here:
//! - the other epochs' grid does not depend on the current epoch, so it is built once per
//!   merge (exact ray casting, `mapmerge-grid`), classified and dilated (`CellMask::dilate`);
//! - the window's grid is kept as per-cell counters (returns, beams through, returns within
//!   the dilation square) on the other grid's lattice, in the tiles of it the window's scans
//!   touch (the other grid's classes are two bits a cell), so a new vertex adds one scan and
//!   removes the one that left the window (walking the cells its insertion recorded, not
//!   tracing its beams again), and the overlap and contradiction counts are updated for the
//!   cells whose class changed. Comparing on all cells known in the window's
//!   grid is the paper's comparison in the bounding box, which contains every such cell;
//!   cells the other epochs never saw cannot overlap and are not stored, and the window's
//!   beams skip them (a bit per cell says which are known);
//! - the other epochs' grid is kept while a re-optimisation only moves them rigidly, and
//!   across a new merge of the same epochs (a conditional merge made full): the window is
//!   then inserted in the grid's frame.
//!
//! The window's grid classes (counter form of "hits win", as `mapmerge-grid` within a scan):
//! occupied when any window scan returned from a cell (after dilation: from any cell of the
//! square), free when beams passed through and none returned, unknown otherwise.
//!
//! Unknown space: a cell the other epochs never saw is unknown in their grid, so the window's
//! beams through it neither agree nor contradict; only cells known in both count. When the
//! robot's scans cross only such space (it left the merged map, or the merge put it where the
//! merged map has no structure) the overlap stays below `τ`: the ratio is 0 and the merge is
//! *unsupported* ([`RatioSupport::Unsupported`]), not valid.

use std::f64::consts::PI;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{CellClass, ClassThresholds, GridGeometry, InsertParams, OccupancyGrid};
use mapmerge_params::{Checker, Real, Validate};
use mapmerge_posegraph::NodeId;
use mapmerge_scan::Point2;
use serde::{Deserialize, Serialize};

use crate::common::{moved, recent, unit, OtherSnapshot};
use crate::{DetectorScan, InvalidMergeDetector, MergedMap, RatioSupport};

/// Parameters of [`GridmapDetector`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GridmapParams {
    /// `n`: the most recent current-epoch keyframes in the window (default: 10).
    pub recent_scans: usize,
    /// Cell side (m) (default: 0.025, the paper's). The other epochs' extent at this
    /// resolution is held in memory (a quarter byte a cell, and 12 bytes a cell in the
    /// tiles the window's scans touch); see `max_cells`.
    pub cell_m: f64,
    /// Dilation radius (cells) of occupied cells in both grids (default: 3, the paper's 7 × 7
    /// square; at most 20). Larger forgives more misalignment of correct merges, and hides
    /// more of a wrong merge's crossing walls.
    pub dilation_radius_cells: usize,
    /// `τ`: below this overlap (m², cells known in both grids) the ratio is 0 (default: 2).
    /// A few cells of overlap (the first scan after a merge seeing through a door) are no
    /// evidence either way.
    pub min_overlap_m2: f64,
    /// Beams longer than this (m) are not used (default: 40).
    pub max_range_m: f64,
    /// Classes of the other epochs' log-odds grid (default: occupied from p = 0.65, free up
    /// to p = 0.45, so that a cell one beam passed through is free, as in the window's grid).
    pub other_thresholds: ClassThresholds,
    /// A window scan is re-inserted when its pose moved more than this (m) (default: 0.05);
    /// the other epochs' grid is rebuilt when one of their poses did.
    pub cache_translation_m: f64,
    /// … or turned more than this (rad) (default: 0.5°).
    pub cache_rotation_rad: f64,
    /// Largest grid (cells); a larger extent gets coarser cells (default: 2²⁴, 100 × 160 m
    /// at 2.5 cm; at most 2²⁸).
    pub max_cells: usize,
}

impl Default for GridmapParams {
    fn default() -> Self {
        Self {
            recent_scans: 10,
            cell_m: 0.025,
            dilation_radius_cells: 3,
            min_overlap_m2: 2.0,
            max_range_m: 40.0,
            other_thresholds: ClassThresholds {
                occupied_min: 0.65,
                free_max: 0.45,
            },
            cache_translation_m: 0.05,
            cache_rotation_rad: 0.5f64.to_radians(),
            max_cells: 1 << 24,
        }
    }
}

impl Validate for GridmapParams {
    fn check(&self, check: &mut Checker) {
        check
            .size("recent_scans", self.recent_scans, 1, 100_000)
            .real("cell_m", self.cell_m, Real::positive())
            .size("dilation_radius_cells", self.dilation_radius_cells, 0, 20)
            .real("min_overlap_m2", self.min_overlap_m2, Real::non_negative())
            .real("max_range_m", self.max_range_m, Real::positive())
            .nested("other_thresholds", &self.other_thresholds)
            .real(
                "cache_translation_m",
                self.cache_translation_m,
                Real::non_negative(),
            )
            .real(
                "cache_rotation_rad",
                self.cache_rotation_rad,
                Real::within(0.0, PI),
            )
            .size("max_cells", self.max_cells, 1, 1 << 28);
    }
}

/// Most cells a canvas stores (padded to whole tiles), so that a storage index fits in the
/// `u32` of [`ScanCells::missed`]; `max_cells` is held to half of it.
const MAX_STORED_CELLS: usize = 1 << 31;

const UNKNOWN: u8 = 0;
const FREE: u8 = 1;
const OCCUPIED: u8 = 2;

/// What the last call compared.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct GridmapInfo {
    /// `|C_overlap|`: cells known in both grids.
    pub overlap_cells: u64,
    /// `|C_contradictions|`: free in one, occupied in the other.
    pub contradiction_cells: u64,
    /// Scans inserted into (or removed from) the window's grid in the last call.
    pub updated_scans: usize,
}

/// A window scan as inserted: where it was, and the cells its beams changed, so that it is
/// removed exactly without tracing its beams again.
#[derive(Clone, Debug)]
struct Inserted {
    node: NodeId,
    pose: Se2,
    cells: ScanCells,
}

/// The cells one scan's beams changed in the window's grid.
#[derive(Clone, Debug, Default)]
struct ScanCells {
    /// Storage index of every known cell a beam passed through, once per beam.
    missed: Vec<u32>,
    /// Every cell `(x, y)` a beam returned from, once per beam.
    returned: Vec<(u32, u32)>,
}

impl ScanCells {
    fn clear(&mut self) {
        self.missed.clear();
        self.returned.clear();
    }
}

/// Where cell `(x, y)` of a grid is stored: in 32 × 32 tiles (8 KB of cell records), row by
/// row of tiles, each tile row by row. At 2.5 cm a grid row of records spans several memory
/// pages, so a beam stepping across rows touched a new page at every step; within a tile it
/// touches two. The per-cell record loads were the gridmap's cost (freiburg-campus, one
/// core, same run: 1.04 ms per new vertex row-major, 1.04 with 4 × 4 tiles, 0.91 with
/// 16 × 16, 0.90 with 32 × 32).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct TileLattice {
    tiles_wide: usize,
}

impl TileLattice {
    const SIDE_BITS: u32 = 5;
    const SIDE: usize = 1 << Self::SIDE_BITS;
    const MASK: usize = Self::SIDE - 1;

    /// The lattice of a `width` × `height` grid, and the number of cells it stores
    /// (the grid padded to whole tiles).
    fn new(width: usize, height: usize) -> (Self, usize) {
        let (tiles_wide, tiles_high) = (width.div_ceil(Self::SIDE), height.div_ceil(Self::SIDE));
        (
            Self { tiles_wide },
            tiles_wide * tiles_high * Self::SIDE * Self::SIDE,
        )
    }

    /// Storage index of cell `(x, y)` (non-negative, inside the grid).
    #[inline]
    fn index(&self, x: usize, y: usize) -> usize {
        let tile = (y >> Self::SIDE_BITS) * self.tiles_wide + (x >> Self::SIDE_BITS);
        (tile << (2 * Self::SIDE_BITS)) | ((y & Self::MASK) << Self::SIDE_BITS) | (x & Self::MASK)
    }
}

/// Cells of one tile (see [`TileLattice`]).
const TILE_CELLS: usize = TileLattice::SIDE * TileLattice::SIDE;

/// `Canvas::slot_of_tile` of a tile without window counters.
const NO_SLOT: u32 = u32::MAX;

/// The two grids on one lattice. The other epochs' classes are two bits a cell over the
/// whole grid; the window's counters exist only in the tiles its scans touch (a window of
/// `n` scans covers a small part of a campus-sized grid: 2²⁴ cells of counters were 200 MB).
#[derive(Debug, Default)]
struct Canvas {
    geometry: Option<GridGeometry>,
    lattice: TileLattice,
    /// One bit per cell (storage order): the other epochs know it (not unknown). A beam's
    /// misses in cells they never saw change nothing (no overlap either way), so those cells
    /// are not touched: the bit set (2 MB at most) stays in cache while counters would not.
    known: Vec<u64>,
    /// One bit per cell: the other epochs' dilated class is occupied (else free, if known).
    occupied: Vec<u64>,
    /// Per tile: its slot in `tiles`, or [`NO_SLOT`].
    slot_of_tile: Vec<u32>,
    /// The window's counters of the tiles it touched since the last sweep.
    tiles: Vec<Box<WindowTile>>,
    /// Slots in use after the last sweep of empty tiles.
    live_after_sweep: usize,
    radius: i64,
    overlap: u64,
    contradictions: u64,
}

/// The window's counters of one tile, in storage order.
#[derive(Debug)]
struct WindowTile {
    /// The tile's index in the lattice.
    tile: usize,
    cells: [CellState; TILE_CELLS],
    /// Window: returns per cell.
    hits: [u32; TILE_CELLS],
}

impl WindowTile {
    /// Every counter is 0: dropping the tile changes no class.
    fn is_empty(&self) -> bool {
        self.hits.iter().all(|&h| h == 0) && self.cells.iter().all(|c| c.misses == 0 && c.near == 0)
    }
}

/// One cell of the window's grid (one 8-byte record, so a beam step touches one record).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct CellState {
    /// Window: beams through the cell.
    misses: u32,
    /// Window: cells with returns within the dilation square.
    near: u16,
    /// The other epochs' dilated class (copied from the bit sets).
    other: u8,
}

impl CellState {
    #[inline]
    fn window_class(&self) -> u8 {
        if self.near > 0 {
            OCCUPIED
        } else if self.misses > 0 {
            FREE
        } else {
            UNKNOWN
        }
    }
}

#[inline]
fn contribution(a: u8, b: u8) -> (u64, u64) {
    let overlap = u64::from(a != UNKNOWN && b != UNKNOWN);
    let contradiction = u64::from((a == FREE && b == OCCUPIED) || (a == OCCUPIED && b == FREE));
    (overlap, contradiction)
}

#[inline]
fn bit(bits: &[u64], i: usize) -> bool {
    bits.get(i >> 6).is_some_and(|w| (w >> (i & 63)) & 1 == 1)
}

impl Canvas {
    /// The other epochs' dilated class of cell `i` (storage index).
    #[inline]
    fn other_class(&self, i: usize) -> u8 {
        if !bit(&self.known, i) {
            UNKNOWN
        } else if bit(&self.occupied, i) {
            OCCUPIED
        } else {
            FREE
        }
    }

    /// The window's class of cell `i`.
    #[cfg(test)]
    fn window_class(&self, i: usize) -> u8 {
        let slot = self.slot_of_tile.get(i / TILE_CELLS).copied();
        match slot.and_then(|s| self.tiles.get(s as usize)) {
            Some(tile) => tile.cells[i % TILE_CELLS].window_class(),
            None => UNKNOWN,
        }
    }

    /// The counters of cell `i`'s tile, made (all 0) when the window first touches it.
    #[inline]
    fn tile_mut(&mut self, i: usize) -> Option<&mut WindowTile> {
        let tile = i / TILE_CELLS;
        let slot = *self.slot_of_tile.get(tile)?;
        if slot == NO_SLOT {
            let mut fresh = Box::new(WindowTile {
                tile,
                cells: [CellState::default(); TILE_CELLS],
                hits: [0; TILE_CELLS],
            });
            for (k, cell) in fresh.cells.iter_mut().enumerate() {
                cell.other = self.other_class(tile * TILE_CELLS + k);
            }
            let slot = u32::try_from(self.tiles.len()).ok()?;
            *self.slot_of_tile.get_mut(tile)? = slot;
            self.tiles.push(fresh);
            return self.tiles.last_mut().map(|t| &mut **t);
        }
        self.tiles.get_mut(slot as usize).map(|t| &mut **t)
    }

    /// Adds the change of one cell's window class against its other class to the totals.
    #[inline]
    fn account(&mut self, before: u8, after: u8, other: u8) {
        if before == after || other == UNKNOWN {
            return;
        }
        let (o0, c0) = contribution(before, other);
        let (o1, c1) = contribution(after, other);
        self.overlap = self.overlap.wrapping_sub(o0).wrapping_add(o1);
        self.contradictions = self.contradictions.wrapping_sub(c0).wrapping_add(c1);
    }

    /// One beam more (or less) through cell `i` (known to the other epochs). The class
    /// changes only when the count leaves or reaches 0 and no return is near (the hot path:
    /// a slot load, a record load and a store).
    #[inline]
    fn miss(&mut self, i: usize, add: bool) {
        let Some(tile) = self.tile_mut(i) else {
            return;
        };
        let cell = &mut tile.cells[i % TILE_CELLS];
        let before = cell.misses;
        cell.misses = if add {
            before.wrapping_add(1)
        } else {
            before.wrapping_sub(1)
        };
        let toggled = if add { before == 0 } else { before == 1 };
        if !toggled || cell.near > 0 {
            return;
        }
        let other = cell.other;
        let (without, with) = (UNKNOWN, FREE);
        if add {
            self.account(without, with, other);
        } else {
            self.account(with, without, other);
        }
    }

    /// One return more (or less) within the dilation square of cell `j`.
    #[inline]
    fn near(&mut self, j: usize, add: bool) {
        let Some(tile) = self.tile_mut(j) else {
            return;
        };
        let cell = &mut tile.cells[j % TILE_CELLS];
        let before = cell.window_class();
        cell.near = if add {
            cell.near.wrapping_add(1)
        } else {
            cell.near.wrapping_sub(1)
        };
        let (after, other) = (cell.window_class(), cell.other);
        self.account(before, after, other);
    }

    /// One return more (or less) in cell `(x, y)`.
    fn hit(&mut self, x: usize, y: usize, add: bool) {
        let Some(geometry) = self.geometry else {
            return;
        };
        let lattice = self.lattice;
        let Some(tile) = self.tile_mut(lattice.index(x, y)) else {
            return;
        };
        let h = &mut tile.hits[lattice.index(x, y) % TILE_CELLS];
        let was = *h > 0;
        *h = if add {
            h.wrapping_add(1)
        } else {
            h.wrapping_sub(1)
        };
        if was == (*h > 0) {
            return;
        }
        // The cell started or stopped returning: its dilation square changes. Cells the
        // other epochs never saw cannot overlap; their counters are not kept.
        let (w, h) = (geometry.width as i64, geometry.height as i64);
        let (cx, cy) = (x as i64, y as i64);
        let r = self.radius;
        for y in (cy - r).max(0)..=(cy + r).min(h - 1) {
            for x in (cx - r).max(0)..=(cx + r).min(w - 1) {
                let j = lattice.index(x as usize, y as usize);
                if bit(&self.known, j) {
                    self.near(j, add);
                }
            }
        }
    }

    /// Sweeps once the tiles in use have doubled since the last sweep (amortised: the
    /// window's tiles, not the path's, stay in memory).
    fn sweep_when_grown(&mut self) {
        if self.tiles.len() >= (2 * self.live_after_sweep).max(64) {
            self.sweep();
        }
    }

    /// Drops the tiles whose counters all went back to 0.
    fn sweep(&mut self) {
        self.tiles.retain(|t| !t.is_empty());
        self.slot_of_tile.fill(NO_SLOT);
        for (slot, t) in self.tiles.iter().enumerate() {
            if let Some(s) = self.slot_of_tile.get_mut(t.tile) {
                *s = slot as u32;
            }
        }
        self.live_after_sweep = self.tiles.len();
    }

    /// Adds the beams of `points_in_robot` taken at `map_from_robot`, and records in `changed`
    /// (cleared first) the cells they changed.
    fn insert_scan(
        &mut self,
        map_from_robot: &Se2,
        points_in_robot: &[Point2],
        max_range_m: f64,
        changed: &mut ScanCells,
    ) {
        changed.clear();
        let Some(geometry) = self.geometry else {
            return;
        };
        if !map_from_robot.is_finite() {
            return;
        }
        let rotation = map_from_robot.rotation_matrix();
        let origin = map_from_robot.translation();
        let to_cells = |p: &Point2| (p - geometry.origin_m) / geometry.resolution_m;
        let start = to_cells(&origin);
        let size = Point2::new(geometry.width as f64, geometry.height as f64);
        let lattice = self.lattice;
        for p in points_in_robot {
            let range = p.norm();
            if !(range.is_finite() && range > 0.0 && range <= max_range_m) {
                continue;
            }
            let end = to_cells(&(rotation * p + origin));
            let Some((from, to, end_inside)) = clip(start, end, size) else {
                continue;
            };
            // Misses along the beam (the end cell excluded when it is the return; cells the
            // other epochs never saw skipped), then the return. Storage indices fit in u32
            // (`MAX_STORED_CELLS`).
            mapmerge_grid::traverse_cells(from, to, end_inside, |x, y| {
                let i = lattice.index(x as usize, y as usize);
                if bit(&self.known, i) {
                    self.miss(i, true);
                    changed.missed.push(i as u32);
                }
            });
            if end_inside {
                let (x, y) = (end.x.floor() as u32, end.y.floor() as u32);
                self.hit(x as usize, y as usize, true);
                changed.returned.push((x, y));
            }
        }
    }

    /// Takes out a scan whose insertion changed `cells`.
    fn remove_scan(&mut self, cells: &ScanCells) {
        for &i in &cells.missed {
            self.miss(i as usize, false);
        }
        for &(x, y) in &cells.returned {
            self.hit(x as usize, y as usize, false);
        }
    }
}

/// Clips the segment `a → b` (cell units) to `[0, size)`; returns the clipped ends and
/// whether `b` itself is inside.
fn clip(a: Point2, b: Point2, size: Point2) -> Option<(Point2, Point2, bool)> {
    // Stay a hair inside the upper borders so that floor() gives a valid cell.
    let hi = size - Point2::repeat(1e-9);
    let inside = |p: &Point2| p.x >= 0.0 && p.y >= 0.0 && p.x <= hi.x && p.y <= hi.y;
    let b_inside = inside(&b);
    if inside(&a) && b_inside {
        return Some((a, b, true));
    }
    // Liang–Barsky.
    let d = b - a;
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [
        (-d.x, a.x),
        (d.x, hi.x - a.x),
        (-d.y, a.y),
        (d.y, hi.y - a.y),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
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
    if t0.is_nan() || t1.is_nan() || t0 > t1 {
        return None;
    }
    let from = a + d * t0;
    let to = a + d * t1;
    Some((
        from.sup(&Point2::zeros()).inf(&hi),
        to.sup(&Point2::zeros()).inf(&hi),
        b_inside,
    ))
}

/// Gridmap comparison (Holoch et al., Sec. IV-B); see the module documentation.
#[derive(Debug)]
pub struct GridmapDetector {
    params: GridmapParams,
    snapshot: Option<OtherSnapshot>,
    /// The canvas' frame from the map frame: identity when built, then the inverse of the
    /// merged epochs' rigid motion since (so that a re-optimisation that only shifts them as
    /// a whole costs re-inserting the window, not rebuilding their grid).
    canvas_from_map: Se2,
    canvas: Canvas,
    inserted: Vec<Inserted>,
    info: GridmapInfo,
    /// How many times the other epochs' grid was built.
    other_builds: usize,
}

impl Default for GridmapDetector {
    fn default() -> Self {
        Self {
            params: GridmapParams::default(),
            snapshot: None,
            canvas_from_map: Se2::identity(),
            canvas: Canvas::default(),
            inserted: Vec::new(),
            info: GridmapInfo::default(),
            other_builds: 0,
        }
    }
}

impl GridmapDetector {
    /// A detector with `params`.
    pub fn new(params: GridmapParams) -> Self {
        Self {
            params,
            ..Self::default()
        }
    }

    /// Its parameters.
    pub fn params(&self) -> &GridmapParams {
        &self.params
    }

    /// What the last [`InvalidMergeDetector::on_vertex`] compared.
    pub fn info(&self) -> GridmapInfo {
        self.info
    }

    /// The last overlap reached `τ` (Sec. IV-B): below it the ratio is 0 and no evidence.
    fn overlap_reaches_tau(&self) -> bool {
        let cell_m = self.canvas.geometry.map_or(1.0, |g| g.resolution_m);
        let overlap = self.info.overlap_cells;
        overlap > 0 && (overlap as f64) * cell_m * cell_m >= self.params.min_overlap_m2
    }

    fn max_range_m(&self) -> f64 {
        if self.params.max_range_m.is_finite() {
            self.params.max_range_m.max(0.0)
        } else {
            40.0
        }
    }

    /// The other epochs' grid: kept while they only moved as a whole (the window is then
    /// inserted in the grid's frame), rebuilt when they changed or deformed.
    fn keep_or_rebuild(&mut self, other: &[DetectorScan]) {
        let (t, r) = (
            self.params.cache_translation_m,
            self.params.cache_rotation_rad,
        );
        match self
            .snapshot
            .as_ref()
            .and_then(|s| s.rigid_motion(other, t, r))
        {
            Some(now_from_then) => self.canvas_from_map = now_from_then.inverse(),
            None => self.prepare(other),
        }
    }

    /// The other epochs' grid, classified and dilated, and an empty window grid on its lattice.
    fn prepare(&mut self, other: &[DetectorScan]) {
        self.snapshot = Some(OtherSnapshot::new(other));
        self.other_builds += 1;
        self.canvas_from_map = Se2::identity();
        self.inserted.clear();
        self.canvas = Canvas::default();
        let max_range_m = self.max_range_m();
        let mut cell_m = if self.params.cell_m.is_finite() && self.params.cell_m > 0.0 {
            self.params.cell_m
        } else {
            0.025
        };
        // 1. Extent, and a coarser cell if it would be too large.
        let (mut lo, mut hi) = (
            Point2::repeat(f64::INFINITY),
            Point2::repeat(f64::NEG_INFINITY),
        );
        let mut beams: Vec<(Point2, Vec<Point2>)> = Vec::with_capacity(other.len());
        for scan in other {
            let pose = &scan.map_from_robot;
            if !pose.is_finite() {
                continue;
            }
            let origin = pose.translation();
            let ends: Vec<Point2> = scan
                .points_in_robot
                .iter()
                .filter(|p| p.norm() <= max_range_m && p.norm() > 0.0)
                .map(|p| pose.transform_point(p))
                .collect();
            lo = ends.iter().fold(lo.inf(&origin), |l, e| l.inf(e));
            hi = ends.iter().fold(hi.sup(&origin), |h, e| h.sup(e));
            beams.push((origin, ends));
        }
        if !(lo.x <= hi.x && lo.y <= hi.y) {
            return;
        }
        let extent = hi - lo;
        let max_cells = self.params.max_cells.clamp(1, MAX_STORED_CELLS / 2) as f64;
        if (extent.x / cell_m + 2.0) * (extent.y / cell_m + 2.0) > max_cells {
            cell_m = ((extent.x + 1.0) * (extent.y + 1.0) / max_cells).sqrt() * 1.01;
        }
        // 2. The other epochs' log-odds grid by exact ray casting (`mapmerge-grid`).
        // Made at once as large as the insertions grow it (a campus-sized grid is not copied
        // as it grows); when that fails, grown scan by scan.
        let boxes = beams
            .iter()
            .filter(|(_, ends)| !ends.is_empty())
            .map(|(origin, ends)| {
                ends.iter()
                    .fold((*origin, *origin), |(l, h), e| (l.inf(e), h.sup(e)))
            });
        let Ok(mut grid) =
            OccupancyGrid::sized_for(cell_m, boxes).or_else(|_| OccupancyGrid::new(cell_m))
        else {
            return;
        };
        let model = InsertParams::default().model;
        for (origin, ends) in &beams {
            // A scan that cannot be inserted (it would exceed the grid's limits) is skipped.
            let _ = grid.insert_rays(origin, ends, &[], &model);
        }
        drop(beams);
        grid.release_scratch();
        // 3. Classes, occupied dilated (Sec. IV-B: 7 × 7). The log-odds go before the
        // canvas is made: on a campus-sized map each is tens of MB.
        let radius = self.params.dilation_radius_cells.min(20);
        let thresholds = &self.params.other_thresholds;
        let occupied = grid.mask(CellClass::Occupied, thresholds).dilate(radius);
        let free = grid.mask(CellClass::Free, thresholds);
        let geometry = *grid.geometry();
        drop(grid);
        let (lattice, stored) = TileLattice::new(geometry.width, geometry.height);
        if stored > MAX_STORED_CELLS {
            return;
        }
        let mut known = vec![0u64; stored.div_ceil(64)];
        let mut occupied_bits = vec![0u64; stored.div_ceil(64)];
        let classes = occupied.flags().iter().zip(free.flags());
        for (row_major, (&o, &f)) in classes.enumerate() {
            if !(o || f) {
                continue;
            }
            let (x, y) = (row_major % geometry.width, row_major / geometry.width);
            let i = lattice.index(x, y);
            if let (Some(k), Some(w)) = (known.get_mut(i >> 6), occupied_bits.get_mut(i >> 6)) {
                *k |= 1 << (i & 63);
                *w |= u64::from(o) << (i & 63);
            }
        }
        drop((occupied, free));
        self.canvas = Canvas {
            geometry: Some(geometry),
            lattice,
            known,
            occupied: occupied_bits,
            slot_of_tile: vec![NO_SLOT; stored / TILE_CELLS],
            tiles: Vec::new(),
            live_after_sweep: 0,
            radius: radius as i64,
            overlap: 0,
            contradictions: 0,
        };
    }
}

impl InvalidMergeDetector for GridmapDetector {
    fn name(&self) -> &'static str {
        "gridmap"
    }

    /// A new merge of the same epochs, moved at most rigidly (a conditional merge made full)
    /// keeps their grid and the window, as a new vertex would; other merges rebuild.
    fn on_merge(&mut self, map: &MergedMap<'_>) {
        self.keep_or_rebuild(map.other);
        self.info = GridmapInfo::default();
    }

    fn on_vertex(&mut self, map: &MergedMap<'_>) -> f64 {
        let (t, r) = (
            self.params.cache_translation_m,
            self.params.cache_rotation_rad,
        );
        // 1. The other epochs' grid.
        self.keep_or_rebuild(map.other);
        let canvas_from_map = self.canvas_from_map;
        // 2. The window: remove scans that left it or moved, insert new and moved ones.
        let window = recent(map.current, self.params.recent_scans);
        let max_range_m = self.max_range_m();
        let mut updated = 0;
        let mut inserted = std::mem::take(&mut self.inserted);
        // The cell lists of removed scans, reused for the inserted ones.
        let mut spare: Vec<ScanCells> = Vec::new();
        inserted.retain_mut(|e| {
            let keep = window.iter().any(|s| {
                s.node == e.node
                    && !moved(&e.pose, &canvas_from_map.compose(&s.map_from_robot), t, r)
            });
            if !keep {
                self.canvas.remove_scan(&e.cells);
                spare.push(std::mem::take(&mut e.cells));
                updated += 1;
            }
            keep
        });
        for scan in window {
            if !scan.map_from_robot.is_finite() || inserted.iter().any(|e| e.node == scan.node) {
                continue;
            }
            let canvas_from_robot = canvas_from_map.compose(&scan.map_from_robot);
            let mut cells = spare.pop().unwrap_or_default();
            self.canvas.insert_scan(
                &canvas_from_robot,
                &scan.points_in_robot,
                max_range_m,
                &mut cells,
            );
            inserted.push(Inserted {
                node: scan.node,
                pose: canvas_from_robot,
                cells,
            });
            updated += 1;
        }
        self.inserted = inserted;
        self.canvas.sweep_when_grown();
        // 3. r = |C_contradictions| / |C_overlap| from τ on (Sec. IV-B).
        let (overlap, contradictions) = (self.canvas.overlap, self.canvas.contradictions);
        self.info = GridmapInfo {
            overlap_cells: overlap,
            contradiction_cells: contradictions,
            updated_scans: updated,
        };
        if !self.overlap_reaches_tau() {
            return 0.0;
        }
        unit(contradictions as f64 / overlap as f64)
    }

    fn support(&self) -> Option<u64> {
        Some(self.info.overlap_cells)
    }

    /// Unsupported below `τ` of overlap: the window's scans crossed only space the merged
    /// epochs never saw (their grid is unknown there), so nothing could contradict them.
    fn evidence(&self) -> RatioSupport {
        if self.overlap_reaches_tau() {
            RatioSupport::Supported
        } else {
            RatioSupport::Unsupported
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testworld::{wrong_shifted, wrong_turned, Case, World};

    /// The counters, recomputed from scratch: the incremental totals must equal them.
    fn totals_from_scratch(c: &Canvas) -> (u64, u64) {
        let (mut o, mut k) = (0, 0);
        // Every stored cell (the grid padded to whole tiles) has one bit.
        for i in 0..c.known.len() * 64 {
            let (a, b) = contribution(c.window_class(i), c.other_class(i));
            o += a;
            k += b;
        }
        (o, k)
    }

    #[test]
    fn office_merges_correct_low_wrong_high_closed_door_low() {
        let (open, closed) = (World::office(false), World::office(true));
        let identity = Se2::identity();
        let run = |case: Case| case.max_ratio(&mut GridmapDetector::default());
        let correct = run(Case::office(&open, &open, &identity));
        let door = run(Case::office(&open, &closed, &identity));
        let turned = run(Case::office(&open, &open, &wrong_turned()));
        let shifted = run(Case::office(&open, &open, &wrong_shifted()));
        assert!(correct < 0.03, "correct {correct}");
        assert!(door < 0.05, "closed door {door}");
        assert!(turned > 0.1, "turned {turned}");
        assert!(shifted > door.max(correct) + 0.02, "shifted {shifted}");
    }

    #[test]
    fn incremental_counts_equal_a_recount_and_removal_is_exact() {
        let open = World::office(false);
        let case = Case::office(&open, &open, &wrong_turned());
        let mut d = GridmapDetector::default();
        d.on_merge(&MergedMap {
            current: &case.current[..1],
            other: &case.other,
        });
        for k in 1..=case.current.len() {
            d.on_vertex(&MergedMap {
                current: &case.current[..k],
                other: &case.other,
            });
            assert_eq!(
                (d.canvas.overlap, d.canvas.contradictions),
                totals_from_scratch(&d.canvas)
            );
        }
        // Moving a window scan re-inserts it; an empty window leaves no trace.
        let mut moved_current = case.current.clone();
        let last = moved_current.len() - 1;
        moved_current[last].map_from_robot =
            Se2::new(0.3, 0.0, 0.0).compose(&moved_current[last].map_from_robot);
        d.on_vertex(&MergedMap {
            current: &moved_current,
            other: &case.other,
        });
        assert_eq!(d.info().updated_scans, 2);
        assert_eq!(
            (d.canvas.overlap, d.canvas.contradictions),
            totals_from_scratch(&d.canvas)
        );
        d.on_vertex(&MergedMap {
            current: &[],
            other: &case.other,
        });
        assert_eq!((d.canvas.overlap, d.canvas.contradictions), (0, 0));
        assert!(d.canvas.tiles.iter().all(|t| t.is_empty()));
    }

    /// Dropping the tiles whose counters went back to 0 changes no count and no ratio, and
    /// leaves only the window's tiles.
    #[test]
    fn sweeping_empty_tiles_changes_nothing() {
        let open = World::office(false);
        let case = Case::office(&open, &open, &wrong_turned());
        let (mut kept, mut swept) = (GridmapDetector::default(), GridmapDetector::default());
        let first = MergedMap {
            current: &case.current[..1],
            other: &case.other,
        };
        kept.on_merge(&first);
        swept.on_merge(&first);
        let mut dropped = 0;
        for k in 1..=case.current.len() {
            let map = MergedMap {
                current: &case.current[..k],
                other: &case.other,
            };
            let (a, b) = (kept.on_vertex(&map), swept.on_vertex(&map));
            let before = swept.canvas.tiles.len();
            swept.canvas.sweep();
            dropped += before - swept.canvas.tiles.len();
            assert!(swept.canvas.tiles.iter().all(|t| !t.is_empty()));
            assert_eq!(a, b, "vertex {k}");
            assert_eq!(
                (swept.canvas.overlap, swept.canvas.contradictions),
                totals_from_scratch(&swept.canvas)
            );
            assert_eq!(
                (swept.canvas.overlap, swept.canvas.contradictions),
                (kept.canvas.overlap, kept.canvas.contradictions)
            );
        }
        assert!(dropped > 0, "the window never left a tile");
    }

    /// A second merge of the same epochs (a conditional merge made full) keeps their grid
    /// and the window, and reads what a fresh detector reads; a merge of other epochs
    /// builds a new grid.
    #[test]
    fn a_merge_of_the_same_epochs_keeps_their_grid() {
        let open = World::office(false);
        let case = Case::office(&open, &open, &wrong_turned());
        case.builds_once_per_merged_epochs(|d: &GridmapDetector| d.other_builds, |_, _| {});
    }

    /// Every cell of a grid has its own storage index, inside the padded storage.
    #[test]
    fn the_tile_lattice_stores_every_cell_once() {
        for (width, height) in [(1, 1), (31, 33), (64, 32), (100, 7)] {
            let (lattice, stored) = TileLattice::new(width, height);
            let mut seen = vec![false; stored];
            for y in 0..height {
                for x in 0..width {
                    let i = lattice.index(x, y);
                    assert!(
                        i < stored && !seen[i],
                        "{width}x{height}: ({x}, {y}) -> {i}"
                    );
                    seen[i] = true;
                }
            }
        }
    }

    /// A re-optimisation that moves the whole merged map (both epochs) rigidly keeps the
    /// grid (no rebuild, the canvas frame follows) and gives the ratios it gave before.
    #[test]
    fn a_rigid_motion_of_everything_changes_nothing() {
        let open = World::office(false);
        let case = Case::office(&open, &open, &wrong_turned());
        let motion = Se2::new(3.0, -2.0, 0.7);
        let moved = |scans: &[DetectorScan]| -> Vec<DetectorScan> {
            scans
                .iter()
                .map(|s| DetectorScan {
                    map_from_robot: motion.compose(&s.map_from_robot),
                    ..s.clone()
                })
                .collect()
        };
        let (other_moved, current_moved) = (moved(&case.other), moved(&case.current));
        let mut still = GridmapDetector::default();
        let mut shifted = GridmapDetector::default();
        let first = MergedMap {
            current: &case.current[..1],
            other: &case.other,
        };
        still.on_merge(&first);
        shifted.on_merge(&first);
        for k in 1..=case.current.len() {
            let a = still.on_vertex(&MergedMap {
                current: &case.current[..k],
                other: &case.other,
            });
            // From the fifth vertex on, everything has moved.
            let (current, other) = if k >= 5 {
                (&current_moved, &other_moved)
            } else {
                (&case.current, &case.other)
            };
            let b = shifted.on_vertex(&MergedMap {
                current: &current[..k],
                other,
            });
            // The same up to cells flipped by rounding (the test world's walls lie on cell
            // borders, and the motion is estimated to ~1e-15).
            assert!((a - b).abs() < 0.02, "vertex {k}: {a} vs {b}");
            let (o1, o2) = (still.info().overlap_cells, shifted.info().overlap_cells);
            assert!(
                o1.abs_diff(o2) * 50 <= o1.max(1),
                "vertex {k}: {o1} vs {o2}"
            );
        }
        assert!(shifted.canvas_from_map.translation().norm() > 1.0);
    }

    #[test]
    fn degenerate_input_gives_zero() {
        use std::sync::Arc;
        let mut d = GridmapDetector::default();
        let weird = [
            DetectorScan {
                node: NodeId(1),
                epoch: 1,
                map_from_robot: Se2::identity(),
                points_in_robot: Arc::from(vec![]),
            },
            DetectorScan {
                node: NodeId(2),
                epoch: 1,
                map_from_robot: Se2::identity(),
                points_in_robot: Arc::from(vec![
                    Point2::new(f64::NAN, 0.0),
                    Point2::new(1e300, 1.0),
                    Point2::zeros(),
                ]),
            },
            DetectorScan {
                node: NodeId(3),
                epoch: 1,
                map_from_robot: Se2::new(f64::INFINITY, 0.0, 0.0),
                points_in_robot: Arc::from(vec![Point2::new(1.0, 0.0)]),
            },
        ];
        let map = MergedMap {
            current: &weird,
            other: &weird,
        };
        d.on_merge(&map);
        assert_eq!(d.on_vertex(&map), 0.0);
        let map = MergedMap {
            current: &weird,
            other: &[],
        };
        d.on_merge(&map);
        assert_eq!(d.on_vertex(&map), 0.0);
    }
}
