//! Matching two occupancy grids without an initial guess: rotations from Hough spectra
//! (Carpin 2008), translations by FFT correlation, refinement by correlative
//! branch-and-bound (`mapmerge-scanmatch`), ranking and acceptance with SM / DM.

use std::f64::consts::PI;

use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_grid::{OccupancyGrid, Point2};
use mapmerge_scanmatch::{
    match_scan, refine_icp, CorrelativeParams, IcpParams, IcpTarget, MatchTarget, SearchWindow,
};
use rayon::prelude::*;
use serde::Serialize;

use crate::correlate::{CoarseCandidate, CoarseMap, TranslationSearch};
use crate::error::{GridMatchError, Which};
use crate::hough::{hough_spectrum, rotation_peaks, spectrum_correlation};
use crate::metrics::{evaluate, MapMetrics, PreparedMap};
use crate::orientation::{orientation_histogram, smooth_circular};
use crate::params::GridMatchParams;
use crate::raster::{common_resolution, ClassRaster, OCCUPIED, UNKNOWN};

/// Occupied cells voting in each local-orientation histogram (evenly strided): enough for a
/// histogram of 360 bins, and a bound on its cost.
const ORIENTATION_MAX_SAMPLES: usize = 8_000;

/// B's occupied cells (evenly strided) in the ICP polish.
const ICP_MAX_POINTS: usize = 2_000;

/// Occupied (pooled) cells entering each Hough spectrum (evenly strided), a bound on its cost.
const HOUGH_MAX_POINTS: usize = 8_000;

/// One candidate placement of B in A.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MatchHypothesis {
    /// B's map frame in A's map frame: `p_a = a_from_b · p_b` (m, rad).
    pub a_from_b: Se2,
    /// Birk & Carpin 2006's acceptance index ω = agree / (agree + disagree) over the cells
    /// known in both maps (equal to `metrics.sm`, Andersone Eq. 1).
    pub acceptance: f64,
    /// The ranking score: `o · occupied agreements + free agreements − d · disagreements`
    /// (cells; `o`, `d`: `GridMatchParams::rank_occupied_weight`, `rank_disagree_weight`).
    pub score: f64,
    /// SM, DM and the overlap.
    pub metrics: MapMetrics,
    /// Mean likelihood of B's occupied cells in A's occupied-cell field after refinement
    /// (scan matcher score, [0, 1]; B's cells outside the overlap count 0).
    pub refinement_score: f64,
}

/// Why the best hypothesis was not accepted.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[non_exhaustive]
pub enum MatchRejection {
    /// No hypothesis at all (no rotation or translation peak).
    NoHypothesis,
    /// ω below `AcceptanceParams::min_acceptance`.
    LowAcceptance {
        /// ω of the best hypothesis.
        acceptance: f64,
        /// The threshold.
        min: f64,
    },
    /// Overlap below `AcceptanceParams::min_overlap_fraction`.
    SmallOverlap {
        /// Cells known in both.
        cells: usize,
        /// The threshold (cells).
        min: usize,
    },
    /// DM above `AcceptanceParams::max_dm_cells`.
    HighDistance {
        /// DM of the best hypothesis (cells).
        dm_cells: f64,
        /// The threshold.
        max: f64,
    },
    /// A distinct runner-up agrees better (higher ω) and lies closer (lower DM) than the
    /// best, which outscores it only by a larger overlap (e.g. a 180° look-alike of a
    /// corridor): one of the two is wrong, and the score cannot tell which.
    Dominated {
        /// ω of the runner-up.
        acceptance: f64,
        /// DM of the runner-up (cells).
        dm_cells: f64,
    },
    /// A distinct runner-up scores almost as well.
    Ambiguous {
        /// `(best − runner_up) / best`.
        margin: f64,
        /// The threshold.
        min: f64,
    },
}

impl std::fmt::Display for MatchRejection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MatchRejection::NoHypothesis => write!(f, "no hypothesis"),
            MatchRejection::LowAcceptance { acceptance, min } => {
                write!(f, "acceptance {acceptance:.3} below {min:.3}")
            }
            MatchRejection::SmallOverlap { cells, min } => {
                write!(f, "overlap of {cells} cells below {min}")
            }
            MatchRejection::HighDistance { dm_cells, max } => {
                write!(f, "DM {dm_cells:.2} cells above {max:.2}")
            }
            MatchRejection::Dominated {
                acceptance,
                dm_cells,
            } => write!(
                f,
                "a runner-up agrees better (ω {acceptance:.3}) and lies closer (DM {dm_cells:.2} cells)"
            ),
            MatchRejection::Ambiguous { margin, min } => {
                write!(f, "margin {margin:.3} over the runner-up below {min:.3}")
            }
        }
    }
}

/// The result of [`match_grids`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GridMatch {
    /// Distinct hypotheses, best first (by `score`).
    pub hypotheses: Vec<MatchHypothesis>,
    /// Whether `hypotheses[0]` passes the acceptance rule.
    pub accepted: bool,
    /// Why not, when not accepted.
    pub rejection: Option<MatchRejection>,
    /// `(best − runner_up) / best` of the scores; 1 without a runner-up.
    pub margin: f64,
    /// The common resolution the maps were matched at (m): the coarser one.
    pub resolution_m: f64,
    /// The rotation hypotheses (rad, in (−π, π]): the Hough spectra's, best peak first, then
    /// the local-orientation histograms' that are new.
    pub rotations_rad: Vec<f64>,
    /// Pooling factor of the coarse correlation raster.
    pub coarse_factor: usize,
}

impl GridMatch {
    /// The accepted hypothesis, if any.
    pub fn best(&self) -> Option<&MatchHypothesis> {
        self.accepted.then(|| self.hypotheses.first()).flatten()
    }
}

/// Finds where map `b` lies in map `a` without an initial guess (Carpin 2008).
///
/// 1. Both maps go to the coarser resolution (the finer is resampled; walls survive).
/// 2. Rotation hypotheses: peaks of the circular cross-correlation of the maps' Hough
///    spectra, and of their local wall-orientation histograms (every wall segment votes
///    for its direction, so partial crops still agree), each as θ and θ + π.
/// 3. Per rotation, translations: peaks of the FFT cross-correlation of coarse class rasters
///    over the whole overlap (occupied `w`, free −1, unknown 0).
/// 4. Refinement of the best candidates at full resolution: correlative branch-and-bound
///    over a small window (coarse cell ± `refine_margin_cells`, ± `refine_angle_rad`);
///    point-to-line ICP on the best.
/// 5. SM, DM and ω of each; distinct hypotheses ranked by score; the acceptance rule
///    (ω, overlap, DM, margin over the runner-up, no runner-up better in both ω and DM).
///
/// Deterministic: the same inputs give the same output on any number of threads.
pub fn match_grids(
    a: &OccupancyGrid,
    b: &OccupancyGrid,
    params: &GridMatchParams,
) -> Result<GridMatch, GridMatchError> {
    params.validate()?;
    // 1. Common resolution.
    let (a, b, resolution_m) = common_resolution(a, b)?;
    for (which, grid) in [(Which::A, &a), (Which::B, &b)] {
        let cells = grid.geometry().len();
        if cells > params.max_cells {
            return Err(GridMatchError::TooLarge {
                which,
                cells,
                max_cells: params.max_cells,
            });
        }
    }
    let thresholds = &params.thresholds;
    let (raster_a, raster_b) = rayon::join(
        || ClassRaster::new(&a, thresholds),
        || ClassRaster::new(&b, thresholds),
    );
    raster_a.check(Which::A)?;
    raster_b.check(Which::B)?;

    // 2. Rotation hypotheses (Carpin 2008, Sec. 3).
    let rotations = rotation_hypotheses(&raster_a, &raster_b, params);

    // 3. Translations by correlation of coarse rasters (Carpin 2008, Sec. 4).
    let longest = [
        raster_a.width(),
        raster_a.height(),
        raster_b.width(),
        raster_b.height(),
    ]
    .into_iter()
    .max()
    .unwrap_or(1);
    let factor = longest.div_ceil(params.coarse_max_cells).max(1);
    let (coarse_a, coarse_b) = rayon::join(
        || CoarseMap::pool(&raster_a, factor),
        || CoarseMap::pool(&raster_b, factor),
    );
    let b_extent = ((coarse_b.width.pow(2) + coarse_b.height.pow(2)) as f64)
        .sqrt()
        .ceil() as usize
        + 2;
    let search = TranslationSearch::new(coarse_a, b_extent, params.occupied_weight);
    let candidates = search.search(&coarse_b, &rotations, params.translation_peaks, 2);
    let chosen = choose_candidates(candidates, params.refine_candidates);

    // 4. Refinement at full resolution: branch-and-bound, then ICP on the best one.
    let b_points = raster_b.occupied_points();
    let b_centroid = b_points.iter().sum::<Point2>() / b_points.len().max(1) as f64;
    let query = Query::new(&b_points, &b_centroid, params.refine_max_points);
    let a_points = raster_a.occupied_points();
    let linear_m = (factor as f64 + params.refine_margin_cells) * resolution_m;
    let linear_cells = (linear_m / resolution_m).ceil() as usize;
    let correlative = CorrelativeParams {
        resolution_m,
        kernel_sigma_cells: params.refine_kernel_sigma_cells,
        branch_and_bound_depth: ((usize::BITS - (2 * linear_cells).leading_zeros()) as usize)
            .clamp(1, 16),
        min_score: 0.0,
        query_voxel_m: 0.0,
        covariance_half_width: 0,
        max_grid_cells: (params.max_cells as u64).saturating_mul(2),
    };
    let icp_params = IcpParams {
        max_correspondence_m: 3.0 * resolution_m,
        huber_m: 0.5 * resolution_m,
        normal_radius_m: 3.0 * resolution_m,
        target_voxel_m: resolution_m,
        ..IcpParams::default()
    };
    // The maps' distance transforms (for the metrics) are computed beside the refinement,
    // whose first search runs alone.
    let (refined, (a, b)) = rayon::join(
        || {
            let target = MatchTarget::new(&a_points, &correlative)?;
            refine(&target, &a_points, &query, &chosen, linear_m, params)
        },
        || rayon::join(|| PreparedMap::new(raster_a), || PreparedMap::new(raster_b)),
    );
    let refined = refined?;

    // 5. Metrics, ranking; ICP on the best, kept when it raises the score.
    let hypothesis = |a_from_b: Se2, refinement_score: f64| {
        let metrics = evaluate(&a, &b, &a_from_b);
        let free_agree = metrics.agree_cells - metrics.agree_occupied_cells;
        MatchHypothesis {
            a_from_b,
            acceptance: metrics.sm,
            score: params.rank_occupied_weight * metrics.agree_occupied_cells as f64
                + free_agree as f64
                - params.rank_disagree_weight * metrics.disagree_cells as f64,
            metrics,
            refinement_score,
        }
    };
    let by_score = |l: &MatchHypothesis, r: &MatchHypothesis| r.score.total_cmp(&l.score);
    let mut hypotheses: Vec<MatchHypothesis> = refined
        .par_iter()
        .map(|&(a_from_b, refinement_score)| hypothesis(a_from_b, refinement_score))
        .collect();
    hypotheses.sort_by(by_score);
    let polish_count = params.polish_candidates.min(hypotheses.len());
    // ICP's target: A's occupied cells near B's (the query's) under the hypotheses polished,
    // found on a lattice of `reach_m` cells; the rest cannot be matched.
    let reach_m = icp_params.max_correspondence_m + icp_params.normal_radius_m;
    let (lo, hi) = a.raster.geometry.bounds_m();
    let columns = ((hi.x - lo.x) / reach_m).ceil() as i64 + 1;
    let rows = ((hi.y - lo.y) / reach_m).ceil() as i64 + 1;
    let lattice = |p: &Point2| {
        (
            ((p.x - lo.x) / reach_m).floor() as i64,
            ((p.y - lo.y) / reach_m).floor() as i64,
        )
    };
    let mut near_b = vec![false; (columns * rows) as usize];
    for h in &hypotheses[..polish_count] {
        let a_from_query = h.a_from_b.compose(&query.b_from_query);
        for q in &query.points {
            let (i, j) = lattice(&a_from_query.transform_point(q));
            for (u, v) in (j - 1..=j + 1).flat_map(|v| (i - 1..=i + 1).map(move |u| (u, v))) {
                if (0..columns).contains(&u) && (0..rows).contains(&v) {
                    near_b[(v * columns + u) as usize] = true;
                }
            }
        }
    }
    let near: Vec<Point2> = a_points
        .iter()
        .filter(|p| {
            let (i, j) = lattice(p);
            (0..columns).contains(&i)
                && (0..rows).contains(&j)
                && near_b[(j * columns + i) as usize]
        })
        .copied()
        .collect();
    let icp_target = IcpTarget::new(&near, &icp_params);
    // ICP needs fewer of B's cells than the search: a line fit per correspondence.
    let icp_query = Query::new(&b_points, &b_centroid, ICP_MAX_POINTS);
    let polished: Vec<MatchHypothesis> = hypotheses[..polish_count]
        .par_iter()
        .map(|h| {
            polish(&icp_target, &icp_query, &h.a_from_b, &icp_params)
                .map(|pose| hypothesis(pose, h.refinement_score))
                .filter(|p| p.score > h.score)
                .unwrap_or(*h)
        })
        .collect();
    hypotheses.splice(..polish_count, polished);
    hypotheses.sort_by(by_score);
    let distinct = |h: &MatchHypothesis, g: &MatchHypothesis| {
        let d = (h.a_from_b.transform_point(&b_centroid) - g.a_from_b.transform_point(&b_centroid))
            .norm()
            / resolution_m;
        let turn = wrap_angle_rad(h.a_from_b.theta_rad - g.a_from_b.theta_rad).abs();
        d > params.distinct_cells || turn > params.distinct_rad
    };
    let mut kept: Vec<MatchHypothesis> = Vec::new();
    for h in hypotheses {
        if kept.iter().all(|g| distinct(&h, g)) {
            kept.push(h);
        }
    }
    let known = |r: &ClassRaster| r.cells.iter().filter(|&&c| c != UNKNOWN).count();
    let min_overlap = (params.acceptance.min_overlap_fraction
        * known(&a.raster).min(known(&b.raster)) as f64)
        .ceil()
        .max(1.0) as usize;
    let margin = match (kept.first(), kept.get(1)) {
        (Some(best), Some(runner_up)) if best.score > 0.0 => {
            (best.score - runner_up.score.max(0.0)) / best.score
        }
        (Some(best), _) if best.score > 0.0 => 1.0,
        _ => 0.0,
    };
    let rejection = match kept.first() {
        None => Some(MatchRejection::NoHypothesis),
        Some(best) if best.acceptance < params.acceptance.min_acceptance => {
            Some(MatchRejection::LowAcceptance {
                acceptance: best.acceptance,
                min: params.acceptance.min_acceptance,
            })
        }
        Some(best) if best.metrics.overlap_cells < min_overlap => {
            Some(MatchRejection::SmallOverlap {
                cells: best.metrics.overlap_cells,
                min: min_overlap,
            })
        }
        Some(best) if best.metrics.dm_cells > params.acceptance.max_dm_cells => {
            Some(MatchRejection::HighDistance {
                dm_cells: best.metrics.dm_cells,
                max: params.acceptance.max_dm_cells,
            })
        }
        Some(_) if margin < params.acceptance.min_margin => Some(MatchRejection::Ambiguous {
            margin,
            min: params.acceptance.min_margin,
        }),
        Some(best) => kept
            .iter()
            .skip(1)
            .find(|r| {
                r.acceptance > best.acceptance
                    && r.metrics.dm_cells < best.metrics.dm_cells
                    && r.metrics.overlap_cells >= min_overlap
                    && 2 * r.metrics.overlap_cells >= best.metrics.overlap_cells
            })
            .map(|r| MatchRejection::Dominated {
                acceptance: r.acceptance,
                dm_cells: r.metrics.dm_cells,
            }),
    };
    Ok(GridMatch {
        hypotheses: kept,
        accepted: rejection.is_none(),
        rejection,
        margin,
        resolution_m,
        rotations_rad: rotations,
        coarse_factor: factor,
    })
}

/// Rotation hypotheses, each as θ and θ + π: first the peaks of the cross-correlated Hough
/// spectra (Carpin 2008, Sec. 3), then those of the cross-correlated local-orientation
/// histograms (`orientation.rs`) not within `rotation_merge_rad` of one already kept.
fn rotation_hypotheses(a: &ClassRaster, b: &ClassRaster, params: &GridMatchParams) -> Vec<f64> {
    let occupied = |r: &ClassRaster| {
        let pooled = CoarseMap::pool(r, params.hough_rho_cells);
        let points = pooled
            .codes
            .iter()
            .enumerate()
            .filter(|&(_, &c)| c == OCCUPIED)
            .map(|(i, _)| {
                let (x, y) = (i % pooled.width, i / pooled.width);
                pooled.origin_m + Point2::new(x as f64 + 0.5, y as f64 + 0.5) * pooled.cell_m
            })
            .collect::<Vec<_>>();
        // An even subsample keeps the spectrum's shape (every H(θ, ρ) scales alike).
        let stride = points.len().div_ceil(HOUGH_MAX_POINTS).max(1);
        points.into_iter().step_by(stride).collect::<Vec<_>>()
    };
    let rho_bin_m = a.geometry.resolution_m * params.hough_rho_cells as f64;
    let bins = params.hough_angle_bins;
    let orientation = |r: &ClassRaster| {
        smooth_circular(
            &orientation_histogram(
                r,
                params.orientation_radius_cells,
                bins,
                ORIENTATION_MAX_SAMPLES,
            ),
            1.0,
        )
    };
    let ((spectrum_a, spectrum_b), (histogram_a, histogram_b)) = rayon::join(
        || {
            rayon::join(
                || hough_spectrum(&occupied(a), rho_bin_m, bins),
                || hough_spectrum(&occupied(b), rho_bin_m, bins),
            )
        },
        || {
            if params.orientation_peaks == 0 {
                (Vec::new(), Vec::new())
            } else {
                rayon::join(|| orientation(a), || orientation(b))
            }
        },
    );
    // Peaks at least 3° apart.
    let separation = ((3f64.to_radians() / (PI / bins as f64)).round() as usize).max(1);
    let mut peaks = rotation_peaks(
        &spectrum_correlation(&spectrum_a, &spectrum_b),
        params.rotation_peaks,
        separation,
    );
    let orientation_peaks = rotation_peaks(
        &spectrum_correlation(&histogram_a, &histogram_b),
        params.orientation_peaks,
        separation,
    );
    for (theta, value) in orientation_peaks {
        let near = |&(kept, _): &(f64, f64)| {
            wrap_angle_rad(2.0 * (theta - kept)).abs() / 2.0 <= params.rotation_merge_rad
        };
        if !peaks.iter().any(near) {
            peaks.push((theta, value));
        }
    }
    peaks
        .into_iter()
        .flat_map(|(theta, _)| [wrap_angle_rad(theta), wrap_angle_rad(theta + PI)])
        .collect()
}

/// The best candidate of every rotation first (so θ + π and the 90° turns are always
/// refined), then the rest by score; at most `count`.
fn choose_candidates(mut candidates: Vec<CoarseCandidate>, count: usize) -> Vec<CoarseCandidate> {
    let order = |l: &CoarseCandidate, r: &CoarseCandidate| {
        r.score
            .total_cmp(&l.score)
            .then(l.rotation.cmp(&r.rotation))
            .then(l.a_from_b.x_m.total_cmp(&r.a_from_b.x_m))
            .then(l.a_from_b.y_m.total_cmp(&r.a_from_b.y_m))
    };
    candidates.sort_by(order);
    let mut first = Vec::new();
    let mut rest = Vec::new();
    let mut seen = Vec::new();
    for c in candidates {
        if seen.contains(&c.rotation) {
            rest.push(c);
        } else {
            seen.push(c.rotation);
            first.push(c);
        }
    }
    first.truncate(count);
    let room = count - first.len();
    first.extend(rest.into_iter().take(room));
    first
}

/// B's occupied cells (evenly strided), about their centroid, for the refinement: the
/// search's angular step (Hess et al. 2016, Eq. 7) and its rotations are about the middle.
struct Query {
    points: Vec<Point2>,
    b_from_query: Se2,
    query_from_b: Se2,
}

impl Query {
    fn new(b_points: &[Point2], b_centroid: &Point2, max_points: usize) -> Self {
        let stride = b_points.len().div_ceil(max_points).max(1);
        let b_from_query = Se2::new(b_centroid.x, b_centroid.y, 0.0);
        Self {
            points: b_points
                .iter()
                .step_by(stride)
                .map(|p| p - b_centroid)
                .collect(),
            b_from_query,
            query_from_b: b_from_query.inverse(),
        }
    }
}

/// Correlative branch-and-bound (Hess et al. 2016, via `mapmerge-scanmatch`) of B's occupied
/// cells against A's around each candidate. The best coarse candidate goes first; the others
/// are searched only above `refine_min_score_ratio` of its score (a shared incumbent, so
/// hopeless rotations are pruned early) and keep their coarse pose otherwise.
fn refine(
    target: &MatchTarget,
    a_points: &[Point2],
    query: &Query,
    candidates: &[CoarseCandidate],
    linear_m: f64,
    params: &GridMatchParams,
) -> Result<Vec<(Se2, f64)>, GridMatchError> {
    let window = SearchWindow::new(linear_m, params.refine_angle_rad);
    let search = |c: &CoarseCandidate, target: &MatchTarget| {
        let guess = c.a_from_b.compose(&query.b_from_query);
        match match_scan(target, &query.points, &guess, &window) {
            Some(m) => (m.target_from_query.compose(&query.query_from_b), m.score),
            None => (c.a_from_b, 0.0),
        }
    };
    let Some((first, rest)) = candidates.split_first() else {
        return Ok(Vec::new());
    };
    let best = search(first, target);
    let mut correlative = *target.params();
    correlative.min_score = best.1 * params.refine_min_score_ratio;
    let pruned = MatchTarget::new(a_points, &correlative)?;
    let mut out = vec![best];
    out.extend(
        rest.par_iter()
            .map(|c| search(c, &pruned))
            .collect::<Vec<_>>(),
    );
    Ok(out)
}

/// Point-to-line ICP (Censi 2008, via `mapmerge-scanmatch`) from a refined pose: below the
/// branch-and-bound's cell and angular step.
fn polish(icp: &IcpTarget, query: &Query, a_from_b: &Se2, params: &IcpParams) -> Option<Se2> {
    let guess = a_from_b.compose(&query.b_from_query);
    let info = refine_icp(icp, &query.points, &guess, params)?;
    Some(info.target_from_query.compose(&query.query_from_b))
}
