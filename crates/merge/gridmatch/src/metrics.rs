//! Map similarity metrics (Andersone, Sec. 3.3): SM (Eq. 1, Birk & Carpin 2006's acceptance
//! index ω) and the modified distance metric DM, with distance transforms.

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{ClassThresholds, OccupancyGrid, Point2};
use rayon::prelude::*;
use serde::Serialize;

use crate::error::GridMatchError;
use crate::raster::{common_resolution, manhattan_distance, ClassRaster, OCCUPIED, UNKNOWN};

/// How similar two maps are under a transform, over the cells known in both.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MapMetrics {
    /// Andersone Eq. 1: `agree / (agree + disagree)`, 0 when nothing agrees. This is Birk &
    /// Carpin 2006's acceptance index ω (Andersone quotes it as SM), in [0, 1].
    pub sm: f64,
    /// Modified distance metric (Andersone Sec. 3.3), in cells of the common resolution:
    /// `dm_occupied_cells + dm_free_cells`; 0 for identical maps, grows with misalignment.
    pub dm_cells: f64,
    /// DM's occupied part: mean Manhattan distance from each occupied cell of one map to
    /// the nearest occupied cell of the other, one mean per direction, summed (Birk & Carpin
    /// 2006's picture distance ψ restricted to cells known in both maps).
    pub dm_occupied_cells: f64,
    /// DM's free part, as `dm_occupied_cells` for free cells.
    pub dm_free_cells: f64,
    /// Cells (of A's lattice) known in both maps.
    pub overlap_cells: usize,
    /// Cells known in both with the same class.
    pub agree_cells: usize,
    /// Of those, occupied in both.
    pub agree_occupied_cells: usize,
    /// Cells occupied in one map and free in the other.
    pub disagree_cells: usize,
    /// The common resolution the metrics were computed at (m): the coarser of the two.
    pub resolution_m: f64,
}

impl MapMetrics {
    /// DM in metres.
    pub fn dm_m(&self) -> f64 {
        self.dm_cells * self.resolution_m
    }
}

/// SM and DM of map `b` placed in map `a`'s frame by `a_from_b` (a point `p_b` in B's map frame
/// is `a_from_b · p_b` in A's).
///
/// Both maps are first brought to the coarser resolution (the finer is resampled). Cells are
/// compared on A's lattice, B's class read at the cell containing each A cell's centre. Only
/// cells known in both maps count (Andersone's modification, Fig. 4d). The distance from a
/// cell to the nearest same-class cell of the other map is that map's own Manhattan distance
/// transform (exact, two raster passes), read at the cell: the paper's metric when the maps
/// are axis-aligned, and for rotated maps the city-block distance along the other map's own
/// axes (which lets each map's transforms be computed once for any number of transforms).
pub fn map_metrics(
    a: &OccupancyGrid,
    b: &OccupancyGrid,
    a_from_b: &Se2,
    thresholds: &ClassThresholds,
) -> Result<MapMetrics, GridMatchError> {
    if !(a_from_b.x_m.is_finite() && a_from_b.y_m.is_finite() && a_from_b.theta_rad.is_finite()) {
        return Err(GridMatchError::NonFiniteTransform);
    }
    let (a, b, _) = common_resolution(a, b)?;
    let (a, b) = rayon::join(
        || PreparedMap::new(ClassRaster::new(&a, thresholds)),
        || PreparedMap::new(ClassRaster::new(&b, thresholds)),
    );
    Ok(evaluate(&a, &b, a_from_b))
}

/// A map's classes and its two Manhattan distance transforms (occupied, free), in cells.
#[derive(Clone, Debug)]
pub(crate) struct PreparedMap {
    pub raster: ClassRaster,
    distance_to_occupied: Vec<u32>,
    distance_to_free: Vec<u32>,
}

impl PreparedMap {
    pub fn new(raster: ClassRaster) -> Self {
        let (mut occupied, mut free) = (Vec::new(), Vec::new());
        rayon::join(
            || manhattan_distance(&raster, OCCUPIED, &mut occupied),
            || manhattan_distance(&raster, crate::raster::FREE, &mut free),
        );
        // Cap "no such cell" at the map's largest possible distance.
        let cap = (raster.width() + raster.height()) as u32;
        for d in occupied.iter_mut().chain(free.iter_mut()) {
            *d = (*d).min(cap);
        }
        Self {
            raster,
            distance_to_occupied: occupied,
            distance_to_free: free,
        }
    }

    fn distance(&self, class: u8, index: usize) -> u64 {
        let field = if class == OCCUPIED {
            &self.distance_to_occupied
        } else {
            &self.distance_to_free
        };
        u64::from(field.get(index).copied().unwrap_or(0))
    }
}

/// Integer sums over the cells known in both maps (exact, so the parallel sum is
/// deterministic).
#[derive(Clone, Copy, Default)]
struct Sums {
    overlap: u64,
    agree: u64,
    agree_occupied: u64,
    /// Per class (free 0, occupied 1) and direction (A's cells 0, B's cells 1): sum of
    /// distances and count.
    distance: [[u64; 2]; 2],
    count: [[u64; 2]; 2],
}

impl Sums {
    fn add(mut self, other: Sums) -> Sums {
        self.overlap += other.overlap;
        self.agree += other.agree;
        self.agree_occupied += other.agree_occupied;
        for c in 0..2 {
            for d in 0..2 {
                self.distance[c][d] += other.distance[c][d];
                self.count[c][d] += other.count[c][d];
            }
        }
        self
    }
}

/// The rows of A's lattice (and their column range) that B's grid can reach under
/// `a_from_b`: A's extent intersected with the bounding box of B's corners.
fn window(
    a: &ClassRaster,
    b: &ClassRaster,
    a_from_b: &Se2,
) -> Option<(usize, usize, usize, usize)> {
    let (lo, hi) = b.geometry.bounds_m();
    let corners = [
        Point2::new(lo.x, lo.y),
        Point2::new(hi.x, lo.y),
        Point2::new(lo.x, hi.y),
        Point2::new(hi.x, hi.y),
    ]
    .map(|p| a_from_b.transform_point(&p));
    let r = a.geometry.resolution_m;
    let o = a.geometry.origin_m;
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for p in corners {
        x0 = x0.min((p.x - o.x) / r);
        y0 = y0.min((p.y - o.y) / r);
        x1 = x1.max((p.x - o.x) / r);
        y1 = y1.max((p.y - o.y) / r);
    }
    let clamp = |v: f64, n: usize| v.clamp(0.0, n as f64) as usize;
    let (x0, x1) = (
        clamp(x0.floor() - 1.0, a.width()),
        clamp(x1.ceil() + 1.0, a.width()),
    );
    let (y0, y1) = (
        clamp(y0.floor() - 1.0, a.height()),
        clamp(y1.ceil() + 1.0, a.height()),
    );
    (x0 < x1 && y0 < y1).then_some((x0, x1, y0, y1))
}

/// SM and DM of `b` under `a_from_b`, on A's lattice (both at the same resolution).
pub(crate) fn evaluate(a: &PreparedMap, b: &PreparedMap, a_from_b: &Se2) -> MapMetrics {
    let resolution_m = a.raster.geometry.resolution_m;
    let sums = match window(&a.raster, &b.raster, a_from_b) {
        Some((x0, x1, y0, y1)) => (y0..y1)
            .into_par_iter()
            .map(|y| row_sums(a, b, a_from_b, y, x0, x1))
            .reduce(Sums::default, Sums::add),
        None => Sums::default(),
    };
    let agree = sums.agree as usize;
    let overlap = sums.overlap as usize;
    let disagree = overlap - agree;
    let mean = |class: usize, direction: usize| {
        let n = sums.count[class][direction];
        if n == 0 {
            0.0
        } else {
            sums.distance[class][direction] as f64 / n as f64
        }
    };
    let dm_free_cells = mean(0, 0) + mean(0, 1);
    let dm_occupied_cells = mean(1, 0) + mean(1, 1);
    MapMetrics {
        sm: if agree == 0 {
            0.0
        } else {
            agree as f64 / overlap as f64
        },
        dm_cells: dm_occupied_cells + dm_free_cells,
        dm_occupied_cells,
        dm_free_cells,
        overlap_cells: overlap,
        agree_cells: agree,
        agree_occupied_cells: sums.agree_occupied as usize,
        disagree_cells: disagree,
        resolution_m,
    }
}

/// One row of A's lattice: B's cell under each A cell centre, walked incrementally.
fn row_sums(
    a: &PreparedMap,
    b: &PreparedMap,
    a_from_b: &Se2,
    y: usize,
    x0: usize,
    x1: usize,
) -> Sums {
    let ga = &a.raster.geometry;
    let gb = &b.raster.geometry;
    let b_from_a = a_from_b.inverse();
    let rotation = b_from_a.rotation_matrix();
    let inverse_rb = 1.0 / gb.resolution_m;
    let start = ga.origin_m + Point2::new(x0 as f64 + 0.5, y as f64 + 0.5) * ga.resolution_m;
    let mut q = (b_from_a.transform_point(&start) - gb.origin_m) * inverse_rb;
    let step = rotation * Point2::new(ga.resolution_m, 0.0) * inverse_rb;
    let (wb, hb) = (gb.width as f64, gb.height as f64);
    let mut sums = Sums::default();
    let row = y * ga.width;
    for x in x0..x1 {
        let here = q;
        q += step;
        if !(here.x >= 0.0 && here.y >= 0.0 && here.x < wb && here.y < hb) {
            continue;
        }
        let index_a = row + x;
        // A's class first: a sequential read that skips B's (scattered) one when unknown.
        let ca = a.raster.cells.get(index_a).copied().unwrap_or(UNKNOWN);
        if ca == UNKNOWN {
            continue;
        }
        let index_b = here.y as usize * gb.width + here.x as usize;
        let cb = b.raster.cells.get(index_b).copied().unwrap_or(UNKNOWN);
        if cb == UNKNOWN {
            continue;
        }
        sums.overlap += 1;
        if ca == cb {
            sums.agree += 1;
            sums.agree_occupied += u64::from(ca == OCCUPIED);
        }
        // Andersone Sec. 3.3: each cell's distance to the nearest same-valued cell of the
        // other map, per class and direction.
        let class_a = usize::from(ca == OCCUPIED);
        sums.distance[class_a][0] += b.distance(ca, index_b);
        sums.count[class_a][0] += 1;
        let class_b = usize::from(cb == OCCUPIED);
        sums.distance[class_b][1] += a.distance(cb, index_a);
        sums.count[class_b][1] += 1;
    }
    sums
}
