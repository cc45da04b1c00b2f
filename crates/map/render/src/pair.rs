//! Two grids in one picture, each in its own colour: how a merge lines them up.

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{CellClass, ClassThresholds, GridGeometry, OccupancyGrid};

use crate::{Picture, Point2, Rgb};

/// Colours of [`Picture::of_grid_pair`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairStyle {
    /// Pixels per cell of the first grid.
    pub pixels_per_cell: usize,
    /// Occupied in the first grid only.
    pub first: Rgb,
    /// Occupied in the second grid only.
    pub second: Rgb,
    /// Occupied in both.
    pub both: Rgb,
    /// Free in at least one and occupied in none.
    pub free: Rgb,
    /// Unknown in both.
    pub unknown: Rgb,
}

impl Default for PairStyle {
    fn default() -> Self {
        Self {
            pixels_per_cell: 1,
            first: Rgb([30, 90, 220]),
            second: Rgb([235, 120, 20]),
            both: Rgb([40, 40, 40]),
            free: Rgb::WHITE,
            unknown: Rgb::UNKNOWN_GREY,
        }
    }
}

impl Picture {
    /// Grid `a` and grid `b` placed by `a_from_b` (b's map frame in a's), drawn in a's frame
    /// at a's resolution over the union of both; each cell of the picture samples `b` at
    /// its centre.
    pub fn of_grid_pair(
        a: &OccupancyGrid,
        b: &OccupancyGrid,
        a_from_b: &Se2,
        thresholds: &ClassThresholds,
        style: &PairStyle,
    ) -> Self {
        let geometry = union_geometry(a.geometry(), b.geometry(), a_from_b);
        let mut picture = Picture::blank(&geometry, style.pixels_per_cell);
        let scale = style.pixels_per_cell.max(1);
        let b_from_a = a_from_b.inverse();
        let class_at = |grid: &OccupancyGrid, p: &Point2| {
            let cell = grid.geometry().cell_of(p);
            if grid.geometry().contains(cell) {
                grid.class(cell, thresholds)
            } else {
                CellClass::Unknown
            }
        };
        for index in 0..geometry.len() {
            let cell = geometry.cell_at(index);
            let p = geometry.center_of(cell);
            let in_a = class_at(a, &p);
            let in_b = class_at(b, &b_from_a.transform_point(&p));
            let colour = match (in_a, in_b) {
                (CellClass::Occupied, CellClass::Occupied) => style.both,
                (CellClass::Occupied, _) => style.first,
                (_, CellClass::Occupied) => style.second,
                (CellClass::Free, _) | (_, CellClass::Free) => style.free,
                _ => style.unknown,
            };
            let top = geometry.height - 1 - cell.y as usize;
            for py in top * scale..(top + 1) * scale {
                for px in cell.x as usize * scale..(cell.x as usize + 1) * scale {
                    picture.put(px, py, colour);
                }
            }
        }
        picture
    }
}

/// A grid at `a`'s resolution covering `a` and `b`'s corners moved by `a_from_b`.
fn union_geometry(a: &GridGeometry, b: &GridGeometry, a_from_b: &Se2) -> GridGeometry {
    let (a_min, a_max) = a.bounds_m();
    let (b_min, b_max) = b.bounds_m();
    let corners = [
        Point2::new(b_min.x, b_min.y),
        Point2::new(b_max.x, b_min.y),
        Point2::new(b_min.x, b_max.y),
        Point2::new(b_max.x, b_max.y),
    ]
    .map(|c| a_from_b.transform_point(&c));
    let (mut min, mut max) = (a_min, a_max);
    for c in corners
        .iter()
        .filter(|c| c.x.is_finite() && c.y.is_finite())
    {
        min = min.inf(c);
        max = max.sup(c);
    }
    let resolution_m = a.resolution_m;
    // Cap the picture at 8k × 8k cells: a far-off transform must not ask for gigabytes.
    let cells = |extent_m: f64| ((extent_m / resolution_m).ceil().max(1.0) as usize).min(8192);
    GridGeometry {
        origin_m: min,
        resolution_m,
        width: cells(max.x - min.x),
        height: cells(max.y - min.y),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    #[test]
    fn both_grids_show_in_their_colours_where_the_transform_puts_them() {
        // One row of ten 10 cm cells from the origin: a has a wall in its first cell and free
        // space in its last, b a wall in its first cell only.
        let row = GridGeometry {
            resolution_m: 0.1,
            origin_m: Point2::zeros(),
            width: 10,
            height: 1,
        };
        let mut a_cells = vec![0.0; 10];
        a_cells[0] = 5.0;
        a_cells[9] = -5.0;
        let mut b_cells = vec![0.0; 10];
        b_cells[0] = 5.0;
        let a = OccupancyGrid::from_log_odds(row, a_cells).unwrap();
        let b = OccupancyGrid::from_log_odds(row, b_cells).unwrap();
        // b's map frame 1 m to the right of a's.
        let style = PairStyle::default();
        let picture = Picture::of_grid_pair(
            &a,
            &b,
            &Se2::new(1.0, 0.0, 0.0),
            &ClassThresholds::default(),
            &style,
        );
        let at = |p: Point2| {
            let px = picture.to_pixel(&p);
            picture.pixel(px.x as usize, px.y as usize).unwrap()
        };
        assert_eq!(at(Point2::new(0.05, 0.05)), style.first);
        assert_eq!(at(Point2::new(1.05, 0.05)), style.second);
        assert_eq!(at(Point2::new(0.95, 0.05)), style.free);
        assert_eq!(at(Point2::new(0.55, 0.05)), style.unknown);
    }
}
