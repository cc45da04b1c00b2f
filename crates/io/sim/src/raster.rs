//! Rasterising a world into its ground-truth occupancy grid: obstacles occupied, the rest of
//! the building free, outside unknown.

use mapmerge_grid::{GridGeometry, OccupancyGrid, SensorModel};

use crate::shapes::{point_segment_distance, Shape};
use crate::{Point2, SimError, World};

/// Unknown cells kept around the world's bounds (m).
const MARGIN_M: f64 = 1.0;

impl World {
    /// The ground-truth map at `resolution_m`: a cell is occupied (log-odds of the default
    /// [`SensorModel`]'s upper clamp, p = 0.97) when its centre lies in an obstacle (obstacles
    /// thinner than a cell still get one line of cells), free (its lower clamp, p = 0.12) when
    /// its centre lies in the building's footprint, and unknown (0) elsewhere. The grid covers
    /// the world's bounds plus 1 m, its cell corners on multiples of the resolution.
    pub fn to_grid(&self, resolution_m: f64) -> Result<OccupancyGrid, SimError> {
        if !(resolution_m.is_finite() && resolution_m > 0.0) {
            return Err(SimError::InvalidParams {
                field: "resolution_m",
                reason: format!("must be positive and finite, got {resolution_m}"),
            });
        }
        let bounds = self.bounds().expanded(MARGIN_M);
        let origin_m = Point2::new(
            (bounds.min_m.x / resolution_m).floor() * resolution_m,
            (bounds.min_m.y / resolution_m).floor() * resolution_m,
        );
        let width = ((bounds.max_m.x - origin_m.x) / resolution_m).ceil() as usize;
        let height = ((bounds.max_m.y - origin_m.y) / resolution_m).ceil() as usize;
        let geometry = GridGeometry {
            resolution_m,
            origin_m,
            width,
            height,
        };
        let mut grid = OccupancyGrid::with_geometry(geometry)?;
        let model = SensorModel::default();
        let cells = grid.log_odds_mut();
        let mut paint = |rect: &crate::Rect, value: f32, covers: &dyn Fn(&Point2) -> bool| {
            let lo = geometry.cell_of(&rect.min_m);
            let hi = geometry.cell_of(&rect.max_m);
            for y in lo.y.max(0)..=hi.y.min(height as i64 - 1) {
                for x in lo.x.max(0)..=hi.x.min(width as i64 - 1) {
                    let cell = mapmerge_grid::Cell::new(x, y);
                    if covers(&geometry.center_of(cell)) {
                        if let Some(slot) = geometry.index_of(cell).and_then(|i| cells.get_mut(i)) {
                            *slot = value;
                        }
                    }
                }
            }
        };
        for rect in &self.footprint {
            paint(rect, model.min_log_odds, &|p| rect.contains(p));
        }
        let half = 0.5 * resolution_m;
        for obstacle in &self.obstacles {
            let shape = thickened(&obstacle.shape, half);
            let bounds = shape.bounds().expanded(resolution_m);
            let covers = |p: &Point2| match &shape {
                Shape::Segment(s) => {
                    point_segment_distance(p, &s.start_m, &s.end_m)
                        <= half * std::f64::consts::SQRT_2
                }
                solid => solid.contains(p),
            };
            paint(&bounds, model.max_log_odds, &covers);
        }
        Ok(grid)
    }
}

/// The shape with every half extent at least `min_half_m`, so thin obstacles hit a cell centre.
fn thickened(shape: &Shape, min_half_m: f64) -> Shape {
    match *shape {
        Shape::Rect(rect) => {
            let size = Point2::new(
                rect.width_m().max(2.0 * min_half_m),
                rect.height_m().max(2.0 * min_half_m),
            );
            Shape::Rect(crate::Rect::from_center(rect.center_m(), size))
        }
        Shape::Box {
            center_m,
            half_size_m,
            yaw_rad,
        } => Shape::Box {
            center_m,
            half_size_m: half_size_m.sup(&Point2::new(min_half_m, min_half_m)),
            yaw_rad,
        },
        Shape::Segment(s) => Shape::Segment(s),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::ObstacleKind;
    use crate::Rect;
    use mapmerge_grid::{CellClass, ClassThresholds};

    #[test]
    fn walls_occupied_inside_free_outside_unknown() {
        let mut world = World::new("box");
        world.footprint.push(Rect::new(0.0, 0.0, 4.0, 4.0));
        world.add_obstacle(
            ObstacleKind::Wall,
            Shape::Rect(Rect::new(0.0, 0.0, 4.0, 0.2)),
            None,
        );
        // A door leaf thinner than a cell.
        world.add_obstacle(
            ObstacleKind::ClosedDoor,
            Shape::Rect(Rect::new(2.0, 1.0, 2.02, 3.0)),
            None,
        );
        let grid = world.to_grid(0.1).unwrap();
        let t = ClassThresholds::default();
        let class = |x: f64, y: f64| t.classify(grid.log_odds_at(&Point2::new(x, y)));
        assert_eq!(class(1.0, 0.1), CellClass::Occupied);
        assert_eq!(class(1.0, 2.0), CellClass::Free);
        assert_eq!(class(2.01, 2.0), CellClass::Occupied);
        assert_eq!(class(-0.5, 2.0), CellClass::Unknown);
        assert_eq!(class(4.5, 4.5), CellClass::Unknown);
        assert!(world.to_grid(0.0).is_err());
    }
}
