//! Where a grid's cells are in the world.

use serde::{Deserialize, Serialize};

use crate::Point2;

/// Integer cell coordinates: `x` grows to the right (world +x), `y` grows up (world +y).
/// Cell `(0, 0)` is the lower-left cell of the grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Cell {
    /// Column.
    pub x: i64,
    /// Row, counted from the bottom.
    pub y: i64,
}

impl Cell {
    /// A cell from its column and row.
    pub const fn new(x: i64, y: i64) -> Self {
        Self { x, y }
    }
}

/// Size and placement of a grid: `width × height` square cells of `resolution_m`, the
/// lower-left corner of cell `(0, 0)` at `origin_m` in the grid's frame (as ROS map_server's
/// `origin` with zero yaw).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GridGeometry {
    /// Cell side (m).
    pub resolution_m: f64,
    /// Lower-left corner of cell (0, 0) (m).
    pub origin_m: Point2,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

impl GridGeometry {
    /// Number of cells.
    pub fn len(&self) -> usize {
        self.width * self.height
    }

    /// True when the grid has no cells.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The cell containing `p` (may be outside the grid). Non-finite points map to
    /// `i64::MIN`/`MAX` cells, which are never inside.
    pub fn cell_of(&self, p: &Point2) -> Cell {
        let local = (p - self.origin_m) / self.resolution_m;
        Cell::new(local.x.floor() as i64, local.y.floor() as i64)
    }

    /// Centre of `cell` (m).
    pub fn center_of(&self, cell: Cell) -> Point2 {
        self.origin_m + Point2::new(cell.x as f64 + 0.5, cell.y as f64 + 0.5) * self.resolution_m
    }

    /// True when `cell` lies inside the grid.
    pub fn contains(&self, cell: Cell) -> bool {
        cell.x >= 0
            && cell.y >= 0
            && (cell.x as u64) < self.width as u64
            && (cell.y as u64) < self.height as u64
    }

    /// Row-major index of `cell` (row 0 at the bottom), if inside.
    pub fn index_of(&self, cell: Cell) -> Option<usize> {
        self.contains(cell)
            .then(|| cell.y as usize * self.width + cell.x as usize)
    }

    /// The cell at row-major `index`.
    pub fn cell_at(&self, index: usize) -> Cell {
        let width = self.width.max(1);
        Cell::new((index % width) as i64, (index / width) as i64)
    }

    /// World bounds `(min, max)` of the whole grid.
    pub fn bounds_m(&self) -> (Point2, Point2) {
        let size = Point2::new(self.width as f64, self.height as f64) * self.resolution_m;
        (self.origin_m, self.origin_m + size)
    }
}
