//! Binary cell masks: dilation with a square kernel and the exact Euclidean distance
//! transform (Felzenszwalb & Huttenlocher 2012, "Distance Transforms of Sampled Functions").

use serde::{Deserialize, Serialize};

use crate::{Cell, CellClass, ClassThresholds, GridGeometry, OccupancyGrid};

/// One bool per cell of a grid (row-major, row 0 at the bottom).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CellMask {
    geometry: GridGeometry,
    set: Vec<bool>,
}

/// Distance (m) from every cell centre to the nearest set cell's centre of a [`CellMask`];
/// `f32::INFINITY` when the mask is empty.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DistanceField {
    geometry: GridGeometry,
    distance_m: Vec<f32>,
}

impl OccupancyGrid {
    /// The cells of class `class`.
    pub fn mask(&self, class: CellClass, thresholds: &ClassThresholds) -> CellMask {
        let mut classify = thresholds.classifier();
        CellMask {
            geometry: *self.geometry(),
            set: self
                .log_odds()
                .iter()
                .map(|&l| classify(l) == class)
                .collect(),
        }
    }
}

impl CellMask {
    /// A mask from row-major flags; `None` when the length does not match the geometry.
    pub fn from_flags(geometry: GridGeometry, set: Vec<bool>) -> Option<Self> {
        (set.len() == geometry.len()).then_some(Self { geometry, set })
    }

    /// Size and placement.
    pub fn geometry(&self) -> &GridGeometry {
        &self.geometry
    }

    /// Row-major flags.
    pub fn flags(&self) -> &[bool] {
        &self.set
    }

    /// Whether `cell` is set (false outside).
    pub fn is_set(&self, cell: Cell) -> bool {
        self.geometry
            .index_of(cell)
            .and_then(|i| self.set.get(i).copied())
            .unwrap_or(false)
    }

    /// Number of set cells.
    pub fn count(&self) -> usize {
        self.set.iter().filter(|&&s| s).count()
    }

    /// Dilation by a `(2r + 1) × (2r + 1)` square (`radius_cells = 3` is a 7 × 7 kernel):
    /// a cell is set when any cell of the square around it is. Separable, O(cells).
    pub fn dilate(&self, radius_cells: usize) -> CellMask {
        let (w, h) = (self.geometry.width, self.geometry.height);
        let rows = dilate_lines(&self.set, w, h, radius_cells, 1, w);
        let both = dilate_lines(&rows, h, w, radius_cells, w, 1);
        CellMask {
            geometry: self.geometry,
            set: both,
        }
    }

    /// Exact Euclidean distance (m) from every cell to the nearest set cell.
    pub fn distance_transform(&self) -> DistanceField {
        let (w, h) = (self.geometry.width, self.geometry.height);
        let far = ((w + h) as f64).powi(2) + 1.0;
        let mut squared: Vec<f64> = self
            .set
            .iter()
            .map(|&s| if s { 0.0 } else { far })
            .collect();
        let mut line = Vec::new();
        let mut out = Vec::new();
        let mut scratch = EdtScratch::default();
        // Columns, then rows (the 2D transform is separable).
        for (count, length, stride, step) in [(w, h, 1, w), (h, w, w, 1)] {
            for k in 0..count {
                line.clear();
                line.extend(
                    (0..length).filter_map(|i| squared.get(k * stride + i * step).copied()),
                );
                squared_edt_1d(&line, &mut out, &mut scratch);
                for (i, &v) in out.iter().enumerate() {
                    if let Some(slot) = squared.get_mut(k * stride + i * step) {
                        *slot = v;
                    }
                }
            }
        }
        let resolution = self.geometry.resolution_m;
        let empty = !self.set.iter().any(|&s| s);
        DistanceField {
            geometry: self.geometry,
            distance_m: squared
                .iter()
                .map(|&d| {
                    if empty {
                        f32::INFINITY
                    } else {
                        (d.sqrt() * resolution) as f32
                    }
                })
                .collect(),
        }
    }
}

impl DistanceField {
    /// Size and placement.
    pub fn geometry(&self) -> &GridGeometry {
        &self.geometry
    }

    /// Row-major distances (m).
    pub fn distances_m(&self) -> &[f32] {
        &self.distance_m
    }

    /// Distance at `cell`; infinity outside the grid.
    pub fn at(&self, cell: Cell) -> f32 {
        self.geometry
            .index_of(cell)
            .and_then(|i| self.distance_m.get(i).copied())
            .unwrap_or(f32::INFINITY)
    }
}

/// Running-window dilation of `count` lines of `length` cells; element `i` of line `k` is at
/// `k · stride + i · step`.
fn dilate_lines(
    input: &[bool],
    length: usize,
    count: usize,
    radius: usize,
    step: usize,
    stride: usize,
) -> Vec<bool> {
    let mut out = vec![false; input.len()];
    for k in 0..count {
        let at = |i: usize| input.get(k * stride + i * step).copied().unwrap_or(false);
        // Number of set cells in the window [i − r, i + r].
        let mut in_window = (0..=radius.min(length.saturating_sub(1)))
            .filter(|&i| at(i))
            .count();
        for i in 0..length {
            if let Some(slot) = out.get_mut(k * stride + i * step) {
                *slot = in_window > 0;
            }
            let entering = i + radius + 1;
            if entering < length && at(entering) {
                in_window += 1;
            }
            if i >= radius && at(i - radius) {
                in_window -= 1;
            }
        }
    }
    out
}

#[derive(Default)]
struct EdtScratch {
    vertices: Vec<usize>,
    boundaries: Vec<f64>,
}

/// The 1D squared distance transform of `f` (lower envelope of parabolas).
fn squared_edt_1d(f: &[f64], out: &mut Vec<f64>, scratch: &mut EdtScratch) {
    let n = f.len();
    out.clear();
    out.resize(n, 0.0);
    if n == 0 {
        return;
    }
    let v = &mut scratch.vertices;
    let z = &mut scratch.boundaries;
    v.clear();
    z.clear();
    v.push(0);
    z.push(f64::NEG_INFINITY);
    z.push(f64::INFINITY);
    let value = |i: usize| f.get(i).copied().unwrap_or(f64::INFINITY);
    for q in 1..n {
        while let Some(&p) = v.last() {
            let (qf, pf) = (q as f64, p as f64);
            let s = ((value(q) + qf * qf) - (value(p) + pf * pf)) / (2.0 * qf - 2.0 * pf);
            let k = v.len() - 1;
            if k > 0 && z.get(k).is_some_and(|&zk| s <= zk) {
                v.pop();
                z.pop();
                continue;
            }
            v.push(q);
            if let Some(last) = z.last_mut() {
                *last = s;
            }
            z.push(f64::INFINITY);
            break;
        }
    }
    let mut k = 0;
    for (q, slot) in out.iter_mut().enumerate() {
        while z.get(k + 1).is_some_and(|&zk| zk < q as f64) {
            k += 1;
        }
        let p = v.get(k).copied().unwrap_or(0);
        let d = q as f64 - p as f64;
        *slot = d * d + value(p);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Point2;
    use proptest::prelude::*;

    fn geometry(width: usize, height: usize) -> GridGeometry {
        GridGeometry {
            resolution_m: 0.5,
            origin_m: Point2::zeros(),
            width,
            height,
        }
    }

    proptest! {
        #[test]
        fn distance_transform_equals_brute_force(flags in proptest::collection::vec(proptest::bool::weighted(0.08), 1..300), width in 1usize..25) {
            let height = flags.len().div_ceil(width);
            let mut flags = flags;
            flags.resize(width * height, false);
            let mask = CellMask::from_flags(geometry(width, height), flags.clone()).unwrap();
            let field = mask.distance_transform();
            let set: Vec<Cell> = (0..flags.len()).filter(|&i| flags[i]).map(|i| mask.geometry().cell_at(i)).collect();
            for i in 0..flags.len() {
                let c = mask.geometry().cell_at(i);
                let expected = set.iter().map(|s| (((s.x - c.x).pow(2) + (s.y - c.y).pow(2)) as f64).sqrt() * 0.5)
                    .fold(f64::INFINITY, f64::min);
                prop_assert!((f64::from(field.distances_m()[i]) - expected).abs() < 1e-4 || (expected.is_infinite() && field.distances_m()[i].is_infinite()));
            }
        }

        #[test]
        fn dilation_equals_brute_force(flags in proptest::collection::vec(proptest::bool::weighted(0.05), 1..300), width in 1usize..25, radius in 0usize..4) {
            let height = flags.len().div_ceil(width);
            let mut flags = flags;
            flags.resize(width * height, false);
            let mask = CellMask::from_flags(geometry(width, height), flags).unwrap();
            let dilated = mask.dilate(radius);
            for i in 0..mask.flags().len() {
                let c = mask.geometry().cell_at(i);
                let r = radius as i64;
                let expected = (-r..=r).any(|dy| (-r..=r).any(|dx| mask.is_set(Cell::new(c.x + dx, c.y + dy))));
                prop_assert_eq!(dilated.flags()[i], expected);
            }
        }
    }
}
