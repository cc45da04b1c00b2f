//! Grid map matching without an initial guess (Carpin 2008: Hough spectra, correlation) and
//! the map similarity metrics SM and DM (Andersone, Sec. 3.3).
//!
//! Entry points:
//! - [`match_grids`] with [`GridMatchParams`]: where map B lies in map A, as ranked
//!   [`MatchHypothesis`]es (`a_from_b`, acceptance index ω, SM, DM, overlap) and whether the
//!   best one is accepted ([`GridMatch`]).
//! - [`map_metrics`]: SM and DM of two grids under a given transform (e.g. a merged map
//!   against a robot's own map).
//!
//! ```
//! use mapmerge_geometry::Se2;
//! use mapmerge_grid::{Cell, GridGeometry, OccupancyGrid, Point2};
//! use mapmerge_gridmatch::{map_metrics, match_grids, GridMatchParams};
//!
//! // A 6 × 4 m room with a pillar and a side wall, at 0.1 m.
//! let geometry = GridGeometry { resolution_m: 0.1, origin_m: Point2::zeros(), width: 80, height: 60 };
//! let mut a = OccupancyGrid::with_geometry(geometry).unwrap();
//! for x in 5..75 {
//!     for y in 5..55 {
//!         let wall = x == 5 || x == 74 || y == 5 || y == 54 || (x == 30 && y < 35)
//!             || ((50..54).contains(&x) && (20..24).contains(&y));
//!         a.set(Cell::new(x, y), if wall { 2.0 } else { -2.0 }).unwrap();
//!     }
//! }
//! // B: the same map with its origin moved, i.e. B's frame is A's shifted by (−1.5, 0.7) m.
//! let mut b_geometry = geometry;
//! b_geometry.origin_m = Point2::new(1.5, -0.7);
//! let b = OccupancyGrid::from_log_odds(b_geometry, a.log_odds().to_vec()).unwrap();
//!
//! let found = match_grids(&a, &b, &GridMatchParams::default()).unwrap();
//! let best = &found.hypotheses[0];
//! assert!((best.a_from_b.x_m + 1.5).abs() < 0.15 && (best.a_from_b.y_m - 0.7).abs() < 0.15);
//! assert!(best.acceptance > 0.99);
//!
//! let metrics = map_metrics(&a, &b, &Se2::new(-1.5, 0.7, 0.0), &Default::default()).unwrap();
//! assert_eq!(metrics.sm, 1.0);
//! assert_eq!(metrics.dm_cells, 0.0);
//! ```

#![warn(missing_docs)]

mod correlate;
mod error;
mod hough;
mod matcher;
mod metrics;
mod orientation;
mod params;
mod raster;

pub use error::{GridMatchError, Which};
pub use matcher::{match_grids, GridMatch, MatchHypothesis, MatchRejection};
pub use metrics::{map_metrics, MapMetrics};
pub use params::{AcceptanceParams, GridMatchParams};
