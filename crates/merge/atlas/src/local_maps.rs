//! Local maps: occupancy grids anchored at vertices, rendered into one map per graph (iRobot,
//! Sec. 3.3 and 4.3: "a collection of overlapping local maps, which are anchored to nodes in
//! the pose graph"; rendering "collapses" them into a global occupancy map).
//!
//! The atlas keeps one local map per tracker submap, built from the submap's keyframes when
//! the session ends. Afterwards the map no longer needs those keyframes: views can be pruned
//! for relocalisation's sake alone (Sec. 4.1) and local maps for the map's (Sec. 4.3, Eq. 9).
//! A local map is cropped to its known cells and its log-odds are quantised to
//! [`LOG_ODDS_STEP`] in an `i8` (one byte a cell in the store).

use std::collections::BTreeMap;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{CellClass, ClassThresholds, GridGeometry, OccupancyGrid, SensorModel};
use mapmerge_posegraph::{NodeId, PoseGraph2};
use mapmerge_scan::Point2;
use serde::{Deserialize, Serialize};

use crate::error::AtlasError;

/// Quantisation step of a local map's log-odds (the clamps, −2.0 and 3.5, fit an `i8`).
pub const LOG_ODDS_STEP: f32 = 1.0 / 32.0;

/// One local map, in its anchor vertex's frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LocalMapGrid {
    /// Cell side (m).
    pub resolution_m: f64,
    /// The corner of cell (0, 0) in the anchor's frame (m).
    pub origin_m: [f64; 2],
    /// Columns and rows.
    pub width: u32,
    /// …
    pub height: u32,
    /// Log-odds / [`LOG_ODDS_STEP`], row-major; 0 is unknown.
    pub cells: Vec<i8>,
    /// Keyframes it was built from.
    pub keyframes: u32,
}

impl LocalMapGrid {
    /// Builds a local map from keyframes given in the anchor's frame (`anchor_from_robot`,
    /// points in the robot's frame): every beam from the robot to its return (OctoMap's
    /// inverse sensor model), cropped to the known cells.
    pub fn from_keyframes<'a>(
        resolution_m: f64,
        keyframes: impl IntoIterator<Item = (Se2, &'a [Point2])>,
    ) -> Result<Self, AtlasError> {
        let grid_error = |e: mapmerge_grid::GridError| AtlasError::Config(e.to_string());
        let mut grid = OccupancyGrid::new(resolution_m).map_err(grid_error)?;
        let model = SensorModel::default();
        let mut count = 0u32;
        for (anchor_from_robot, points) in keyframes {
            let ends: Vec<Point2> = points
                .iter()
                .map(|p| anchor_from_robot.transform_point(p))
                .collect();
            grid.insert_rays(&anchor_from_robot.translation(), &ends, &[], &model)
                .map_err(grid_error)?;
            count += 1;
        }
        Ok(Self::cropped(&grid, count))
    }

    /// `grid` cropped to its known cells and quantised.
    fn cropped(grid: &OccupancyGrid, keyframes: u32) -> Self {
        let geometry = grid.geometry();
        let quantised = |l: f32| (l / LOG_ODDS_STEP).round().clamp(-127.0, 127.0) as i8;
        let (mut lo, mut hi) = ((usize::MAX, usize::MAX), (0usize, 0usize));
        for (index, l) in grid.log_odds().iter().enumerate() {
            if quantised(*l) != 0 {
                let (x, y) = (index % geometry.width, index / geometry.width);
                lo = (lo.0.min(x), lo.1.min(y));
                hi = (hi.0.max(x), hi.1.max(y));
            }
        }
        if lo.0 > hi.0 {
            return Self {
                resolution_m: geometry.resolution_m,
                origin_m: [0.0, 0.0],
                width: 0,
                height: 0,
                cells: Vec::new(),
                keyframes,
            };
        }
        let (width, height) = (hi.0 - lo.0 + 1, hi.1 - lo.1 + 1);
        let mut cells = Vec::with_capacity(width * height);
        for y in lo.1..=hi.1 {
            for x in lo.0..=hi.0 {
                let l = grid.log_odds().get(y * geometry.width + x).copied();
                cells.push(quantised(l.unwrap_or(0.0)));
            }
        }
        let r = geometry.resolution_m;
        Self {
            resolution_m: r,
            origin_m: [
                geometry.origin_m.x + lo.0 as f64 * r,
                geometry.origin_m.y + lo.1 as f64 * r,
            ],
            width: width as u32,
            height: height as u32,
            cells,
            keyframes,
        }
    }

    /// Cells with evidence.
    pub fn known_cells(&self) -> usize {
        self.cells.iter().filter(|c| **c != 0).count()
    }

    /// The log-odds at `p` (anchor frame); 0 outside.
    pub fn log_odds_at(&self, p: &Point2) -> f32 {
        let x = ((p.x - self.origin_m[0]) / self.resolution_m).floor();
        let y = ((p.y - self.origin_m[1]) / self.resolution_m).floor();
        if x < 0.0 || y < 0.0 || x >= f64::from(self.width) || y >= f64::from(self.height) {
            return 0.0;
        }
        let index = y as usize * self.width as usize + x as usize;
        self.cells
            .get(index)
            .map_or(0.0, |c| f32::from(*c) * LOG_ODDS_STEP)
    }

    /// The centres (anchor frame) of its occupied and of its free cells within `radius_m` of
    /// `centre` (anchor frame), by `thresholds`.
    pub fn cells_within(
        &self,
        centre: &Point2,
        radius_m: f64,
        thresholds: &ClassThresholds,
    ) -> (Vec<Point2>, Vec<Point2>) {
        let (mut occupied, mut free) = (Vec::new(), Vec::new());
        let r = self.resolution_m;
        if !(r > 0.0 && radius_m >= 0.0) || self.cells.is_empty() {
            return (occupied, free);
        }
        // The rows and columns that can hold a cell within the radius.
        let span = |c: f64, origin: f64, cells: u32| {
            let lo = ((c - radius_m - origin) / r).floor().max(0.0);
            let hi = ((c + radius_m - origin) / r).ceil().min(f64::from(cells));
            (lo as usize, (hi.max(lo)) as usize)
        };
        let (x0, x1) = span(centre.x, self.origin_m[0], self.width);
        let (y0, y1) = span(centre.y, self.origin_m[1], self.height);
        let width = self.width as usize;
        for y in y0..y1 {
            for x in x0..x1 {
                let Some(&value) = self.cells.get(y * width + x) else {
                    continue;
                };
                if value == 0 {
                    continue;
                }
                let p = Point2::new(
                    self.origin_m[0] + (x as f64 + 0.5) * r,
                    self.origin_m[1] + (y as f64 + 0.5) * r,
                );
                if (p - centre).norm() > radius_m {
                    continue;
                }
                match thresholds.classify(f32::from(value) * LOG_ODDS_STEP) {
                    CellClass::Occupied => occupied.push(p),
                    CellClass::Free => free.push(p),
                    CellClass::Unknown => {}
                }
            }
        }
        (occupied, free)
    }

    /// How far its farthest cell lies from the anchor (m).
    pub fn reach_m(&self) -> f64 {
        self.corners().iter().map(|c| c.norm()).fold(0.0, f64::max)
    }

    /// The corners of its box in the anchor's frame.
    fn corners(&self) -> [Point2; 4] {
        let (x0, y0) = (self.origin_m[0], self.origin_m[1]);
        let x1 = x0 + f64::from(self.width) * self.resolution_m;
        let y1 = y0 + f64::from(self.height) * self.resolution_m;
        [
            Point2::new(x0, y0),
            Point2::new(x1, y0),
            Point2::new(x0, y1),
            Point2::new(x1, y1),
        ]
    }
}

/// Local maps rendered into one grid in a graph's frame: the sum of their log-odds at the
/// anchors' poses, and each local map's contribution (cell index, log-odds) so that taking
/// one out is cheap (Sec. 4.3's rendering).
#[derive(Clone, Debug)]
pub struct RenderedMap {
    /// The grid's geometry (the graph's frame).
    pub geometry: GridGeometry,
    /// Summed log-odds per cell.
    pub sums: Vec<f32>,
    /// What each local map added.
    pub contributions: BTreeMap<NodeId, Vec<(u32, f32)>>,
}

impl RenderedMap {
    /// Renders the local maps of `graph`'s vertices at `resolution_m`: each grid cell takes
    /// the log-odds of the local-map cell under its centre (resampling from the map side, so
    /// rotated local maps leave no holes). `None` without local maps in the graph, or for a
    /// graph too large to render.
    pub fn render(
        graph: &PoseGraph2,
        local_maps: &BTreeMap<NodeId, LocalMapGrid>,
        resolution_m: f64,
    ) -> Option<Self> {
        let placed: Vec<(NodeId, Se2, &LocalMapGrid)> = local_maps
            .iter()
            .filter_map(|(anchor, map)| Some((*anchor, graph.vertex(*anchor)?.pose, map)))
            .filter(|(_, pose, map)| pose.is_finite() && map.width > 0)
            .collect();
        let mut lo = Point2::new(f64::INFINITY, f64::INFINITY);
        let mut hi = -lo;
        for (_, pose, map) in &placed {
            for corner in map.corners() {
                let p = pose.transform_point(&corner);
                lo = lo.inf(&p);
                hi = hi.sup(&p);
            }
        }
        if placed.is_empty() || resolution_m.is_nan() || resolution_m <= 0.0 {
            return None;
        }
        let width = ((hi.x - lo.x) / resolution_m).ceil() as usize + 1;
        let height = ((hi.y - lo.y) / resolution_m).ceil() as usize + 1;
        if width.saturating_mul(height) > mapmerge_grid::MAX_CELLS {
            return None;
        }
        let geometry = GridGeometry {
            resolution_m,
            origin_m: lo,
            width,
            height,
        };
        Some(Self::render_into(graph, local_maps, geometry))
    }

    /// Renders the local maps of `graph`'s vertices on a given grid (what falls outside it is
    /// left out), as [`RenderedMap::render`] does.
    pub fn render_into(
        graph: &PoseGraph2,
        local_maps: &BTreeMap<NodeId, LocalMapGrid>,
        geometry: GridGeometry,
    ) -> Self {
        let (lo, resolution_m) = (geometry.origin_m, geometry.resolution_m);
        let (width, height) = (geometry.width, geometry.height);
        let mut sums = vec![0.0f32; geometry.len()];
        let mut contributions = BTreeMap::new();
        let placed = local_maps
            .iter()
            .filter_map(|(anchor, map)| Some((*anchor, graph.vertex(*anchor)?.pose, map)))
            .filter(|(_, pose, map)| pose.is_finite() && map.width > 0);
        for (anchor, map_from_anchor, map) in placed {
            let anchor_from_map = map_from_anchor.inverse();
            let mut blo = Point2::new(f64::INFINITY, f64::INFINITY);
            let mut bhi = -blo;
            for corner in map.corners() {
                let p = map_from_anchor.transform_point(&corner);
                blo = blo.inf(&p);
                bhi = bhi.sup(&p);
            }
            // The cells of the box, clipped to the grid (none when it lies outside).
            let range = |from: f64, to: f64, origin: f64, n: usize| {
                let a = ((from - origin) / resolution_m).floor().max(0.0);
                let b = ((to - origin) / resolution_m).floor().min(n as f64 - 1.0);
                (a <= b).then_some((a as usize, b as usize))
            };
            let (Some((x0, x1)), Some((y0, y1))) = (
                range(blo.x, bhi.x, lo.x, width),
                range(blo.y, bhi.y, lo.y, height),
            ) else {
                contributions.insert(anchor, Vec::new());
                continue;
            };
            let mut added = Vec::new();
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let centre = Point2::new(
                        lo.x + (x as f64 + 0.5) * resolution_m,
                        lo.y + (y as f64 + 0.5) * resolution_m,
                    );
                    let l = map.log_odds_at(&anchor_from_map.transform_point(&centre));
                    if l != 0.0 {
                        let index = y * width + x;
                        if let Some(sum) = sums.get_mut(index) {
                            *sum += l;
                            added.push((index as u32, l));
                        }
                    }
                }
            }
            contributions.insert(anchor, added);
        }
        Self {
            geometry,
            sums,
            contributions,
        }
    }

    /// The class of every cell.
    pub fn classes(&self, thresholds: &ClassThresholds) -> Vec<CellClass> {
        self.sums.iter().map(|l| thresholds.classify(*l)).collect()
    }

    /// Cells that are not unknown, and their area (m²).
    pub fn known_area_m2(&self, thresholds: &ClassThresholds) -> f64 {
        let known = self
            .sums
            .iter()
            .filter(|l| thresholds.classify(**l) != CellClass::Unknown)
            .count();
        known as f64 * self.geometry.resolution_m * self.geometry.resolution_m
    }

    /// The rendered map as an occupancy grid (log-odds sums).
    pub fn to_grid(&self) -> Option<OccupancyGrid> {
        OccupancyGrid::from_log_odds(self.geometry, self.sums.clone()).ok()
    }
}
