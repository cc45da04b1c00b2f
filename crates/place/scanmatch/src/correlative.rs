//! Real-time correlative scan matching by depth-first branch-and-bound over (x, y, θ).
//!
//! Olson, "Real-Time Correlative Scan Matching", ICRA 2009 (the score and the covariance,
//! Sec. III and IV); Hess, Kohler, Rapp, Andor, "Real-Time Loop Closure in 2D LIDAR SLAM",
//! ICRA 2016, Sec. V (the angular step, Eq. 7; the search, Algorithms 2–3; the bounds from
//! precomputed grids, Sec. V-C).

use std::borrow::Cow;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::{voxel_downsample, Point2};
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;

use crate::correlation_grid::{
    fast_floor, Ceiling, CellScan, CorrelationGrid, PrecomputedGrid, CELLS_PER_RUN, LIKELIHOOD_MAX,
};
use crate::error::ScanMatchError;
use crate::params::{CorrelativeParams, SearchWindow};

/// What a query is matched against: the target's correlation grid, its precomputed coarse
/// levels, and the target points themselves (for ICP). Build once, match many scans.
#[derive(Clone, Debug)]
pub struct MatchTarget {
    params: CorrelativeParams,
    grid: CorrelationGrid,
    /// `levels[h − 1]` is height `h` (1 ..= depth); height 0 is `grid`. Stale after an
    /// insertion until [`MatchTarget::prepare`] (a map that grows scan by scan pays only when
    /// it is matched, and reuses the buffers).
    levels: Vec<PrecomputedGrid>,
    levels_fresh: bool,
    scratch: Vec<u16>,
    points_in_target: Vec<Point2>,
}

impl MatchTarget {
    /// Rasterises `points_in_target` (non-finite points are dropped) and precomputes
    /// `params.branch_and_bound_depth` coarse levels.
    pub fn new(
        points_in_target: &[Point2],
        params: &CorrelativeParams,
    ) -> Result<Self, ScanMatchError> {
        let mut target = Self::empty(params)?;
        target.rebuild(points_in_target, params)?;
        Ok(target)
    }

    /// Makes this the target of `points_in_target` alone with `params` (what
    /// [`MatchTarget::new`] builds), reusing the buffers: a verifier that matches against a
    /// different map each time builds into the same memory. On error the target is empty.
    pub fn rebuild(
        &mut self,
        points_in_target: &[Point2],
        params: &CorrelativeParams,
    ) -> Result<(), ScanMatchError> {
        params.validate()?;
        if self.params.resolution_m != params.resolution_m
            || self.params.kernel_sigma_cells != params.kernel_sigma_cells
            || self.params.max_grid_cells != params.max_grid_cells
        {
            self.grid = CorrelationGrid::empty(params)?;
        }
        self.params = *params;
        self.grid.clear();
        self.points_in_target.clear();
        self.levels_fresh = false;
        self.grid.insert(points_in_target, 0)?;
        if self.grid.size().0 == 0 {
            return Err(ScanMatchError::EmptyTarget);
        }
        self.points_in_target.extend(
            points_in_target
                .iter()
                .filter(|p| p.x.is_finite() && p.y.is_finite()),
        );
        self.prepare();
        Ok(())
    }

    /// A target with nothing in it yet (every match fails until points are inserted).
    pub fn empty(params: &CorrelativeParams) -> Result<Self, ScanMatchError> {
        Ok(Self {
            params: *params,
            grid: CorrelationGrid::empty(params)?,
            levels: Vec::new(),
            levels_fresh: true,
            scratch: Vec::new(),
            points_in_target: Vec::new(),
        })
    }

    /// Adds `points_in_target` (a map built scan by scan): the grid grows with a margin of
    /// `margin_cells`; the coarse levels are recomputed when next needed.
    pub fn insert(
        &mut self,
        points_in_target: &[Point2],
        margin_cells: usize,
    ) -> Result<(), ScanMatchError> {
        if self.grid.insert(points_in_target, margin_cells)?.is_some() {
            self.levels_fresh = false;
            self.points_in_target.extend(
                points_in_target
                    .iter()
                    .filter(|p| p.x.is_finite() && p.y.is_finite()),
            );
        }
        Ok(())
    }

    /// Recomputes the coarse levels for a new branch-and-bound depth (a map that was
    /// matched with small windows while it was built and with large ones once finished).
    pub fn set_branch_and_bound_depth(&mut self, depth: usize) -> Result<(), ScanMatchError> {
        let mut params = self.params;
        params.branch_and_bound_depth = depth;
        params.validate()?;
        self.params = params;
        self.levels_fresh = false;
        Ok(())
    }

    /// Brings the coarse levels up to date after insertions (cheap when they are). Matching
    /// a target that was not prepared still works, computing its levels for that match alone.
    pub fn prepare(&mut self) {
        if !self.levels_fresh {
            PrecomputedGrid::levels_into(
                &self.grid,
                self.params.branch_and_bound_depth,
                &mut self.levels,
                &mut self.scratch,
            );
            self.levels_fresh = true;
        }
    }

    /// The coarse levels: the stored ones, or computed now when stale.
    fn levels(&self) -> Cow<'_, [PrecomputedGrid]> {
        if self.levels_fresh {
            Cow::Borrowed(&self.levels)
        } else {
            let (mut levels, mut scratch) = (Vec::new(), Vec::new());
            PrecomputedGrid::levels_into(
                &self.grid,
                self.params.branch_and_bound_depth,
                &mut levels,
                &mut scratch,
            );
            Cow::Owned(levels)
        }
    }

    /// Frees the row buffer the levels are computed in (as large as the grid): a target
    /// that stops growing needs it only if its levels go stale again.
    pub fn release_scratch(&mut self) {
        self.scratch = Vec::new();
    }

    /// The parameters the target was built with (also used by every match against it).
    pub fn params(&self) -> &CorrelativeParams {
        &self.params
    }

    /// The full-resolution correlation grid.
    pub fn grid(&self) -> &CorrelationGrid {
        &self.grid
    }

    /// The finite target points (target frame).
    pub fn points_in_target(&self) -> &[Point2] {
        &self.points_in_target
    }

    /// Bytes it holds on the heap: the grid, its levels, the scratch row buffer and the points.
    pub fn heap_bytes(&self) -> usize {
        self.grid.heap_bytes()
            + self
                .levels
                .iter()
                .map(PrecomputedGrid::heap_bytes)
                .sum::<usize>()
            + self.levels.capacity() * std::mem::size_of::<PrecomputedGrid>()
            + self.scratch.capacity() * std::mem::size_of::<u16>()
            + self.points_in_target.capacity() * std::mem::size_of::<Point2>()
    }
}

/// The result of a correlative search.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct CorrelativeMatch {
    /// The best discretised pose of the query (robot) frame in the target frame.
    pub target_from_query: Se2,
    /// Mean likelihood of the (downsampled) query points at that pose, in [0, 1].
    pub score: f64,
    /// Covariance of `target_from_query` in its right-perturbation tangent `(v_x, v_y, ω)`
    /// (Olson 2009, Sec. IV, from the scores around the optimum).
    pub covariance: Matrix3<f64>,
    /// Candidates scored (inner nodes and leaves of the search tree).
    pub candidates: usize,
    /// Angular step of the search (rad).
    pub angular_step_rad: f64,
}

/// The discretised search: angles, per-angle cell indices of the query points, window in
/// cells.
struct Search {
    /// Heading of angle index `a` is `guess.theta_rad + a · angular_step_rad`, for
    /// `a ∈ [angle_min, angle_max]`.
    angle_min: i64,
    angle_max: i64,
    angular_step_rad: f64,
    /// Translation offsets in cells, `[-linear_cells, linear_cells]` in x and y.
    linear_cells: i64,
    /// `scans[a − angle_min]`: cell of every query point at offset (0, 0).
    scans: Vec<CellScan>,
    point_count: u64,
    guess: Se2,
}

impl Search {
    fn new(
        target: &MatchTarget,
        query_points_in_robot: &[Point2],
        guess: &Se2,
        window: &SearchWindow,
    ) -> Option<Self> {
        let params = &target.params;
        if !(guess.x_m.is_finite() && guess.y_m.is_finite() && guess.theta_rad.is_finite()) {
            return None;
        }
        if !(window.linear_m.is_finite() && window.linear_m >= 0.0 && window.angular_rad >= 0.0)
            || window.angular_rad.is_nan()
        {
            return None;
        }
        let points = query_points(params, query_points_in_robot)?;
        let resolution = params.resolution_m;
        // Hess et al. 2016, Eq. 7: the step that moves the farthest point by ≤ one cell.
        let max_range = points.iter().map(|p| p.norm()).fold(0.0, f64::max);
        let step = if max_range > resolution {
            (1.0 - resolution * resolution / (2.0 * max_range * max_range)).acos()
        } else {
            std::f64::consts::FRAC_PI_4
        };
        let two_pi = std::f64::consts::TAU;
        let full_count = (two_pi / step).ceil().max(1.0) as i64;
        let mut half = (window.angular_rad / step).ceil() as i64;
        let (angle_min, angle_max, angular_step_rad) = if 2 * half + 1 >= full_count {
            // The whole circle, evenly, with no heading twice.
            let step = two_pi / full_count as f64;
            (-(full_count / 2), full_count - 1 - full_count / 2, step)
        } else {
            half = half.max(0);
            (-half, half, step)
        };
        let linear_cells = (window.linear_m / resolution).ceil() as i64;
        if linear_cells > 1 << 20 {
            return None;
        }
        // Cell coordinates of `target_from_query · p` (Hess et al., "discretised scans").
        let origin = target.grid.origin_m();
        let inverse_resolution = 1.0 / resolution;
        let (tx, ty) = (
            (guess.x_m - origin.x) * inverse_resolution,
            (guess.y_m - origin.y) * inverse_resolution,
        );
        let scaled: Vec<Point2> = points.iter().map(|p| p * inverse_resolution).collect();
        let scans = (angle_min..=angle_max)
            .map(|a| {
                let (sin, cos) = (guess.theta_rad + a as f64 * angular_step_rad).sin_cos();
                CellScan::new(scaled.iter().map(|p| {
                    (
                        fast_floor(cos * p.x - sin * p.y + tx),
                        fast_floor(sin * p.x + cos * p.y + ty),
                    )
                }))
            })
            .collect();
        Some(Self {
            angle_min,
            angle_max,
            angular_step_rad,
            linear_cells,
            scans,
            point_count: points.len() as u64,
            guess: *guess,
        })
    }

    /// Σ of the height-`height` values of the scan at angle `a` shifted by (x, y) cells: the
    /// exact score (height 0) or an upper bound of every leaf in the block (Hess, Sec. V-C).
    /// Exact when it reaches `cutoff`; below it, some value below `cutoff`, and `run_sums`
    /// then incomplete ([`CellScan::sum_under`]).
    #[allow(clippy::too_many_arguments)]
    fn score(
        &self,
        target: &MatchTarget,
        levels: &[PrecomputedGrid],
        (a, x, y): (i64, i64, i64),
        height: usize,
        ceiling: &Ceiling<'_>,
        cutoff: u64,
        run_sums: Option<&mut Vec<u32>>,
    ) -> u64 {
        let Some(scan) = usize::try_from(a - self.angle_min)
            .ok()
            .and_then(|k| self.scans.get(k))
        else {
            return 0;
        };
        let view = match height.checked_sub(1) {
            None => target.grid.view(),
            Some(level) => match levels.get(level) {
                Some(grid) => grid.view(),
                None => {
                    // Above the tallest level: every cell may score the most.
                    if let Some(run_sums) = run_sums {
                        run_sums.clear();
                        run_sums.extend(
                            scan.cells_by_run()
                                .map(|cells| cells as u32 * u32::from(LIKELIHOOD_MAX)),
                        );
                    }
                    return scan.len() as u64 * u64::from(LIKELIHOOD_MAX);
                }
            },
        };
        scan.sum_under(&view, x, y, ceiling, cutoff, run_sums)
    }

    /// The exact score (height 0) the slow way, one bounds-checked cell at a time: the
    /// reference [`match_scan_brute_force`] checks [`Search::score`] against.
    fn score_reference(&self, target: &MatchTarget, a: i64, x: i64, y: i64) -> u64 {
        usize::try_from(a - self.angle_min)
            .ok()
            .and_then(|k| self.scans.get(k))
            .map_or(0, |scan| {
                scan.cells()
                    .map(|(i, j)| u64::from(target.grid.value(i + x, j + y)))
                    .sum()
            })
    }

    fn pose(&self, target: &MatchTarget, a: i64, x: i64, y: i64) -> Se2 {
        let resolution = target.params.resolution_m;
        Se2::new(
            self.guess.x_m + x as f64 * resolution,
            self.guess.y_m + y as f64 * resolution,
            self.guess.theta_rad + a as f64 * self.angular_step_rad,
        )
    }

    fn normalise(&self, sum: u64) -> f64 {
        sum as f64 / (self.point_count as f64 * f64::from(LIKELIHOOD_MAX))
    }

    /// The smallest integer sum whose score reaches `min_score`: the product's rounding
    /// corrected, so that the search's integer test and a caller's test of the returned
    /// score (`score < min_score`) never disagree.
    fn threshold(&self, min_score: f64) -> u64 {
        let full_sum = self.point_count * u64::from(LIKELIHOOD_MAX);
        let full = full_sum as f64;
        let mut sum = (min_score.max(0.0) * full).ceil().min(full) as u64;
        while sum > 0 && self.normalise(sum - 1) >= min_score {
            sum -= 1;
        }
        while sum < full_sum && self.normalise(sum) < min_score {
            sum += 1;
        }
        sum
    }

    /// Olson 2009, Sec. IV: mean and covariance of the pose under the score distribution
    /// over the full-resolution poses within `covariance_half_width` of the optimum (weights
    /// below), plus the discretisation's own variance (step²/12). Returned in the right
    /// tangent of the best pose, `(v_x, v_y, ω)`.
    fn covariance(&self, target: &MatchTarget, best: (i64, i64, i64)) -> Matrix3<f64> {
        let resolution = target.params.resolution_m;
        let k = target.params.covariance_half_width.min(16) as i64;
        let full_circle = self.angle_max - self.angle_min + 1
            >= (std::f64::consts::TAU / self.angular_step_rad).round() as i64;
        let count = self.angle_max - self.angle_min + 1;
        let mut samples = Vec::new();
        for da in -k..=k {
            let mut a = best.0 + da;
            if full_circle {
                a = (a - self.angle_min).rem_euclid(count) + self.angle_min;
            } else if a < self.angle_min || a > self.angle_max {
                continue;
            }
            for dx in -k..=k {
                for dy in -k..=k {
                    let key = (a, best.1 + dx, best.2 + dy);
                    let sum = self.score(target, &[], key, 0, &Ceiling::Max, 0, None);
                    let offset = Vector3::new(
                        dx as f64 * resolution,
                        dy as f64 * resolution,
                        da as f64 * self.angular_step_rad,
                    );
                    samples.push((offset, self.normalise(sum)));
                }
            }
        }
        // Each sample's weight is its likelihood relative to the optimum, as if every query
        // point contributed the mean likelihood independently: (s_i / s_best)^N (Olson's
        // p(z | x) as a product over points).
        let best_score = samples.iter().map(|s| s.1).fold(0.0, f64::max);
        let points = self.point_count as f64;
        let mut weight_sum = 0.0;
        let mut mean = Vector3::zeros();
        let mut second = Matrix3::zeros();
        for (offset, score) in &samples {
            if best_score <= 0.0 || *score <= 0.0 {
                continue;
            }
            let w = (points * (score / best_score).ln()).exp();
            weight_sum += w;
            mean += offset * w;
            second += offset * offset.transpose() * w;
        }
        let discretisation = Matrix3::from_diagonal(&Vector3::new(
            resolution * resolution / 12.0,
            resolution * resolution / 12.0,
            self.angular_step_rad * self.angular_step_rad / 12.0,
        ));
        let in_target = if weight_sum > 0.0 {
            mean /= weight_sum;
            second / weight_sum - mean * mean.transpose() + discretisation
        } else {
            // A flat neighbourhood: as uncertain as the window.
            let linear = (self.linear_cells.max(1) as f64 * resolution).powi(2) / 3.0;
            let angular = ((count as f64 * self.angular_step_rad) / 2.0).powi(2) / 3.0;
            Matrix3::from_diagonal(&Vector3::new(linear, linear, angular)) + discretisation
        };
        // (δx, δy) in the target frame → right-perturbation (v_x, v_y) = Rᵀ (δx, δy).
        let rotation = self.pose(target, best.0, best.1, best.2).rotation_matrix();
        let mut jacobian = Matrix3::identity();
        jacobian
            .fixed_view_mut::<2, 2>(0, 0)
            .copy_from(&rotation.transpose());
        let covariance = jacobian * in_target * jacobian.transpose();
        (covariance + covariance.transpose()) * 0.5
    }

    fn finish(
        &self,
        target: &MatchTarget,
        best: Option<(u64, (i64, i64, i64))>,
        candidates: usize,
        min_score: f64,
    ) -> Option<CorrelativeMatch> {
        let (sum, key) = best?;
        // The integer threshold, exactly as the search prunes.
        if sum < self.threshold(min_score) {
            return None;
        }
        let score = self.normalise(sum);
        Some(CorrelativeMatch {
            target_from_query: self.pose(target, key.0, key.1, key.2),
            score,
            covariance: self.covariance(target, key),
            candidates,
            angular_step_rad: self.angular_step_rad,
        })
    }
}

/// Most coarse candidates [`match_scan`] accepts to enumerate (about a second of work).
const MAX_ROOTS: f64 = 2e7;

/// `(sum, (a, x, y))` ordered by score, ties to the lexicographically smallest key.
fn better(sum: u64, key: (i64, i64, i64), best: &Option<(u64, (i64, i64, i64))>) -> bool {
    match best {
        None => true,
        Some((best_sum, best_key)) => sum > *best_sum || (sum == *best_sum && key < *best_key),
    }
}

/// Finds the discretised pose of the query scan in the target that maximises the mean
/// likelihood of `query_points_in_robot`, within `window` around
/// `guess_target_from_robot`, by depth-first branch-and-bound (Hess et al. 2016,
/// Algorithm 3). The answer equals [`match_scan_brute_force`]'s, ties going to the smallest
/// (angle, x, y) offset. `None` when the best score is below `min_score`, an input is
/// empty or non-finite, or the window is so much larger than the target that even the
/// coarsest level would need more than 2·10⁷ candidates (raise `branch_and_bound_depth`).
pub fn match_scan(
    target: &MatchTarget,
    query_points_in_robot: &[Point2],
    guess_target_from_robot: &Se2,
    window: &SearchWindow,
) -> Option<CorrelativeMatch> {
    match_scan_above(
        target,
        query_points_in_robot,
        guess_target_from_robot,
        window,
        target.params.min_score,
    )
}

/// As [`match_scan`] with `min_score` in place of the target's: the same optimum when it
/// scores at least `min_score`, `None` otherwise. A caller that only cares about scores
/// above some floor (a rival that matters only when nearly as good) prunes far more.
pub fn match_scan_above(
    target: &MatchTarget,
    query_points_in_robot: &[Point2],
    guess_target_from_robot: &Se2,
    window: &SearchWindow,
    min_score: f64,
) -> Option<CorrelativeMatch> {
    let search = Search::new(
        target,
        query_points_in_robot,
        guess_target_from_robot,
        window,
    )?;
    let n = search.linear_cells;
    // The lowest level whose block covers the whole window (one root per angle), or the
    // tallest precomputed one.
    let mut top = 0usize;
    let levels = target.levels();
    let level_count = levels.len();
    while top < level_count && (1i64 << top) < 2 * n + 1 {
        top += 1;
    }
    let block = 1i64 << top;
    // Refuse windows whose coarsest level alone would take minutes (a window far larger
    // than the target); the answer there is "not found" anyway.
    let per_axis = ((2 * n + 1) as f64 / block as f64).ceil();
    let angles = (search.angle_max - search.angle_min + 1) as f64;
    if angles * per_axis * per_axis > MAX_ROOTS {
        return None;
    }
    let mut candidates = 0usize;
    let threshold = search.threshold(min_score);
    // Hess et al., Algorithm 2: the coarsest candidates, best bound first. A root below the
    // threshold is only known to be below it (`Search::score`), and is never explored.
    let mut roots = Vec::new();
    for a in search.angle_min..=search.angle_max {
        let mut x = -n;
        while x <= n {
            let mut y = -n;
            while y <= n {
                let key = (a, x, y);
                let bound = search.score(target, &levels, key, top, &Ceiling::Max, threshold, None);
                roots.push((bound, key));
                candidates += 1;
                y += block;
            }
            x += block;
        }
    }
    roots.sort_unstable_by(|l, r| r.0.cmp(&l.0).then(l.1.cmp(&r.1)));
    let mut best: Option<(u64, (i64, i64, i64))> = None;
    // Depth-first with an explicit stack; children are pushed worst first so the best is
    // popped first (Hess et al., Algorithm 3). Entry k's run sums (the ceiling of its
    // children's) are `run_sums[k · runs ..][.. runs]`.
    let runs = (search.point_count as usize).div_ceil(CELLS_PER_RUN);
    let mut stack: Vec<(u64, (i64, i64, i64), usize)> = Vec::new();
    let mut run_sums: Vec<u32> = Vec::new();
    let mut child_run_sums: [Vec<u32>; 4] = Default::default();
    for &(bound, key) in roots.iter() {
        if bound < threshold {
            break;
        }
        let [root_run_sums, ..] = &mut child_run_sums;
        search.score(
            target,
            &levels,
            key,
            top,
            &Ceiling::Max,
            0,
            Some(root_run_sums),
        );
        run_sums.clear();
        run_sums.extend_from_slice(root_run_sums);
        stack.push((bound, key, top));
        while let Some((bound, key, height)) = stack.pop() {
            // Prune: the block cannot beat the incumbent (ties: only smaller keys can win,
            // and every key in the block is ≥ the block's corner key).
            if bound < threshold {
                continue;
            }
            if let Some((best_sum, best_key)) = best {
                if bound < best_sum || (bound == best_sum && key > best_key) {
                    continue;
                }
            }
            if height == 0 {
                if better(bound, key, &best) {
                    best = Some((bound, key));
                }
                continue;
            }
            let slot = stack.len();
            let half = 1i64 << (height - 1);
            let (a, x0, y0) = key;
            // A child below the incumbent is pruned when popped, so its bound need only be
            // known to be below it; each of its cells scores at most the parent's.
            let cutoff = best.map_or(threshold, |(best_sum, _)| best_sum.max(threshold));
            let parent = run_sums.get(slot * runs..(slot + 1) * runs).unwrap_or(&[]);
            let ceiling = if parent.len() == runs {
                Ceiling::Parent(parent, bound)
            } else {
                Ceiling::Max
            };
            let mut children = [(0u64, (0i64, 0i64, 0i64), 0usize); 4];
            let mut passed = 0;
            for (c, (x, y)) in [
                (x0, y0),
                (x0, y0 + half),
                (x0 + half, y0),
                (x0 + half, y0 + half),
            ]
            .into_iter()
            .enumerate()
            {
                if x > n || y > n {
                    continue;
                }
                let out = child_run_sums.get_mut(c).filter(|_| height > 1);
                let child_bound = search.score(
                    target,
                    &levels,
                    (a, x, y),
                    height - 1,
                    &ceiling,
                    cutoff,
                    out,
                );
                candidates += 1;
                if child_bound >= cutoff {
                    if let Some(entry) = children.get_mut(passed) {
                        *entry = (child_bound, (a, x, y), c);
                        passed += 1;
                    }
                }
            }
            // Ascending bound, ties: larger key first, so the stack pops best/smallest first.
            let children = children.get_mut(..passed).unwrap_or(&mut []);
            children.sort_unstable_by(|l, r| l.0.cmp(&r.0).then(r.1.cmp(&l.1)));
            run_sums.truncate(slot * runs);
            for &(child_bound, child_key, c) in children.iter() {
                stack.push((child_bound, child_key, height - 1));
                match child_run_sums.get(c).filter(|_| height > 1) {
                    Some(child) => run_sums.extend_from_slice(child),
                    None => run_sums.resize(run_sums.len() + runs, 0),
                }
            }
        }
    }
    search.finish(target, best, candidates, min_score)
}

/// The finite query points, voxel-downsampled as `params` say; `None` when none is left.
fn query_points(
    params: &CorrelativeParams,
    query_points_in_robot: &[Point2],
) -> Option<Vec<Point2>> {
    let finite: Vec<Point2> = query_points_in_robot
        .iter()
        .filter(|p| p.x.is_finite() && p.y.is_finite())
        .copied()
        .collect();
    let points = if params.query_voxel_m > 0.0 {
        voxel_downsample(&finite, params.query_voxel_m)
    } else {
        finite
    };
    (!points.is_empty()).then_some(points)
}

/// The score (mean likelihood in [0, 1], as [`match_scan`] reports it) of the query points at
/// one pose, after the same voxel downsampling; `None` for empty or non-finite input.
pub fn score_at(
    target: &MatchTarget,
    query_points_in_robot: &[Point2],
    target_from_robot: &Se2,
) -> Option<f64> {
    if !target_from_robot.is_finite() {
        return None;
    }
    let points = query_points(&target.params, query_points_in_robot)?;
    let sum: u64 = points
        .iter()
        .map(|p| {
            let (i, j) = target.grid.cell_of(&target_from_robot.transform_point(p));
            u64::from(target.grid.value(i, j))
        })
        .sum();
    Some(sum as f64 / (points.len() as f64 * f64::from(LIKELIHOOD_MAX)))
}

/// The reference: scores every discretised pose of the same search as [`match_scan`]. Slow
/// (use for tests and small windows only).
pub fn match_scan_brute_force(
    target: &MatchTarget,
    query_points_in_robot: &[Point2],
    guess_target_from_robot: &Se2,
    window: &SearchWindow,
) -> Option<CorrelativeMatch> {
    let search = Search::new(
        target,
        query_points_in_robot,
        guess_target_from_robot,
        window,
    )?;
    let n = search.linear_cells;
    let mut best = None;
    let mut candidates = 0usize;
    for a in search.angle_min..=search.angle_max {
        for x in -n..=n {
            for y in -n..=n {
                let sum = search.score_reference(target, a, x, y);
                candidates += 1;
                if better(sum, (a, x, y), &best) {
                    best = Some((sum, (a, x, y)));
                }
            }
        }
    }
    search.finish(target, best, candidates, target.params.min_score)
}
