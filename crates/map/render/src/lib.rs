//! Pictures of maps: PNG images of occupancy grids with overlays — trajectories, pose-graph
//! vertices and edges coloured by session, merge edges highlighted, and class-coloured points
//! (for the invalid-merge detectors).
//!
//! Entry points: [`Picture::of_grid`] (draw a grid), [`Picture::of_grid_pair`] (two grids
//! placed by a merge transform, in two colours), the `draw_*` overlay methods, and
//! [`Picture::save_png`].
//!
//! ```
//! use mapmerge_grid::OccupancyGrid;
//! use mapmerge_render::{Picture, PictureStyle, Rgb};
//! let mut grid = OccupancyGrid::new(0.1).unwrap();
//! grid.set(mapmerge_grid::Cell::new(5, 5), 3.0).unwrap();
//! let mut picture = Picture::of_grid(&grid, &PictureStyle::default());
//! picture.draw_polyline(&[nalgebra::Vector2::new(0.0, 0.0), nalgebra::Vector2::new(0.5, 0.5)], Rgb::RED, 1.0);
//! let bytes = picture.to_png().unwrap();
//! assert_eq!(&bytes[1..4], b"PNG");
//! ```

mod draw;
mod overlay;
mod pair;
mod picture;

pub use mapmerge_geometry::Point2;
pub use overlay::{session_color, GraphStyle};
pub use pair::PairStyle;
pub use picture::{Picture, PictureStyle, RenderError, Rgb};
