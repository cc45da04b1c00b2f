//! Where a sensor saw through: the cells crossed by some ray on its way to a return, as a
//! bitset small enough to keep beside every keyframe (a 40 m × 40 m local map at 0.1 m is
//! 20 KB). Together with the returns themselves it splits space into occupied (near a return),
//! free (crossed, not near a return) and unknown (neither), which is what comparing two maps
//! over their overlap needs (Birk & Carpin 2006's agreement counts known cells only).

use serde::{Deserialize, Serialize};

use crate::{traverse, Cell, GridError, GridGeometry, Point2, MAX_CELLS};

/// The cells crossed by rays (see the module documentation), in the rays' frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FreeSpace {
    geometry: GridGeometry,
    /// One bit per cell, row-major.
    bits: Vec<u64>,
}

impl FreeSpace {
    /// The cells of side `resolution_m` that the segments `origin → end` cross, each end cell
    /// left out (it holds the return). Rays with a non-finite coordinate are skipped; an empty
    /// set of rays gives an empty grid.
    pub fn from_rays(
        resolution_m: f64,
        rays: impl IntoIterator<Item = (Point2, Point2)>,
    ) -> Result<Self, GridError> {
        Self::from_rays_and_cells(resolution_m, rays, [])
    }

    /// As [`FreeSpace::from_rays`], and also the cells holding the points `free_cells` (free
    /// space known otherwise, for example an occupancy grid's free cells; non-finite points
    /// are skipped).
    pub fn from_rays_and_cells(
        resolution_m: f64,
        rays: impl IntoIterator<Item = (Point2, Point2)>,
        free_cells: impl IntoIterator<Item = Point2>,
    ) -> Result<Self, GridError> {
        if !(resolution_m.is_finite() && resolution_m > 0.0) {
            return Err(GridError::BadResolution(resolution_m));
        }
        let finite = |p: &Point2| p.x.is_finite() && p.y.is_finite();
        let rays: Vec<(Point2, Point2)> = rays
            .into_iter()
            .filter(|(origin, end)| finite(origin) && finite(end))
            .collect();
        let given: Vec<Point2> = free_cells.into_iter().filter(finite).collect();
        let Some(first) = rays.first().map(|r| r.0).or(given.first().copied()) else {
            return Ok(Self {
                geometry: GridGeometry {
                    resolution_m,
                    origin_m: Point2::zeros(),
                    width: 0,
                    height: 0,
                },
                bits: Vec::new(),
            });
        };
        let (mut lo, mut hi) = (first, first);
        for (origin, end) in &rays {
            lo = lo.inf(origin).inf(end);
            hi = hi.sup(origin).sup(end);
        }
        for p in &given {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        // Cell borders on multiples of the resolution, so a point's cell does not depend on
        // which rays were cast.
        let lo = (lo / resolution_m).map(f64::floor) * resolution_m;
        let cells = |span: f64| (span / resolution_m).floor() + 1.0;
        let (width, height) = (cells(hi.x - lo.x), cells(hi.y - lo.y));
        if width * height > MAX_CELLS as f64 {
            return Err(GridError::TooLarge);
        }
        let geometry = GridGeometry {
            resolution_m,
            origin_m: lo,
            width: width as usize,
            height: height as usize,
        };
        let mut bits = vec![0u64; geometry.len().div_ceil(64)];
        let to_local = |p: &Point2| (p - lo) / resolution_m;
        for (origin, end) in &rays {
            traverse(to_local(origin), to_local(end), geometry.width, true, |i| {
                if let Some(word) = bits.get_mut(i / 64) {
                    *word |= 1 << (i % 64);
                }
            });
        }
        for p in &given {
            if let Some(i) = geometry.index_of(geometry.cell_of(p)) {
                if let Some(word) = bits.get_mut(i / 64) {
                    *word |= 1 << (i % 64);
                }
            }
        }
        Ok(Self { geometry, bits })
    }

    /// Whether a ray crossed the cell holding `p` (false outside the grid).
    pub fn is_free(&self, p: &Point2) -> bool {
        self.crossed(self.geometry.cell_of(p))
    }

    /// Whether rays crossed the cell holding `p` and all eight around it: a return the map's
    /// own beams later saw through (a person who walked on), not a wall grazed by its
    /// neighbours' beams, whose far side no beam crosses (false outside the grid).
    pub fn is_free_around(&self, p: &Point2) -> bool {
        let centre = self.geometry.cell_of(p);
        (-1..=1).all(|dy| (-1..=1).all(|dx| self.crossed(Cell::new(centre.x + dx, centre.y + dy))))
    }

    /// Whether a ray crossed `cell` (false outside the grid).
    fn crossed(&self, cell: Cell) -> bool {
        self.geometry
            .index_of(cell)
            .and_then(|i| self.bits.get(i / 64).map(|word| word >> (i % 64) & 1 == 1))
            .unwrap_or(false)
    }

    /// Number of crossed cells.
    pub fn free_cells(&self) -> usize {
        self.bits.iter().map(|w| w.count_ones() as usize).sum()
    }

    /// Size and placement of the grid.
    pub fn geometry(&self) -> &GridGeometry {
        &self.geometry
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    #[test]
    fn a_ray_frees_the_cells_it_crosses_but_not_its_end() {
        let free = FreeSpace::from_rays(0.1, [(Point2::new(0.05, 0.05), Point2::new(2.05, 0.05))])
            .unwrap();
        assert!(free.is_free(&Point2::new(0.05, 0.05)));
        assert!(free.is_free(&Point2::new(1.95, 0.05)));
        assert!(!free.is_free(&Point2::new(2.05, 0.05)), "the return's cell");
        assert!(!free.is_free(&Point2::new(1.0, 0.5)), "beside the ray");
        assert!(!free.is_free(&Point2::new(-5.0, 0.0)), "outside the grid");
        assert_eq!(free.free_cells(), 20);
    }

    /// A person seen at (2, 0) from the first pose and walked through by the later beams is
    /// free around; a wall's return, grazed by beams to the wall further on, is not: no beam
    /// crosses the wall's far side.
    #[test]
    fn a_return_walked_through_is_free_around_and_a_grazed_wall_is_not() {
        let person = Point2::new(2.05, 0.05);
        let mut rays = vec![(Point2::new(0.05, 0.05), person)];
        for k in -10..=10 {
            let end = Point2::new(4.05, 0.05 + 0.1 * k as f64);
            rays.push((Point2::new(0.05, 0.05), end));
        }
        // A wall along y = 1.05 seen from below at grazing angles.
        let wall: Vec<Point2> = (0..40)
            .map(|i| Point2::new(0.05 + 0.1 * i as f64, 1.05))
            .collect();
        rays.extend(wall.iter().map(|end| (Point2::new(0.05, 0.55), *end)));
        let free = FreeSpace::from_rays(0.1, rays).unwrap();
        assert!(
            free.is_free_around(&person),
            "the person's cell and all around it"
        );
        for end in &wall[5..] {
            assert!(!free.is_free_around(end), "wall at {end:?}");
        }
        assert!(
            !free.is_free_around(&Point2::new(-5.0, 0.0)),
            "outside the grid"
        );
    }

    #[test]
    fn rays_from_several_origins_and_bad_input() {
        let rays = [
            (Point2::new(0.0, 0.0), Point2::new(0.0, 3.0)),
            (Point2::new(2.0, 0.0), Point2::new(-1.0, 0.0)),
            (Point2::new(f64::NAN, 0.0), Point2::new(1.0, 1.0)),
        ];
        let free = FreeSpace::from_rays(0.1, rays).unwrap();
        assert!(free.is_free(&Point2::new(0.05, 2.5)));
        assert!(free.is_free(&Point2::new(1.5, 0.05)));
        assert!(!free.is_free(&Point2::new(0.5, 0.5)));
        let empty = FreeSpace::from_rays(0.1, []).unwrap();
        assert_eq!(empty.free_cells(), 0);
        assert!(!empty.is_free(&Point2::new(0.0, 0.0)));
        assert!(FreeSpace::from_rays(0.0, []).is_err());
        let cells = FreeSpace::from_rays_and_cells(
            0.1,
            [(Point2::new(0.0, 0.0), Point2::new(0.0, 1.0))],
            [Point2::new(3.05, -2.05), Point2::new(f64::NAN, 0.0)],
        )
        .unwrap();
        assert!(cells.is_free(&Point2::new(3.01, -2.09)), "a given cell");
        assert!(cells.is_free(&Point2::new(0.05, 0.5)), "a ray's cell");
        assert!(
            !cells.is_free(&Point2::new(3.15, -2.05)),
            "beside the given cell"
        );
        assert_eq!(cells.free_cells(), 11);
        let only_cells = FreeSpace::from_rays_and_cells(0.1, [], [Point2::new(-1.0, 1.0)]).unwrap();
        assert_eq!(only_cells.free_cells(), 1);
        let huge = [(Point2::new(0.0, 0.0), Point2::new(1e9, 1e9))];
        assert!(matches!(
            FreeSpace::from_rays(0.1, huge),
            Err(GridError::TooLarge)
        ));
    }
}
