//! Graduated Non-Convexity with the truncated-least-squares cost.
//!
//! Yang, Antonante, Tzoumas, Carlone, "Graduated Non-Convexity for Robust Spatial Perception:
//! From Non-Minimal Solvers to Global Outlier Rejection", RA-L 2020, Sec. III and Prop. 4 (TLS).

use std::collections::HashMap;

use mapmerge_geometry::LieGroup;
use mapmerge_posegraph::{EdgeId, EdgeKind, PoseGraph};
use nalgebra::SMatrix;
use serde::{Deserialize, Serialize};

use crate::error::SolveError;
use crate::optimizer::{OptimizerInfo, OptimizerParams, Session};
use crate::problem::Problem;
use crate::robust::RobustKernel;

/// Parameters of [`optimize_gnc`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GncParams {
    /// The weighted least-squares solver run at every step (its `robust` must be `None`).
    pub inner: OptimizerParams,
    /// `c̄²`: an edge whose squared Mahalanobis error exceeds this is an outlier. Default: the
    /// 0.99 quantile of χ² with D degrees of freedom (11.34 in 2D, 16.81 in 3D).
    pub inlier_threshold_chi2: Option<f64>,
    /// `μ ← μ · mu_factor` per step (paper: 1.4).
    pub mu_factor: f64,
    /// At most this many GNC steps per graduation (default 100).
    pub max_steps: usize,
    /// Stop when `Σ w(1 − w)` falls below this (weights are binary; default 1e-6).
    pub binary_tolerance: f64,
    /// Odometry edges are trusted and never down-weighted (default true, as in vertigo).
    pub odometry_is_inlier: bool,
    /// Where the graduation starts (default: loop closures on consistent cycles first).
    pub start: GncStart,
}

/// The estimate GNC starts from, and how the first `μ` is chosen.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GncStart {
    /// Yang et al.'s rule: the plain least-squares solution, `μ₀ = c̄² / (2 r²_max − c̄²)`.
    /// With many false loop closures that solution is already folded and GNC follows it.
    LeastSquares,
    /// The graph's initial guess with the same `μ₀` rule.
    InitialGuess,
    /// Dynamic Covariance Scaling (Agarwal et al. 2013) from the initial guess, then GNC with
    /// `μ₀ = mu_initial`. From an odometry-like guess DCS already lands near the right basin
    /// (M3500 with 50 % false loops: 1 cm RMS), where Yang's tiny `μ₀` would throw it away
    /// again; a moderate `μ₀` only sharpens DCS's soft decisions into binary ones.
    Dcs {
        /// DCS's Φ; `None` (default) uses the inlier threshold `c̄²`, so edges consistent with
        /// their information keep full weight during the warm start.
        phi: Option<f64>,
        /// The first `μ` (1: full weight below c̄²/2, none above 2c̄²).
        mu_initial: f64,
    },
    /// [`GncStart::Dcs`] twice: first over the odometry and the loop closures that close
    /// consistent cycles with others nearby, then over every edge from that estimate.
    ///
    /// Latif, Cadena and Neira's intra-cluster consistency (RRR, IJRR 2013): loop closures
    /// `(i, j)` and `(k, l)` with `|i − k|` and `|j − l|` within `window` poses, joined by the
    /// odometry between them, make a cycle that must compose to the identity. A loop closure
    /// whose cycles pass the χ² test with at least `min_partners` others is a seed. Random
    /// false loop closures rarely close a consistent cycle, so the first pass is not folded by
    /// them, which a DCS start from a long chain's drifted initial guess is (city10000 with
    /// 50 % false loops: 91.6 % of the true loops kept). Without odometry or seeds this is
    /// [`GncStart::Dcs`].
    Cycles {
        /// DCS's Φ, as in [`GncStart::Dcs`].
        phi: Option<f64>,
        /// The first `μ` of each graduation, as in [`GncStart::Dcs`].
        mu_initial: f64,
        /// How many poses apart the ends of two loop closures may be (1–1000).
        window: u32,
        /// Consistent cycles a seed needs (≥ 1).
        min_partners: u32,
    },
}

impl Default for GncParams {
    fn default() -> Self {
        Self {
            inner: OptimizerParams {
                max_iterations: 30,
                relative_decrease_tolerance: 1e-6,
                ..Default::default()
            },
            inlier_threshold_chi2: None,
            mu_factor: 1.4,
            max_steps: 100,
            binary_tolerance: 1e-6,
            odometry_is_inlier: true,
            start: GncStart::Cycles {
                phi: None,
                mu_initial: 1.0,
                window: 10,
                min_partners: 2,
            },
        }
    }
}

/// The 0.99 quantile of χ² with `dof` degrees of freedom (Wilson–Hilferty beyond the table).
pub fn chi2_quantile_99(dof: usize) -> f64 {
    const TABLE: [f64; 6] = [6.635, 9.210, 11.345, 13.277, 15.086, 16.812];
    match dof {
        1..=6 => TABLE[dof - 1],
        _ => {
            let k = dof as f64;
            let z = 2.326_347_874;
            let h = 2.0 / (9.0 * k);
            k * (1.0 - h + z * h.sqrt()).powi(3)
        }
    }
}

/// What GNC did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GncInfo {
    /// GNC steps taken (each a weighted least-squares solve).
    pub steps: usize,
    /// The last `μ`.
    pub final_mu: f64,
    /// The inlier threshold `c̄²` used.
    pub threshold_chi2: f64,
    /// Final weight of every edge, in edge-id order.
    pub weights: Vec<(EdgeId, f64)>,
    /// Edges rejected as outliers (final weight < 0.5).
    pub rejected: Vec<EdgeId>,
    /// Chi2 of all edges, outliers included, at the result.
    pub chi2_all_edges: f64,
    /// The final least-squares polish over the inliers (its `final_chi2` excludes outliers).
    pub optimizer: OptimizerInfo,
    /// Inner optimizer iterations summed over all steps.
    pub inner_iterations: usize,
}

/// Reweighting rounds of the DCS warm start at most.
const DCS_ROUNDS: usize = 30;
/// The warm start ends when no DCS weight moves by more than this.
const DCS_WEIGHT_TOLERANCE: f64 = 1e-3;
/// A DCS weight below this is treated as 0 (its edge leaves the sparsity pattern).
const NEGLIGIBLE_WEIGHT: f64 = 1e-6;

/// TLS weight for squared error `s` (Yang et al. 2020, Prop. 4).
fn tls_weight(s: f64, threshold: f64, mu: f64) -> f64 {
    if s >= (mu + 1.0) / mu * threshold {
        0.0
    } else if s <= mu / (mu + 1.0) * threshold {
        1.0
    } else {
        (threshold.sqrt() / s.sqrt() * (mu * (mu + 1.0)).sqrt() - mu).clamp(0.0, 1.0)
    }
}

/// Rebuilds the normal equations without the zero-weight edges once at least 5 % of the
/// edges in the current pattern have dropped out (their fill is what makes random false loop
/// closures expensive), and whenever an edge outside the pattern regains weight.
fn rebuild_if_needed<G: LieGroup<D>, const D: usize>(
    session: &mut Session<G, D>,
    problem: &mut Problem<G, D>,
    weights: &[f64],
    pattern: &mut Vec<bool>,
) -> Result<(), SolveError> {
    let missing = weights
        .iter()
        .zip(pattern.iter())
        .any(|(w, in_pattern)| *w > 0.0 && !in_pattern);
    let dropped = weights
        .iter()
        .zip(pattern.iter())
        .filter(|(w, p)| **w == 0.0 && **p)
        .count();
    if !missing && dropped * 20 < weights.len() {
        return Ok(());
    }
    *pattern = weights.iter().map(|w| *w > 0.0).collect();
    *session = Session::with_active_edges(problem, Some(pattern))?;
    Ok(())
}

/// Robust optimisation of `graph` by GNC-TLS. Rejected edges stay in the graph; the result
/// lists them.
pub fn optimize_gnc<G: LieGroup<D>, const D: usize>(
    graph: &mut PoseGraph<G, D>,
    params: &GncParams,
) -> Result<GncInfo, SolveError> {
    params.inner.validate()?;
    if params.inner.robust != RobustKernel::None {
        return Err(SolveError::InvalidParameter(
            "GNC's inner solver must not use a robust kernel".into(),
        ));
    }
    let threshold = params
        .inlier_threshold_chi2
        .unwrap_or_else(|| chi2_quantile_99(D));
    if !(threshold.is_finite() && threshold > 0.0 && params.mu_factor > 1.0) {
        return Err(SolveError::InvalidParameter(
            "GNC threshold must be > 0 and mu_factor > 1".into(),
        ));
    }
    let mut problem = Problem::compile(graph)?;
    let trusted: Vec<bool> = problem
        .edges
        .iter()
        .map(|e| e.is_prior || (params.odometry_is_inlier && e.kind == EdgeKind::Odometry))
        .collect();
    let mut stage = Stage {
        weights: vec![1.0; problem.edges.len()],
        // The session's pattern starts with every edge; a DCS start narrows it before the
        // first factorisation (`rebuild_if_needed`).
        pattern: vec![
            matches!(
                params.start,
                GncStart::LeastSquares | GncStart::InitialGuess
            );
            problem.edges.len()
        ],
        trusted: &trusted,
        threshold,
        params,
        inner_iterations: 0,
        steps: 0,
    };
    let mut session = Session::with_active_edges(&mut problem, Some(&stage.pattern))?;
    let (mu, residuals) = match params.start {
        GncStart::LeastSquares | GncStart::InitialGuess => {
            if params.start == GncStart::LeastSquares {
                let first = session.run(&mut problem, &stage.weights, &params.inner, |_| {});
                stage.inner_iterations += first.iterations.len();
            }
            let max_untrusted = chi2_of(&problem)
                .iter()
                .zip(&trusted)
                .filter(|(_, t)| !**t)
                .fold(0.0f64, |m, (s, _)| m.max(*s));
            let mu = if 2.0 * max_untrusted > threshold {
                threshold / (2.0 * max_untrusted - threshold)
            } else {
                f64::INFINITY
            };
            stage.graduate(&mut session, &mut problem, None, mu)?
        }
        GncStart::Dcs { phi, mu_initial } => {
            let kernel = dcs_kernel(phi, mu_initial, threshold)?;
            stage.dcs_rounds(&mut session, &mut problem, None, kernel)?;
            stage.graduate(&mut session, &mut problem, None, mu_initial)?
        }
        GncStart::Cycles {
            phi,
            mu_initial,
            window,
            min_partners,
        } => {
            if !(1..=1000).contains(&window) || min_partners == 0 {
                return Err(SolveError::InvalidParameter(
                    "GNC cycle window must be 1–1000 and min_partners ≥ 1".into(),
                ));
            }
            let kernel = dcs_kernel(phi, mu_initial, threshold)?;
            let seeds = cycle_seeds(&problem, &trusted, threshold, window, min_partners);
            if seeds.iter().zip(&trusted).any(|(s, t)| *s && !*t) {
                stage.dcs_rounds(&mut session, &mut problem, Some(&seeds), kernel)?;
                stage.graduate(&mut session, &mut problem, Some(&seeds), mu_initial)?;
            }
            stage.dcs_rounds(&mut session, &mut problem, None, kernel)?;
            stage.graduate(&mut session, &mut problem, None, mu_initial)?
        }
    };
    // Final binary decision and a full least-squares polish over the inliers.
    let Stage {
        mut weights,
        mut pattern,
        mut inner_iterations,
        steps,
        ..
    } = stage;
    for ((w, s), t) in weights.iter_mut().zip(&residuals).zip(&trusted) {
        let soft = if *t {
            1.0
        } else if mu.is_finite() {
            tls_weight(*s, threshold, mu)
        } else {
            1.0
        };
        *w = if soft >= 0.5 { 1.0 } else { 0.0 };
    }
    rebuild_if_needed(&mut session, &mut problem, &weights, &mut pattern)?;
    let polish_params = OptimizerParams {
        max_iterations: 100.max(params.inner.max_iterations),
        relative_decrease_tolerance: 1e-9,
        ..params.inner
    };
    let optimizer = session.run(&mut problem, &weights, &polish_params, |_| {});
    inner_iterations += optimizer.iterations.len();
    let all = vec![1.0; problem.edges.len()];
    let (chi2_all_edges, _) = problem.cost(&problem.poses, &all, &RobustKernel::None);
    problem.write_back(graph);
    let rejected = problem
        .edges
        .iter()
        .zip(&weights)
        .filter(|(_, w)| **w < 0.5)
        .map(|(e, _)| e.id)
        .collect();
    Ok(GncInfo {
        steps,
        final_mu: mu,
        threshold_chi2: threshold,
        weights: problem
            .edges
            .iter()
            .zip(&weights)
            .map(|(e, w)| (e.id, *w))
            .collect(),
        rejected,
        chi2_all_edges,
        optimizer,
        inner_iterations,
    })
}

/// Squared error of every edge at the problem's poses.
fn chi2_of<G: LieGroup<D>, const D: usize>(problem: &Problem<G, D>) -> Vec<f64> {
    problem
        .edges
        .iter()
        .map(|e| Problem::edge_chi2(e, &problem.poses))
        .collect()
}

/// DCS's kernel for a [`GncStart`] with `phi` and `mu_initial`.
fn dcs_kernel(
    phi: Option<f64>,
    mu_initial: f64,
    threshold: f64,
) -> Result<RobustKernel, SolveError> {
    if !(mu_initial.is_finite() && mu_initial > 0.0) {
        return Err(SolveError::InvalidParameter(
            "GNC mu_initial must be > 0".into(),
        ));
    }
    let kernel = RobustKernel::Dcs {
        phi: phi.unwrap_or(threshold),
    };
    mapmerge_params::Validate::validate(&kernel)?;
    Ok(kernel)
}

/// What the warm start and the graduation share: the weights, the session's pattern, and
/// the work done.
struct Stage<'a> {
    weights: Vec<f64>,
    pattern: Vec<bool>,
    trusted: &'a [bool],
    threshold: f64,
    params: &'a GncParams,
    inner_iterations: usize,
    steps: usize,
}

impl Stage<'_> {
    /// The weight an untrusted edge may have: none outside `allowed`.
    fn allows(allowed: Option<&[bool]>, edge: usize) -> bool {
        allowed.is_none_or(|a| a[edge])
    }

    /// DCS (Agarwal et al. 2013) as explicit reweighting rounds from the problem's poses, over
    /// the edges `allowed` (every edge when `None`). An edge whose DCS weight is negligible is
    /// left out of the sparsity pattern until its residual shrinks: random false loop closures
    /// would otherwise fill the factor (city10000 with 50 %: dense).
    fn dcs_rounds<G: LieGroup<D>, const D: usize>(
        &mut self,
        session: &mut Session<G, D>,
        problem: &mut Problem<G, D>,
        allowed: Option<&[bool]>,
        kernel: RobustKernel,
    ) -> Result<(), SolveError> {
        for _ in 0..DCS_ROUNDS {
            let residuals = chi2_of(problem);
            let mut change = 0.0f64;
            for (k, (w, s)) in self.weights.iter_mut().zip(&residuals).enumerate() {
                let new = if self.trusted[k] {
                    1.0
                } else if !Self::allows(allowed, k) {
                    0.0
                } else {
                    let d = kernel.weight(*s);
                    if d < NEGLIGIBLE_WEIGHT {
                        0.0
                    } else {
                        d
                    }
                };
                change = change.max((new - *w).abs());
                *w = new;
            }
            rebuild_if_needed(session, problem, &self.weights, &mut self.pattern)?;
            let run = session.run(problem, &self.weights, &self.params.inner, |_| {});
            self.inner_iterations += run.iterations.len();
            if change < DCS_WEIGHT_TOLERANCE {
                break;
            }
        }
        Ok(())
    }

    /// GNC-TLS's graduation from `mu` over the edges `allowed` (Yang et al. 2020, Alg. 1):
    /// returns the last `μ` and the edges' squared errors at the result.
    fn graduate<G: LieGroup<D>, const D: usize>(
        &mut self,
        session: &mut Session<G, D>,
        problem: &mut Problem<G, D>,
        allowed: Option<&[bool]>,
        mut mu: f64,
    ) -> Result<(f64, Vec<f64>), SolveError> {
        let mut residuals = chi2_of(problem);
        let mut steps = 0;
        while mu.is_finite() && steps < self.params.max_steps {
            steps += 1;
            for (k, (w, s)) in self.weights.iter_mut().zip(&residuals).enumerate() {
                *w = if self.trusted[k] {
                    1.0
                } else if !Self::allows(allowed, k) {
                    0.0
                } else {
                    tls_weight(*s, self.threshold, mu)
                };
            }
            // The session leaves edges outside its pattern out of every step: an edge the
            // warm start dropped that regains weight must be back in it, and the false loop
            // closures the graduation switches off leave it (their fill is most of the
            // factor's).
            rebuild_if_needed(session, problem, &self.weights, &mut self.pattern)?;
            let run = session.run(problem, &self.weights, &self.params.inner, |_| {});
            self.inner_iterations += run.iterations.len();
            residuals = chi2_of(problem);
            let non_binary: f64 = self.weights.iter().map(|w| w * (1.0 - w)).sum();
            if non_binary < self.params.binary_tolerance {
                break;
            }
            mu *= self.params.mu_factor;
        }
        self.steps += steps;
        Ok((mu, residuals))
    }
}

/// Untrusted edges that close consistent cycles ([`GncStart::Cycles`]), with every trusted
/// edge. A cycle joins loop closures `(i, j)` and `(k, l)` (`i < j`, `k < l`, dense vertex
/// indices in id order) by the odometry `i → k` and `j → l`:
/// `E = Z_ij⁻¹ · O_ik · Z_kl · O_jl⁻¹` should be the identity. Its χ² uses the sum of the four
/// parts' covariances, not carried through the rotations: a first-order test for short chains.
fn cycle_seeds<G: LieGroup<D>, const D: usize>(
    problem: &Problem<G, D>,
    trusted: &[bool],
    threshold: f64,
    window: u32,
    min_partners: u32,
) -> Vec<bool> {
    let n = problem.poses.len();
    // steps[v]: the odometry from vertex v to v + 1 and its covariance.
    let mut steps: Vec<Option<(G, SMatrix<f64, D, D>)>> = vec![None; n];
    // loops: (edge, i, j, Z_ij, covariance), i < j.
    let mut loops = Vec::new();
    for (k, e) in problem.edges.iter().enumerate() {
        if e.is_prior || e.from == e.to {
            continue;
        }
        let Some(covariance) = e.information.try_inverse() else {
            continue;
        };
        let (i, j) = (e.from.min(e.to) as usize, e.from.max(e.to) as usize);
        // The edge measures x_from⁻¹ · x_to = measurement_inverse⁻¹.
        let z_ij = if e.from < e.to {
            e.measurement_inverse.inverse()
        } else {
            e.measurement_inverse
        };
        if e.kind == EdgeKind::Odometry && j == i + 1 {
            if steps[i].is_none() {
                steps[i] = Some((z_ij, covariance));
            }
        } else if !trusted[k] {
            loops.push((k, i, j, z_ij, covariance));
        }
    }
    // x_a⁻¹ · x_b along the odometry, either way, and its summed covariance.
    let chain = |a: usize, b: usize| -> Option<(G, SMatrix<f64, D, D>)> {
        let mut pose = G::identity();
        let mut covariance = SMatrix::<f64, D, D>::zeros();
        for step in steps.get(a.min(b)..a.max(b))? {
            let (z, c) = step.as_ref()?;
            pose = pose.compose(z);
            covariance += c;
        }
        Some((if a <= b { pose } else { pose.inverse() }, covariance))
    };
    let w = window as usize;
    let mut cells: HashMap<(usize, usize), Vec<usize>> = HashMap::new();
    for (index, (_, i, j, _, _)) in loops.iter().enumerate() {
        cells.entry((i / w, j / w)).or_default().push(index);
    }
    let mut seeds = trusted.to_vec();
    for (index, (edge, i, j, z_ij, covariance)) in loops.iter().enumerate() {
        let mut partners = 0;
        'cells: for ci in (i / w).saturating_sub(1)..=i / w + 1 {
            for cj in (j / w).saturating_sub(1)..=j / w + 1 {
                for &other in cells.get(&(ci, cj)).into_iter().flatten() {
                    let (_, k, l, z_kl, covariance_kl) = &loops[other];
                    if other == index || i.abs_diff(*k) > w || j.abs_diff(*l) > w {
                        continue;
                    }
                    let (Some((o_ik, c_ik)), Some((o_jl, c_jl))) = (chain(*i, *k), chain(*j, *l))
                    else {
                        continue;
                    };
                    let cycle = z_ij
                        .inverse()
                        .compose(&o_ik)
                        .compose(z_kl)
                        .compose(&o_jl.inverse());
                    let r = cycle.error_coordinates();
                    let Some(information) =
                        (covariance + covariance_kl + c_ik + c_jl).try_inverse()
                    else {
                        continue;
                    };
                    if (r.transpose() * information * r)[(0, 0)] <= threshold {
                        partners += 1;
                        if partners >= min_partners {
                            seeds[*edge] = true;
                            break 'cells;
                        }
                    }
                }
            }
        }
    }
    seeds
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tls_weights_span_zero_to_one() {
        let c2 = 10.0;
        assert_eq!(tls_weight(1.0, c2, 1.0), 1.0);
        assert_eq!(tls_weight(100.0, c2, 1.0), 0.0);
        let mid = tls_weight(c2, c2, 1.0);
        assert!(mid > 0.0 && mid < 1.0);
        // As μ grows the transition band shrinks to the threshold.
        assert_eq!(tls_weight(c2 * 0.99, c2, 1e4), 1.0);
        assert_eq!(tls_weight(c2 * 1.01, c2, 1e4), 0.0);
    }

    /// A square of odometry closed by a loop that disagrees with it by 0.5 m: an edge left
    /// out of the session's pattern is left out of its steps (the odometry alone is met and
    /// the loop keeps its whole error), and shares the error once `rebuild_if_needed` puts it
    /// back, as the graduation needs when a dropped edge regains weight.
    #[test]
    fn an_edge_that_regains_weight_is_back_in_the_steps() {
        use mapmerge_geometry::Se2;
        use mapmerge_posegraph::{Edge, NodeId, PoseGraph2, Vertex};
        use nalgebra::Matrix3;
        let mut graph = PoseGraph2::new();
        let step = Se2::new(1.0, 0.0, std::f64::consts::FRAC_PI_2);
        let mut pose = Se2::identity();
        for k in 0..4u64 {
            graph.add_vertex(NodeId(k), Vertex::new(pose)).unwrap();
            pose = pose.compose(&step);
        }
        for (from, to, kind) in [
            (0, 1, EdgeKind::Odometry),
            (1, 2, EdgeKind::Odometry),
            (2, 3, EdgeKind::Odometry),
            (3, 0, EdgeKind::Loop),
        ] {
            graph
                .add_edge(Edge {
                    from: NodeId(from),
                    to: NodeId(to),
                    measurement: if kind == EdgeKind::Loop {
                        Se2::new(1.0, 0.5, std::f64::consts::FRAC_PI_2)
                    } else {
                        step
                    },
                    information: Matrix3::identity(),
                    kind,
                })
                .unwrap();
        }
        let loop_chi2 = |rebuild: bool| {
            let mut problem = Problem::compile(&graph).unwrap();
            let mut pattern = vec![true, true, true, false];
            let weights = vec![1.0; 4];
            let mut session = Session::with_active_edges(&mut problem, Some(&pattern)).unwrap();
            if rebuild {
                rebuild_if_needed(&mut session, &mut problem, &weights, &mut pattern).unwrap();
            }
            session.run(&mut problem, &weights, &OptimizerParams::default(), |_| {});
            Problem::edge_chi2(&problem.edges[3], &problem.poses)
        };
        let (left_out, back_in) = (loop_chi2(false), loop_chi2(true));
        assert!((left_out - 0.25).abs() < 1e-6, "{left_out}");
        assert!(back_in < 0.5 * left_out, "{back_in} against {left_out}");
    }

    /// A corridor driven out and back: loop closures between the two passes close consistent
    /// cycles with each other; a false one among them (near them in both indices) does not.
    #[test]
    fn loop_closures_on_consistent_cycles_are_seeds_and_a_false_one_is_not() {
        use mapmerge_geometry::Se2;
        use mapmerge_posegraph::{Edge, NodeId, PoseGraph2, Vertex};
        use nalgebra::Matrix3;
        let pose_of = |k: u64| {
            if k <= 20 {
                Se2::new(k as f64, 0.0, 0.0)
            } else {
                Se2::new(40.0 - k as f64, 0.5, std::f64::consts::PI)
            }
        };
        let mut graph = PoseGraph2::new();
        for k in 0..=40u64 {
            graph
                .add_vertex(NodeId(k), Vertex::new(pose_of(k)))
                .unwrap();
        }
        let mut add = |from: u64, to: u64, measurement: Se2, kind: EdgeKind| {
            graph
                .add_edge(Edge {
                    from: NodeId(from),
                    to: NodeId(to),
                    measurement,
                    information: Matrix3::identity() * 100.0,
                    kind,
                })
                .unwrap()
        };
        for k in 0..40u64 {
            add(
                k,
                k + 1,
                pose_of(k).between(&pose_of(k + 1)),
                EdgeKind::Odometry,
            );
        }
        // True loops from the way back to the way out, stored in that direction.
        let true_loops: Vec<EdgeId> = (2..=8u64)
            .map(|m| {
                add(
                    40 - m,
                    m,
                    pose_of(40 - m).between(&pose_of(m)),
                    EdgeKind::Loop,
                )
            })
            .collect();
        let isolated = add(19, 21, pose_of(19).between(&pose_of(21)), EdgeKind::Loop);
        let false_loop = add(3, 30, Se2::new(0.2, 0.0, 0.1), EdgeKind::Loop);
        let problem = Problem::compile(&graph).unwrap();
        let trusted: Vec<bool> = problem
            .edges
            .iter()
            .map(|e| e.kind == EdgeKind::Odometry)
            .collect();
        let seeds = cycle_seeds(&problem, &trusted, chi2_quantile_99(3), 10, 2);
        let seed_of = |id: EdgeId| seeds[problem.edges.iter().position(|e| e.id == id).unwrap()];
        for id in true_loops {
            assert!(seed_of(id), "true loop {id:?}");
        }
        // Consistent, but no other loop closure has both ends within 10 poses of its ends.
        assert!(!seed_of(isolated));
        assert!(!seed_of(false_loop));
        assert!(trusted.iter().zip(&seeds).all(|(t, s)| !t || *s));
    }

    #[test]
    fn chi2_quantiles() {
        assert!((chi2_quantile_99(3) - 11.345).abs() < 1e-3);
        assert!((chi2_quantile_99(10) - 23.209).abs() < 0.1);
    }
}
