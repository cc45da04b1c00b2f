//! Cell classes as bytes, the common resolution, and the Manhattan distance transform.

use std::borrow::Cow;

use mapmerge_grid::{CellClass, ClassThresholds, GridGeometry, OccupancyGrid, Point2};

use crate::error::{GridMatchError, Which};

pub(crate) const UNKNOWN: u8 = 0;
pub(crate) const FREE: u8 = 1;
pub(crate) const OCCUPIED: u8 = 2;

/// Relative difference below which two resolutions count as equal.
const SAME_RESOLUTION_TOLERANCE: f64 = 1e-9;

/// One class byte per cell ([`UNKNOWN`], [`FREE`], [`OCCUPIED`]), row-major from the bottom.
#[derive(Clone, Debug)]
pub(crate) struct ClassRaster {
    pub geometry: GridGeometry,
    pub cells: Vec<u8>,
}

impl ClassRaster {
    /// Classifies every cell. Maps hold few distinct log-odds (a ROS map three), so the class
    /// of the previous value is reused: exact `ClassThresholds::classify` without an `exp`
    /// per cell.
    pub fn new(grid: &OccupancyGrid, thresholds: &ClassThresholds) -> Self {
        let mut last: Option<(f32, u8)> = None;
        let cells = grid
            .log_odds()
            .iter()
            .map(|&l| match last {
                Some((value, class)) if value.to_bits() == l.to_bits() => class,
                _ => {
                    let class = match thresholds.classify(l) {
                        CellClass::Unknown => UNKNOWN,
                        CellClass::Free => FREE,
                        CellClass::Occupied => OCCUPIED,
                    };
                    last = Some((l, class));
                    class
                }
            })
            .collect();
        Self {
            geometry: *grid.geometry(),
            cells,
        }
    }

    pub fn width(&self) -> usize {
        self.geometry.width
    }

    pub fn height(&self) -> usize {
        self.geometry.height
    }

    /// Centres (map frame, m) of the occupied cells.
    pub fn occupied_points(&self) -> Vec<Point2> {
        self.cells
            .iter()
            .enumerate()
            .filter(|&(_, &c)| c == OCCUPIED)
            .map(|(i, _)| self.geometry.center_of(self.geometry.cell_at(i)))
            .collect()
    }

    /// Refuses rasters with nothing to match.
    pub fn check(&self, which: Which) -> Result<(), GridMatchError> {
        if self.cells.is_empty() {
            return Err(GridMatchError::EmptyMap(which));
        }
        if !self.cells.iter().any(|&c| c != UNKNOWN) {
            return Err(GridMatchError::NoKnownCells(which));
        }
        if !self.cells.contains(&OCCUPIED) {
            return Err(GridMatchError::NoOccupiedCells(which));
        }
        Ok(())
    }
}

/// Both grids at the coarser of their resolutions: the finer one is resampled with
/// `OccupancyGrid::resample` (walls survive coarsening); frames and origins are unchanged,
/// so a transform between the maps stays valid. Returns the common resolution (m).
pub(crate) fn common_resolution<'a>(
    a: &'a OccupancyGrid,
    b: &'a OccupancyGrid,
) -> Result<(Cow<'a, OccupancyGrid>, Cow<'a, OccupancyGrid>, f64), GridMatchError> {
    let (ra, rb) = (a.resolution_m(), b.resolution_m());
    for (which, r) in [(Which::A, ra), (Which::B, rb)] {
        if !(r.is_finite() && r > 0.0) {
            return Err(GridMatchError::BadResolution {
                which,
                resolution_m: r,
            });
        }
    }
    if a.geometry().is_empty() {
        return Err(GridMatchError::EmptyMap(Which::A));
    }
    if b.geometry().is_empty() {
        return Err(GridMatchError::EmptyMap(Which::B));
    }
    let coarse = ra.max(rb);
    if (ra - rb).abs() <= SAME_RESOLUTION_TOLERANCE * coarse {
        return Ok((Cow::Borrowed(a), Cow::Borrowed(b), ra));
    }
    if ra < rb {
        Ok((Cow::Owned(a.resample(coarse)?), Cow::Borrowed(b), coarse))
    } else {
        Ok((Cow::Borrowed(a), Cow::Owned(b.resample(coarse)?), coarse))
    }
}

/// Exact city-block (L1) distance, in cells, from every cell to the nearest cell whose class
/// is `class` (Rosenfeld & Pfaltz 1966: two raster passes). `u32::MAX / 2` when there is none.
pub(crate) fn manhattan_distance(raster: &ClassRaster, class: u8, out: &mut Vec<u32>) {
    const FAR: u32 = u32::MAX / 2;
    let (w, h) = (raster.width(), raster.height());
    out.clear();
    out.extend(
        raster
            .cells
            .iter()
            .map(|&c| if c == class { 0 } else { FAR }),
    );
    if w == 0 || h == 0 {
        return;
    }
    // Forward pass: from the left and from below.
    for y in 0..h {
        let (done, rest) = out.split_at_mut(y * w);
        let row = &mut rest[..w];
        if y > 0 {
            let below = &done[(y - 1) * w..];
            for (d, &b) in row.iter_mut().zip(below) {
                *d = (*d).min(b.saturating_add(1));
            }
        }
        for x in 1..w {
            row[x] = row[x].min(row[x - 1].saturating_add(1));
        }
    }
    // Backward pass: from the right and from above.
    for y in (0..h).rev() {
        let (head, tail) = out.split_at_mut((y + 1) * w);
        let row = &mut head[y * w..];
        if y + 1 < h {
            let above = &tail[..w];
            for (d, &a) in row.iter_mut().zip(above) {
                *d = (*d).min(a.saturating_add(1));
            }
        }
        for x in (0..w.saturating_sub(1)).rev() {
            row[x] = row[x].min(row[x + 1].saturating_add(1));
        }
    }
    for d in out.iter_mut() {
        *d = (*d).min(FAR);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn manhattan_distance_equals_brute_force(flags in proptest::collection::vec(0u8..3, 1..300), width in 1usize..25) {
            let height = flags.len().div_ceil(width);
            let mut cells = flags;
            cells.resize(width * height, UNKNOWN);
            let raster = ClassRaster {
                geometry: GridGeometry { resolution_m: 0.1, origin_m: Point2::zeros(), width, height },
                cells: cells.clone(),
            };
            let mut out = Vec::new();
            manhattan_distance(&raster, OCCUPIED, &mut out);
            for (i, &found) in out.iter().enumerate() {
                let (x, y) = ((i % width) as i64, (i / width) as i64);
                let expected = (0..cells.len())
                    .filter(|&j| cells[j] == OCCUPIED)
                    .map(|j| ((j % width) as i64 - x).abs() + ((j / width) as i64 - y).abs())
                    .min()
                    .map_or(u32::MAX / 2, |d| d as u32);
                prop_assert_eq!(found, expected);
            }
        }
    }
}
