//! Occupancy grids for mapmerge.
//!
//! Entry points: [`OccupancyGrid`] (log-odds, grows on demand) with [`OccupancyGrid::insert_scan`]
//! (exact ray casting), and [`LocalMaps`] (one small grid per pose-graph node, rendered into a
//! global grid from the current poses, incrementally).
//!
//! ```
//! use mapmerge_grid::{CellClass, ClassThresholds, OccupancyGrid};
//! let grid = OccupancyGrid::new(0.05).unwrap();
//! assert_eq!(grid.class(mapmerge_grid::Cell::new(3, 4), &ClassThresholds::default()), CellClass::Unknown);
//! ```

mod error;
mod free_space;
mod geometry;
mod local_maps;
mod morphology;
mod occupancy;
mod raycast;
mod resample;

pub use error::GridError;
pub use free_space::FreeSpace;
pub use geometry::{Cell, GridGeometry};
pub use local_maps::{LocalMap, LocalMapParams, LocalMaps, RenderInfo};
pub use mapmerge_geometry::Point2;
pub use morphology::{CellMask, DistanceField};
pub use occupancy::{
    log_odds_of, probability_of, CellClass, ClassThresholds, OccupancyGrid, SensorModel, MAX_CELLS,
};
pub use raycast::{traverse, traverse_cells, InsertInfo, InsertParams};
