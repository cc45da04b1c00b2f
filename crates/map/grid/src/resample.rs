//! Resampling a grid to another resolution (maps of different robots, Andersone Sec. 3.2).

use crate::{GridError, GridGeometry, OccupancyGrid};

/// Cells of the source grid overlapping a cell of the target, along one axis:
/// `(source index, overlap length in source cells)`.
fn overlaps(target_count: usize, ratio: f64, source_count: usize) -> Vec<Vec<(usize, f64)>> {
    (0..target_count)
        .map(|t| {
            let (lo, hi) = (t as f64 * ratio, (t + 1) as f64 * ratio);
            let first = lo.floor().max(0.0) as usize;
            let last = (hi.ceil() as usize).min(source_count);
            (first..last)
                .filter_map(|s| {
                    let overlap = hi.min((s + 1) as f64) - lo.max(s as f64);
                    (overlap > 1e-9).then_some((s, overlap))
                })
                .collect()
        })
        .collect()
}

impl OccupancyGrid {
    /// The grid at another resolution, covering the same area (same origin).
    ///
    /// Each target cell looks at the source cells it overlaps: if any of them is evidence of
    /// an obstacle (log-odds > 0) it takes the largest such value, so thin walls survive
    /// coarsening; otherwise it takes the overlap-weighted mean of the known (non-zero)
    /// cells, and stays unknown when known cells cover less than half of it.
    pub fn resample(&self, resolution_m: f64) -> Result<OccupancyGrid, GridError> {
        if !(resolution_m.is_finite() && resolution_m > 0.0) {
            return Err(GridError::BadResolution(resolution_m));
        }
        let source = self.geometry();
        let ratio = resolution_m / source.resolution_m;
        let width = (source.width as f64 / ratio).ceil() as usize;
        let height = (source.height as f64 / ratio).ceil() as usize;
        let geometry = GridGeometry {
            resolution_m,
            origin_m: source.origin_m,
            width,
            height,
        };
        let columns = overlaps(width, ratio, source.width);
        let rows = overlaps(height, ratio, source.height);
        let cell_area = ratio * ratio;
        let log_odds = self.log_odds();
        let mut out = Vec::with_capacity(geometry.len());
        for row in &rows {
            for column in &columns {
                let (mut strongest, mut known_area, mut weighted) = (0.0f32, 0.0f64, 0.0f64);
                for &(sy, wy) in row {
                    for &(sx, wx) in column {
                        let l = log_odds.get(sy * source.width + sx).copied().unwrap_or(0.0);
                        if l != 0.0 {
                            strongest = strongest.max(l);
                            known_area += wx * wy;
                            weighted += f64::from(l) * wx * wy;
                        }
                    }
                }
                out.push(if strongest > 0.0 {
                    strongest
                } else if known_area > 0.0 && known_area * 2.0 >= cell_area {
                    (weighted / known_area) as f32
                } else {
                    0.0
                });
            }
        }
        OccupancyGrid::from_log_odds(geometry, out)
    }
}

#[cfg(test)]
mod tests {
    use crate::{Cell, GridGeometry, OccupancyGrid, Point2};

    fn grid(
        resolution_m: f64,
        width: usize,
        height: usize,
        values: &[(i64, i64, f32)],
    ) -> OccupancyGrid {
        let geometry = GridGeometry {
            resolution_m,
            origin_m: Point2::new(-1.0, 2.0),
            width,
            height,
        };
        let mut g = OccupancyGrid::with_geometry(geometry).unwrap();
        for &(x, y, l) in values {
            g.set(Cell::new(x, y), l).unwrap();
        }
        g
    }

    #[test]
    fn coarsening_keeps_walls_and_averages_free_space() {
        // 4x4 at 0.05 → 2x2 at 0.10: one wall cell, one free block, one half-known block.
        let fine = grid(
            0.05,
            4,
            4,
            &[
                (1, 0, 2.0),
                (0, 0, -1.0),
                (2, 0, -1.0),
                (3, 0, -2.0),
                (2, 1, -1.0),
                (3, 1, -2.0),
                (0, 2, -1.0),
            ],
        );
        let coarse = fine.resample(0.10).unwrap();
        assert_eq!(coarse.geometry().width, 2);
        assert_eq!(coarse.cell_log_odds(Cell::new(0, 0)), 2.0);
        assert_eq!(coarse.cell_log_odds(Cell::new(1, 0)), -1.5);
        assert_eq!(
            coarse.cell_log_odds(Cell::new(0, 1)),
            0.0,
            "one known quarter stays unknown"
        );
        assert_eq!(coarse.cell_log_odds(Cell::new(1, 1)), 0.0);
    }

    #[test]
    fn refining_copies_values_and_round_trips() {
        let coarse = grid(0.10, 3, 2, &[(0, 0, 2.0), (1, 0, -1.0), (2, 1, -0.5)]);
        let fine = coarse.resample(0.05).unwrap();
        assert_eq!((fine.geometry().width, fine.geometry().height), (6, 4));
        assert_eq!(fine.cell_log_odds(Cell::new(1, 1)), 2.0);
        assert_eq!(fine.cell_log_odds(Cell::new(5, 3)), -0.5);
        assert_eq!(fine.resample(0.10).unwrap(), coarse);
        // A non-integer ratio still lands each value in the right place.
        let odd = coarse.resample(0.07).unwrap();
        assert_eq!(odd.log_odds_at(&Point2::new(-0.95, 2.05)), 2.0);
    }
}
