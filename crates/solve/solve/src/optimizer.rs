//! Gauss–Newton and Levenberg–Marquardt on the manifold (right perturbations).

use std::time::Instant;

use mapmerge_geometry::LieGroup;
use mapmerge_params::{Checker, Real, Validate};
use mapmerge_posegraph::{NodeId, PoseGraph};
use serde::{Deserialize, Serialize};

use crate::error::SolveError;
use crate::linear::{fill_reducing_slots, NormalEquations};
use crate::problem::{EdgeLinearization, Problem, FIXED};
use crate::robust::RobustKernel;

/// Which nonlinear least-squares method to run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Algorithm {
    /// Undamped Gauss–Newton; a step that raises the cost ends the run.
    GaussNewton,
    /// Levenberg–Marquardt with Marquardt's diagonal scaling (default).
    #[default]
    LevenbergMarquardt,
}

/// Parameters of [`optimize`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OptimizerParams {
    /// Method (default: Levenberg–Marquardt).
    pub algorithm: Algorithm,
    /// Robust kernel on every edge (default: none).
    pub robust: RobustKernel,
    /// Stop after this many iterations (default 100).
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the cost by less than this fraction (default 1e-9,
    /// GTSAM's `relativeErrorTol` in our peer runs). Smaller is more exact and slower.
    pub relative_decrease_tolerance: f64,
    /// Stop when the cost is below this (default 1e-12).
    pub absolute_tolerance: f64,
    /// Stop when `max |g|` falls below this (default 1e-10).
    pub gradient_tolerance: f64,
    /// Initial LM damping relative to diag(H) (default 1e-9). Marquardt's damping ties every
    /// pose to where it is: along a chain of poses a correction fades within about `1/√λ`
    /// poses, so 1e-5 stalled long chains (ais2klinik: 67 iterations, 14 from 1e-9). Starting
    /// near Gauss–Newton, a step that fails raises λ.
    pub lambda_initial: f64,
    /// Damping multiplier after a rejected step (default 10; divided by it after success).
    pub lambda_factor: f64,
    /// Give up raising λ past this (default 1e10): the point is then a minimum to precision.
    pub lambda_max: f64,
}

impl Default for OptimizerParams {
    fn default() -> Self {
        Self {
            algorithm: Algorithm::LevenbergMarquardt,
            robust: RobustKernel::None,
            max_iterations: 100,
            relative_decrease_tolerance: 1e-9,
            absolute_tolerance: 1e-12,
            gradient_tolerance: 1e-10,
            lambda_initial: 1e-9,
            lambda_factor: 10.0,
            lambda_max: 1e10,
        }
    }
}

impl OptimizerParams {
    /// Checks every parameter's range.
    pub fn validate(&self) -> Result<(), SolveError> {
        Ok(Validate::validate(self)?)
    }
}

impl Validate for OptimizerParams {
    fn check(&self, check: &mut Checker) {
        check
            .nested("robust", &self.robust)
            // 0 scores the initial estimate without a step.
            .size("max_iterations", self.max_iterations, 0, 100_000)
            .real(
                "relative_decrease_tolerance",
                self.relative_decrease_tolerance,
                Real::non_negative(),
            )
            .real(
                "absolute_tolerance",
                self.absolute_tolerance,
                Real::non_negative(),
            )
            .real(
                "gradient_tolerance",
                self.gradient_tolerance,
                Real::non_negative(),
            )
            .real("lambda_initial", self.lambda_initial, Real::positive())
            .real("lambda_factor", self.lambda_factor, Real::open(1.0, 1e6))
            .real(
                "lambda_max",
                self.lambda_max,
                Real::at_least(self.lambda_initial),
            );
    }
}

/// Why the run stopped.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Termination {
    /// The relative cost decrease fell below the tolerance.
    RelativeDecrease,
    /// The cost fell below the absolute tolerance.
    AbsoluteCost,
    /// The gradient vanished.
    Gradient,
    /// No damping found a cost decrease: converged to numerical precision.
    NoFurtherDecrease,
    /// The iteration budget ran out.
    MaxIterations,
    /// The linear system could not be solved; the last good state is kept.
    NumericalFailure(String),
    /// Nothing to optimise (every vertex fixed).
    NothingToOptimize,
}

impl Termination {
    /// True unless the run ended on a numerical failure.
    pub fn is_success(&self) -> bool {
        !matches!(self, Self::NumericalFailure(_))
    }
}

/// One iteration (one accepted or finally rejected linearisation).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct IterationStats {
    /// 1-based iteration number.
    pub iteration: usize,
    /// `Σ rᵀ Ω r` after the iteration.
    pub chi2: f64,
    /// Robust cost `Σ ρ(rᵀ Ω r)` after the iteration (equals chi2 without a kernel).
    pub cost: f64,
    /// Damping used by the accepted step.
    pub lambda: f64,
    /// Linear solves this iteration (more than one when steps were rejected).
    pub linear_solves: usize,
    /// `‖δ‖₂` of the accepted step.
    pub step_norm: f64,
    /// `max |g|` at the start of the iteration.
    pub gradient_max: f64,
    /// Seconds since the start of the run.
    pub elapsed_secs: f64,
}

/// What an optimisation did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OptimizerInfo {
    /// Chi2 of the initial guess.
    pub initial_chi2: f64,
    /// Chi2 at the end.
    pub final_chi2: f64,
    /// Robust cost at the start.
    pub initial_cost: f64,
    /// Robust cost at the end.
    pub final_cost: f64,
    /// Per-iteration statistics.
    pub iterations: Vec<IterationStats>,
    /// Why the run stopped.
    pub termination: Termination,
    /// Vertices held fixed to remove the gauge freedom (lowest id of each unanchored component).
    pub gauge_fixed: Vec<NodeId>,
    /// Scalar unknowns.
    pub unknowns: usize,
    /// Seconds spent in the run.
    pub seconds: f64,
}

/// Optimises `graph` in place. See [`optimize_with_progress`].
pub fn optimize<G: LieGroup<D>, const D: usize>(
    graph: &mut PoseGraph<G, D>,
    params: &OptimizerParams,
) -> Result<OptimizerInfo, SolveError> {
    optimize_with_progress(graph, params, |_| {})
}

/// Optimises `graph` in place and calls `progress` after every iteration.
///
/// On a numerical failure the graph holds the last accepted state and
/// `info.termination` is [`Termination::NumericalFailure`].
pub fn optimize_with_progress<G: LieGroup<D>, const D: usize>(
    graph: &mut PoseGraph<G, D>,
    params: &OptimizerParams,
    progress: impl FnMut(&IterationStats),
) -> Result<OptimizerInfo, SolveError> {
    params.validate()?;
    let mut problem = Problem::compile(graph)?;
    let weights = vec![1.0; problem.edges.len()];
    let mut session = Session::new(&mut problem)?;
    let info = session.run(&mut problem, &weights, params, progress);
    problem.write_back(graph);
    Ok(info)
}

/// Reusable optimisation state: the normal equations (symbolic factorisation done once) and
/// scratch buffers. GNC runs many optimisations on one session.
pub(crate) struct Session<G, const D: usize> {
    pub normal: NormalEquations<D>,
    linearizations: Vec<EdgeLinearization<D>>,
    irls_weights: Vec<f64>,
    step: Vec<f64>,
    candidate: Vec<G>,
}

impl<G: LieGroup<D>, const D: usize> Session<G, D> {
    /// Renumbers the problem's free slots in fill-reducing order and builds the normal
    /// equations (symbolic analysis once).
    pub fn new(problem: &mut Problem<G, D>) -> Result<Self, SolveError> {
        Self::with_active_edges(problem, None)
    }

    /// Like [`Session::new`], but only edges marked active enter the sparsity pattern; the
    /// others must then carry weight 0 in every run (GNC drops rejected edges this way, which
    /// keeps the factor sparse once random false loop closures are switched off).
    pub fn with_active_edges(
        problem: &mut Problem<G, D>,
        active: Option<&[bool]>,
    ) -> Result<Self, SolveError> {
        let slots_of_edges = |problem: &Problem<G, D>| -> Vec<(u32, u32)> {
            problem
                .edges
                .iter()
                .enumerate()
                .map(|(k, e)| {
                    if active.is_some_and(|mask| !mask.get(k).copied().unwrap_or(true)) {
                        (FIXED, FIXED)
                    } else {
                        (
                            problem.free_slot[e.from as usize],
                            problem.free_slot[e.to as usize],
                        )
                    }
                })
                .collect()
        };
        let new_of_old = fill_reducing_slots(problem.num_free, &slots_of_edges(problem))?;
        for slot in problem.free_slot.iter_mut().filter(|s| **s != FIXED) {
            *slot = new_of_old[*slot as usize];
        }
        let slots = slots_of_edges(problem);
        let normal = NormalEquations::new(problem.num_free, &slots)?;
        Ok(Self {
            normal,
            linearizations: Vec::with_capacity(problem.edges.len()),
            irls_weights: vec![1.0; problem.edges.len()],
            step: Vec::new(),
            candidate: Vec::with_capacity(problem.poses.len()),
        })
    }

    /// Linearises at the problem's poses and fills the normal equations with weights
    /// `outer_weight · ρ'(χ²)`.
    pub fn linearize(&mut self, problem: &Problem<G, D>, weights: &[f64], kernel: &RobustKernel) {
        problem.linearize_all(&mut self.linearizations);
        for ((w, lin), outer) in self
            .irls_weights
            .iter_mut()
            .zip(&self.linearizations)
            .zip(weights)
        {
            *w = outer * kernel.weight(lin.chi2);
        }
        self.normal.assemble(
            &self.linearizations,
            problem.edges.iter().map(|e| e.information),
            &self.irls_weights,
        );
    }

    /// Runs GN or LM from the problem's current poses.
    pub fn run(
        &mut self,
        problem: &mut Problem<G, D>,
        weights: &[f64],
        params: &OptimizerParams,
        mut progress: impl FnMut(&IterationStats),
    ) -> OptimizerInfo {
        let start = Instant::now();
        let kernel = params.robust;
        let (initial_chi2, initial_cost) = problem.cost(&problem.poses, weights, &kernel);
        let mut info = OptimizerInfo {
            initial_chi2,
            final_chi2: initial_chi2,
            initial_cost,
            final_cost: initial_cost,
            iterations: Vec::new(),
            termination: Termination::MaxIterations,
            gauge_fixed: problem.gauge_fixed.clone(),
            unknowns: self.normal.dim(),
            seconds: 0.0,
        };
        if self.normal.dim() == 0 {
            info.termination = Termination::NothingToOptimize;
            return info;
        }
        let mut cost = initial_cost;
        let mut chi2 = initial_chi2;
        let mut lambda = params.lambda_initial;
        let gauss_newton = params.algorithm == Algorithm::GaussNewton;
        for iteration in 1..=params.max_iterations {
            if cost <= params.absolute_tolerance {
                info.termination = Termination::AbsoluteCost;
                break;
            }
            self.linearize(problem, weights, &kernel);
            let gradient_max = self.normal.gradient_max_abs();
            if gradient_max <= params.gradient_tolerance {
                info.termination = Termination::Gradient;
                break;
            }
            let mut linear_solves = 0;
            let mut accepted: Option<(f64, f64)> = None;
            let mut failure: Option<String> = None;
            loop {
                linear_solves += 1;
                let damping = if gauss_newton { 0.0 } else { lambda };
                if !self.normal.solve_damped(damping, &mut self.step) {
                    if gauss_newton {
                        failure = Some("Gauss-Newton system is not positive definite".into());
                        break;
                    }
                } else {
                    problem.retract_into(&self.step, &mut self.candidate);
                    let (new_chi2, new_cost) = problem.cost(&self.candidate, weights, &kernel);
                    if new_cost.is_finite() && (new_cost < cost || gauss_newton) {
                        accepted = Some((new_chi2, new_cost));
                        break;
                    }
                    if gauss_newton {
                        break;
                    }
                }
                lambda *= params.lambda_factor;
                if lambda > params.lambda_max {
                    break;
                }
            }
            if let Some(reason) = failure {
                info.termination = Termination::NumericalFailure(reason);
                break;
            }
            let Some((new_chi2, new_cost)) = accepted else {
                info.termination = Termination::NoFurtherDecrease;
                break;
            };
            if gauss_newton && new_cost >= cost {
                info.termination = Termination::NoFurtherDecrease;
                break;
            }
            std::mem::swap(&mut problem.poses, &mut self.candidate);
            let decrease = (cost - new_cost) / cost.max(f64::MIN_POSITIVE);
            cost = new_cost;
            chi2 = new_chi2;
            let stats = IterationStats {
                iteration,
                chi2,
                cost,
                lambda: if gauss_newton { 0.0 } else { lambda },
                linear_solves,
                step_norm: self.step.iter().map(|x| x * x).sum::<f64>().sqrt(),
                gradient_max,
                elapsed_secs: start.elapsed().as_secs_f64(),
            };
            progress(&stats);
            info.iterations.push(stats);
            lambda = (lambda / params.lambda_factor).max(1e-12);
            if decrease < params.relative_decrease_tolerance {
                info.termination = Termination::RelativeDecrease;
                break;
            }
        }
        info.final_chi2 = chi2;
        info.final_cost = cost;
        info.seconds = start.elapsed().as_secs_f64();
        info
    }

    /// The free slot of every vertex (for marginals).
    pub fn slot_of(problem: &Problem<G, D>, vertex: usize) -> Option<usize> {
        let s = *problem.free_slot.get(vertex)?;
        (s != FIXED).then_some(s as usize)
    }
}
