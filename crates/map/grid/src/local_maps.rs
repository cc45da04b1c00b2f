//! Local maps anchored to pose-graph nodes, rendered into one global grid (Banerjee et al.,
//! "Lifelong Mapping in the Wild", Sec. 3.3: "a collection of overlapping local maps, which are
//! anchored to nodes in the pose graph … When we need to plan the robot's path, we collapse
//! the current configuration of the local maps into a single global occupancy map – an
//! operation we call *rendering*").
//!
//! Each keyframe's scans are inserted into its node's own small grid, in the node's frame.
//! [`LocalMaps::render`] sums the local maps (log-odds add for independent scans) at the
//! nodes' current poses. It is incremental: a node is re-rendered only when its pose moved by
//! more than a tolerance, its local map changed, or it left the graph; re-rendering subtracts
//! the old contribution exactly (sums are kept in fixed point) and adds the new one.

use std::collections::BTreeMap;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::NodeId;
use mapmerge_scan::LaserScan;
use serde::{Deserialize, Serialize};

use crate::{Cell, GridError, GridGeometry, InsertInfo, InsertParams, OccupancyGrid, Point2};

/// Fixed-point scale of the rendered sums: log-odds × 4096, so subtracting a contribution
/// restores the sum bit for bit.
const FIXED_POINT_SCALE: f32 = 4096.0;

/// One node's local map: a grid in the node's frame and how many scans it holds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LocalMap {
    grid: OccupancyGrid,
    scans: usize,
    /// The cell box of the grid's known cells (what rendering has to cover), kept with it.
    known: Option<(Cell, Cell)>,
}

impl LocalMap {
    /// An empty local map of `resolution_m`.
    pub fn new(resolution_m: f64) -> Result<Self, GridError> {
        Ok(Self::from_grid(OccupancyGrid::new(resolution_m)?, 0))
    }

    /// A local map holding `grid` (in the node's frame), built from `scans` scans.
    pub fn from_grid(grid: OccupancyGrid, scans: usize) -> Self {
        let known = known_bounds(&grid);
        Self { grid, scans, known }
    }

    /// The grid, in the node's frame.
    pub fn grid(&self) -> &OccupancyGrid {
        &self.grid
    }

    /// Scans inserted.
    pub fn scans(&self) -> usize {
        self.scans
    }

    /// Inserts a scan taken at `node_from_robot`.
    pub fn insert_scan(
        &mut self,
        node_from_robot: &Se2,
        scan: &LaserScan,
        params: &InsertParams,
    ) -> Result<InsertInfo, GridError> {
        let info = self.grid.insert_scan(node_from_robot, scan, params)?;
        self.scans += 1;
        self.known = known_bounds(&self.grid);
        Ok(info)
    }
}

/// What a [`LocalMaps::render`] call did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RenderInfo {
    /// Local maps drawn for the first time.
    pub added: usize,
    /// Local maps redrawn because their node moved or their content changed.
    pub moved: usize,
    /// Local maps taken out because their node has no pose any more.
    pub removed: usize,
    /// Local maps left as they were.
    pub unchanged: usize,
    /// Global cells written (added and subtracted).
    pub cells_written: usize,
}

/// Parameters of the local maps and of rendering.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LocalMapParams {
    /// Cell side of local maps and of the rendered grid (m).
    pub resolution_m: f64,
    /// How scans update local maps.
    pub insert: InsertParams,
    /// A node whose local map's farthest cell moved by less than this (m) is not redrawn.
    /// Default: a quarter cell.
    pub move_tolerance_m: f64,
}

impl LocalMapParams {
    /// Defaults for `resolution_m`.
    pub fn new(resolution_m: f64) -> Self {
        Self {
            resolution_m,
            insert: InsertParams::default(),
            move_tolerance_m: resolution_m / 4.0,
        }
    }
}

/// Where a local map is drawn and what bounds it covers.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
struct Drawn {
    map_from_node: Se2,
}

/// The local maps of a pose graph's nodes and the global grid rendered from them.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LocalMaps {
    params: LocalMapParams,
    maps: BTreeMap<NodeId, LocalMap>,
    drawn: BTreeMap<NodeId, Drawn>,
    canvas: Canvas,
}

/// The rendered grid and its fixed-point sums (same geometry).
#[derive(Clone, Debug, Serialize, Deserialize)]
struct Canvas {
    sums: Vec<i32>,
    rendered: OccupancyGrid,
}

impl LocalMaps {
    /// No local maps yet.
    pub fn new(params: LocalMapParams) -> Result<Self, GridError> {
        Ok(Self {
            canvas: Canvas {
                sums: Vec::new(),
                rendered: OccupancyGrid::new(params.resolution_m)?,
            },
            params,
            maps: BTreeMap::new(),
            drawn: BTreeMap::new(),
        })
    }

    /// The parameters.
    pub fn params(&self) -> &LocalMapParams {
        &self.params
    }

    /// Inserts `scan`, taken with the robot at `node_from_robot`, into `node`'s local map
    /// (created if needed). If the map was drawn, it is taken out of the rendered grid first
    /// and comes back at the next [`Self::render`].
    pub fn insert_scan(
        &mut self,
        node: NodeId,
        node_from_robot: &Se2,
        scan: &LaserScan,
    ) -> Result<InsertInfo, GridError> {
        self.undraw(node);
        let map = match self.maps.entry(node) {
            std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::btree_map::Entry::Vacant(e) => {
                e.insert(LocalMap::new(self.params.resolution_m)?)
            }
        };
        map.insert_scan(node_from_robot, scan, &self.params.insert)
    }

    /// The local map of `node`.
    pub fn get(&self, node: NodeId) -> Option<&LocalMap> {
        self.maps.get(&node)
    }

    /// Every local map, by node.
    pub fn iter(&self) -> impl Iterator<Item = (NodeId, &LocalMap)> {
        self.maps.iter().map(|(&id, map)| (id, map))
    }

    /// Number of local maps.
    pub fn len(&self) -> usize {
        self.maps.len()
    }

    /// True when there are no local maps.
    pub fn is_empty(&self) -> bool {
        self.maps.is_empty()
    }

    /// Removes `node`'s local map (and its rendering) and returns it, e.g. to prune it or to
    /// move it with an undone merge; [`Self::insert_local_map`] puts it back.
    pub fn remove(&mut self, node: NodeId) -> Option<LocalMap> {
        self.undraw(node);
        self.maps.remove(&node)
    }

    /// Adds (or replaces) `node`'s local map; it is drawn at the next [`Self::render`].
    pub fn insert_local_map(&mut self, node: NodeId, map: LocalMap) -> Option<LocalMap> {
        self.undraw(node);
        self.maps.insert(node, map)
    }

    /// The global grid as last rendered.
    pub fn rendered(&self) -> &OccupancyGrid {
        &self.canvas.rendered
    }

    /// Brings the rendered grid up to date with the nodes' poses (`map_from_node`; nodes
    /// without a pose are not drawn). Only what moved is redrawn.
    pub fn render(
        &mut self,
        map_from_node: &BTreeMap<NodeId, Se2>,
    ) -> Result<RenderInfo, GridError> {
        let mut info = RenderInfo::default();
        // 1. Take out what left the graph or moved too far.
        let drawn: Vec<(NodeId, Drawn)> = self.drawn.iter().map(|(&id, &d)| (id, d)).collect();
        for (node, drawn) in drawn {
            match map_from_node.get(&node) {
                None => {
                    info.cells_written += self.undraw(node);
                    info.removed += 1;
                }
                Some(pose) if self.moved(node, &drawn.map_from_node, pose) => {
                    info.cells_written += self.undraw(node);
                    info.moved += 1;
                }
                Some(_) => info.unchanged += 1,
            }
        }
        // 2. Draw every local map with a pose that is not drawn.
        let to_draw: Vec<(NodeId, Se2)> = self
            .maps
            .keys()
            .filter(|id| !self.drawn.contains_key(id))
            .filter_map(|id| map_from_node.get(id).map(|pose| (*id, *pose)))
            .collect();
        let moved_before = info.moved;
        for (node, pose) in to_draw {
            if !pose.is_finite() {
                return Err(GridError::NotFinite);
            }
            info.cells_written += self.draw(node, &pose, 1)?;
            self.drawn.insert(
                node,
                Drawn {
                    map_from_node: pose,
                },
            );
        }
        info.added = self.drawn.len() - info.unchanged - moved_before;
        Ok(info)
    }

    /// True when `node`'s local map would land more than the tolerance away from where it
    /// was drawn.
    fn moved(&self, node: NodeId, old: &Se2, new: &Se2) -> bool {
        let Some(map) = self.maps.get(&node) else {
            return true;
        };
        let (lo, hi) = map.grid.geometry().bounds_m();
        let radius = [lo.x.abs(), hi.x.abs()]
            .iter()
            .fold(0.0f64, |a, &b| a.max(b))
            .hypot(
                [lo.y.abs(), hi.y.abs()]
                    .iter()
                    .fold(0.0f64, |a, &b| a.max(b)),
            );
        let shift = (new.translation() - old.translation()).norm()
            + mapmerge_geometry::wrap_angle_rad(new.theta_rad - old.theta_rad).abs() * radius;
        shift > self.params.move_tolerance_m
    }

    /// Takes `node`'s drawing out of the rendered grid; returns the cells written.
    fn undraw(&mut self, node: NodeId) -> usize {
        match self.drawn.remove(&node) {
            // Drawing with sign −1 at the same pose subtracts exactly what was added.
            Some(drawn) => self.draw(node, &drawn.map_from_node, -1).unwrap_or(0),
            None => 0,
        }
    }

    /// Adds `sign ×` the local map of `node` at `map_from_node` to the rendered sums.
    fn draw(&mut self, node: NodeId, map_from_node: &Se2, sign: i32) -> Result<usize, GridError> {
        match self.maps.get(&node) {
            Some(map) => self.canvas.draw(map, map_from_node, sign, &self.params),
            None => Ok(0),
        }
    }
}

impl Canvas {
    /// Adds `sign × map` drawn at `map_from_node` to the sums; returns the cells written.
    /// Inverse mapping: every global cell whose centre falls inside the local map's known
    /// area samples the local cell under it (nearest neighbour).
    fn draw(
        &mut self,
        map: &LocalMap,
        map_from_node: &Se2,
        sign: i32,
        params: &LocalMapParams,
    ) -> Result<usize, GridError> {
        let local = *map.grid.geometry();
        let Some((lo_cell, hi_cell)) = map.known else {
            return Ok(0);
        };
        // Corners of the known area in the map frame → global bounding box.
        let r = local.resolution_m;
        let lo = local.origin_m + Point2::new(lo_cell.x as f64, lo_cell.y as f64) * r;
        let hi = local.origin_m + Point2::new((hi_cell.x + 1) as f64, (hi_cell.y + 1) as f64) * r;
        let corners = [lo, Point2::new(hi.x, lo.y), hi, Point2::new(lo.x, hi.y)]
            .map(|c| map_from_node.transform_point(&c));
        let (mut min, mut max) = (corners[0], corners[0]);
        for c in &corners[1..] {
            min = min.inf(c);
            max = max.sup(c);
        }
        if sign > 0 {
            self.grow_rendered(&min, &max)?;
        }
        let global = *self.rendered.geometry();
        let g_lo = global.cell_of(&min);
        let g_hi = global.cell_of(&max);
        let node_from_map = map_from_node.inverse();
        let rotation = node_from_map.rotation_matrix();
        // Local cell coordinates of a global cell centre: affine in the global cell index.
        let to_local = |p: Point2| (node_from_map.transform_point(&p) - local.origin_m) / r;
        let step_x = rotation * Point2::new(global.resolution_m, 0.0) / r;
        let model = &params.insert.model;
        let (min_sum, max_sum) = (
            (model.min_log_odds * FIXED_POINT_SCALE) as i64,
            (model.max_log_odds * FIXED_POINT_SCALE) as i64,
        );
        let local_odds = map.grid.log_odds();
        let mut written = 0;
        let (box_lo, box_hi) = (
            Point2::new(lo_cell.x as f64, lo_cell.y as f64),
            Point2::new((hi_cell.x + 1) as f64, (hi_cell.y + 1) as f64),
        );
        let sums = &mut self.sums;
        let rendered = self.rendered.log_odds_mut();
        for gy in g_lo.y.max(0)..=g_hi.y.min(global.height as i64 - 1) {
            let x0 = g_lo.x.max(0);
            let x1 = g_hi.x.min(global.width as i64 - 1);
            let p0 = to_local(global.center_of(Cell::new(x0, gy)));
            // Only the part of the row whose centres fall inside the known box (the box's
            // image is a rotated rectangle: skip the corners of its bounding box).
            let Some((k0, k1)) = row_span(&p0, &step_x, &box_lo, &box_hi, (x1 - x0) as f64) else {
                continue;
            };
            let row = gy as usize * global.width;
            for k in k0..=k1 {
                let p = p0 + step_x * k as f64;
                let (lx, ly) = (p.x.floor(), p.y.floor());
                // Rounding at the span's ends can still land one cell outside.
                if lx < box_lo.x || ly < box_lo.y || lx >= box_hi.x || ly >= box_hi.y {
                    continue;
                }
                let l = local_odds
                    .get(ly as usize * local.width + lx as usize)
                    .copied()
                    .unwrap_or(0.0);
                if l == 0.0 {
                    continue;
                }
                let index = row + (x0 + k) as usize;
                let (Some(sum), Some(out)) = (sums.get_mut(index), rendered.get_mut(index)) else {
                    continue;
                };
                *sum += sign * (l * FIXED_POINT_SCALE).round() as i32;
                *out = (i64::from(*sum).clamp(min_sum, max_sum) as f32) / FIXED_POINT_SCALE;
                written += 1;
            }
        }
        Ok(written)
    }

    /// Grows the rendered grid and the sums together.
    fn grow_rendered(&mut self, min: &Point2, max: &Point2) -> Result<(), GridError> {
        let before: GridGeometry = *self.rendered.geometry();
        let shift = self.rendered.grow_to_contain(min, max)?;
        let after = *self.rendered.geometry();
        if after == before && self.sums.len() == after.len() {
            return Ok(());
        }
        let mut sums = vec![0i32; after.len()];
        for row in 0..before.height {
            let dst = (row as i64 + shift.y) as usize * after.width + shift.x as usize;
            if let (Some(dst), Some(src)) = (
                sums.get_mut(dst..dst + before.width),
                self.sums.get(row * before.width..(row + 1) * before.width),
            ) {
                dst.copy_from_slice(src);
            }
        }
        self.sums = sums;
        Ok(())
    }
}

/// The steps `k ∈ [0, last]` for which `p0 + k · step` lies in the box `[lo, hi)`, or `None`.
fn row_span(p0: &Point2, step: &Point2, lo: &Point2, hi: &Point2, last: f64) -> Option<(i64, i64)> {
    let (mut k_min, mut k_max) = (0.0f64, last);
    for axis in 0..2 {
        let (p, s) = (p0[axis], step[axis]);
        if s.abs() < 1e-12 {
            if p < lo[axis] || p >= hi[axis] {
                return None;
            }
        } else {
            let (a, b) = ((lo[axis] - p) / s, (hi[axis] - p) / s);
            k_min = k_min.max(a.min(b));
            k_max = k_max.min(a.max(b));
        }
    }
    // Widen by one step each side; the caller checks every cell anyway.
    let (k0, k1) = (
        (k_min.floor() - 1.0).max(0.0),
        (k_max.ceil() + 1.0).min(last),
    );
    (k0 <= k1).then_some((k0 as i64, k1 as i64))
}

/// The smallest cell box holding every known cell of `grid`, or `None` when all are unknown.
fn known_bounds(grid: &OccupancyGrid) -> Option<(Cell, Cell)> {
    let g = grid.geometry();
    let mut bounds: Option<(Cell, Cell)> = None;
    for (index, &l) in grid.log_odds().iter().enumerate() {
        if l != 0.0 {
            let c = g.cell_at(index);
            bounds = Some(match bounds {
                None => (c, c),
                Some((lo, hi)) => (
                    Cell::new(lo.x.min(c.x), lo.y.min(c.y)),
                    Cell::new(hi.x.max(c.x), hi.y.max(c.y)),
                ),
            });
        }
    }
    bounds
}
