//! Optimising a pose graph file: read, initialise, optimise, write back (`mapmerge optimize`).

use std::path::Path;
use std::time::Instant;

use mapmerge_geometry::LieGroup;
use mapmerge_io::{write_graph, AnyGraph, BadInformation, GraphFormat, LoadedGraph, ReadParams};
use mapmerge_posegraph::{EdgeId, PoseGraph};
use mapmerge_solve::{
    chi2_quantile_99, optimize_gnc, optimize_with_progress, Algorithm, GncParams, IterationStats,
    OptimizerInfo, OptimizerParams, RobustKernel, Termination,
};
use serde::Serialize;

use crate::JobError;

/// Robust cost choices.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum RobustChoice {
    /// Plain least squares.
    None,
    /// Huber kernel, width √χ²₀.₉₉(D) unless --kernel-width is given.
    Huber,
    /// Cauchy kernel, width √χ²₀.₉₉(D) unless --kernel-width is given.
    Cauchy,
    /// Dynamic covariance scaling, Φ = 1 unless --kernel-width is given.
    Dcs,
    /// Graduated non-convexity with truncated least squares; reports rejected edges.
    Gnc,
}

/// Initial-guess choices.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum InitChoice {
    /// The file's poses; odometry chaining when the file has no vertex lines.
    Auto,
    /// The file's poses as they are.
    None,
    /// Compose odometry edges (then a spanning tree) from the first vertex.
    Odometry,
    /// Global initialisation: LAGO in 2D, chordal relaxation in 3D.
    Global,
}

/// Gauss–Newton or Levenberg–Marquardt.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum AlgorithmChoice {
    /// Levenberg–Marquardt.
    Lm,
    /// Gauss–Newton.
    Gn,
}

/// What to do with edges whose information matrix is not positive definite.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum BadInformationChoice {
    /// Stop with an error naming the line.
    Reject,
    /// Keep the diagonal when it is positive (drops correlations; SE-Sync's cubicle needs it).
    KeepDiagonal,
}

/// A choice by its name on the command line (`"gnc"`, `"keep-diagonal"`, …).
pub trait Choice: Sized + Copy + 'static {
    /// Every choice with its name, in the order the CLI lists them.
    const NAMES: &'static [(&'static str, Self)];
    /// What the choice is for (`"robust"`), in errors.
    const WHAT: &'static str;

    /// The choice named `name`; bad input naming the possible values otherwise.
    fn from_name(name: &str) -> Result<Self, JobError> {
        Self::NAMES
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, c)| *c)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::NAMES.iter().map(|(n, _)| *n).collect();
                JobError::bad_input(format!(
                    "invalid value '{name}' for {}: possible values are {}",
                    Self::WHAT,
                    names.join(", ")
                ))
            })
    }
}

impl Choice for RobustChoice {
    const NAMES: &'static [(&'static str, Self)] = &[
        ("none", Self::None),
        ("huber", Self::Huber),
        ("cauchy", Self::Cauchy),
        ("dcs", Self::Dcs),
        ("gnc", Self::Gnc),
    ];
    const WHAT: &'static str = "robust";
}

impl Choice for InitChoice {
    const NAMES: &'static [(&'static str, Self)] = &[
        ("auto", Self::Auto),
        ("none", Self::None),
        ("odometry", Self::Odometry),
        ("global", Self::Global),
    ];
    const WHAT: &'static str = "init";
}

impl Choice for AlgorithmChoice {
    const NAMES: &'static [(&'static str, Self)] = &[("lm", Self::Lm), ("gn", Self::Gn)];
    const WHAT: &'static str = "algorithm";
}

impl Choice for BadInformationChoice {
    const NAMES: &'static [(&'static str, Self)] = &[
        ("reject", Self::Reject),
        ("keep-diagonal", Self::KeepDiagonal),
    ];
    const WHAT: &'static str = "bad_information";
}

/// How to optimise (the options of `mapmerge optimize`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct OptimizeOptions {
    /// Robust cost for outlier edges (default: none).
    pub robust: RobustChoice,
    /// Kernel width (Huber/Cauchy: Mahalanobis distance; DCS: Φ; GNC: inlier χ² threshold)
    /// (default: the kernel's own).
    pub kernel_width: Option<f64>,
    /// Initial guess (default: auto).
    pub init: InitChoice,
    /// Nonlinear least-squares method (default: LM).
    pub algorithm: AlgorithmChoice,
    /// Maximum iterations; 0 only initialises (default: 100).
    pub max_iterations: usize,
    /// Stop when an iteration lowers the cost by less than this fraction (default: 1e-9).
    pub relative_tolerance: f64,
    /// Edges whose information matrix is not positive definite (default: reject).
    pub bad_information: BadInformationChoice,
}

impl Default for OptimizeOptions {
    fn default() -> Self {
        Self {
            robust: RobustChoice::None,
            kernel_width: None,
            init: InitChoice::Auto,
            algorithm: AlgorithmChoice::Lm,
            max_iterations: 100,
            relative_tolerance: 1e-9,
            bad_information: BadInformationChoice::Reject,
        }
    }
}

/// A rejected edge, named by its index among the input file's edge lines.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RejectedEdge {
    /// Index among the edge lines.
    pub edge: u64,
    /// Its vertices' ids.
    pub from: u64,
    /// See `from`.
    pub to: u64,
}

/// What an optimisation did: the `--json` object of `mapmerge optimize`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct OptimizeReport {
    /// The input file.
    pub input: String,
    /// The output file (none when nothing was written).
    pub output: Option<String>,
    /// `g2o` or `toro`.
    pub format: String,
    /// 2 or 3.
    pub dimension: usize,
    /// Vertices and edges.
    pub vertices: usize,
    /// See `vertices`.
    pub edges: usize,
    /// The initial guess chosen, and the chi2 after it when it did something.
    pub init: InitChoice,
    /// See `init`.
    pub init_chi2: Option<f64>,
    /// The robust cost.
    pub robust: RobustChoice,
    /// Chi2 before and after the optimisation, and the robust cost after it.
    pub initial_chi2: f64,
    /// See `initial_chi2`.
    pub final_chi2: f64,
    /// See `initial_chi2`.
    pub final_cost: f64,
    /// Iterations (of the last solve, with GNC).
    pub iterations: usize,
    /// Why the solver stopped.
    pub termination: Termination,
    /// Vertices held fixed to remove the gauge freedom.
    pub gauge_fixed: Vec<u64>,
    /// GNC's outliers.
    pub rejected_edges: Vec<RejectedEdge>,
    /// GNC's steps.
    pub gnc_steps: Option<usize>,
    /// Information matrices whose diagonal was kept (`keep-diagonal`).
    pub repaired_edges: usize,
    /// Wall times (s): reading, initialising, optimising, and the whole job.
    pub load_seconds: f64,
    /// See `load_seconds`.
    pub init_seconds: f64,
    /// See `load_seconds`.
    pub optimize_seconds: f64,
    /// See `load_seconds`.
    pub seconds: f64,
    /// Per-iteration statistics.
    pub iteration_log: Vec<IterationStats>,
}

/// What a job tells its caller as it goes.
#[derive(Debug)]
pub enum OptimizeProgress<'a> {
    /// The graph was read and initialised.
    Initialised(&'a Initialised),
    /// An iteration ended (not reported by GNC).
    Iteration(&'a IterationStats),
}

/// The graph as read and initialised.
#[derive(Clone, Debug, PartialEq)]
pub struct Initialised {
    /// The input's name.
    pub input: String,
    /// 2 or 3.
    pub dimension: usize,
    /// Vertices and edges.
    pub vertices: usize,
    /// See `vertices`.
    pub edges: usize,
    /// Reading time (s).
    pub load_seconds: f64,
    /// Information matrices whose diagonal was kept.
    pub repaired_edges: usize,
    /// The initial guess chosen, the chi2 after it when it did something and its time (s).
    pub init: InitChoice,
    /// See `init`.
    pub init_chi2: Option<f64>,
    /// See `init`.
    pub init_seconds: f64,
}

/// The optimised graph, in its input's format with its ids, and the report.
#[derive(Clone, Debug)]
pub struct Optimized {
    /// The graph.
    pub graph: AnyGraph,
    /// The input's format.
    pub format: GraphFormat,
    /// What happened.
    pub report: OptimizeReport,
}

impl Optimized {
    /// The solver's reason when it failed numerically (the graph holds the last good state).
    pub fn numerical_failure(&self) -> Option<&str> {
        match &self.report.termination {
            Termination::NumericalFailure(reason) => Some(reason),
            _ => None,
        }
    }
}

/// The CLI's message after a numerical failure (exit code 1, the output still written).
pub fn numerical_failure_message(reason: &str) -> String {
    format!("numerical failure ({reason}); wrote the last good state")
}

/// Reads a graph file; any failure is bad input, with the reason chain kept.
pub fn load_graph(
    path: &Path,
    bad_information: BadInformationChoice,
) -> Result<LoadedGraph, JobError> {
    let params = ReadParams {
        bad_information: match bad_information {
            BadInformationChoice::Reject => BadInformation::Reject,
            BadInformationChoice::KeepDiagonal => BadInformation::KeepDiagonal,
        },
    };
    mapmerge_io::read_graph_with(path, &params).map_err(|e| JobError::bad_file(&e))
}

/// `mapmerge optimize`: reads `input`, then [`optimize_loaded`].
pub fn optimize_file(
    input: &Path,
    output: Option<&Path>,
    options: &OptimizeOptions,
    progress: impl FnMut(OptimizeProgress<'_>),
) -> Result<Optimized, JobError> {
    let start = Instant::now();
    let loaded = load_graph(input, options.bad_information)?;
    let load_seconds = start.elapsed().as_secs_f64();
    optimize_loaded(
        loaded,
        &input.display().to_string(),
        load_seconds,
        output,
        options,
        progress,
    )
}

/// Initialises and optimises a graph read from `input` in `load_seconds`, writes it to
/// `output` (in the input's format, with its ids) when given, and reports. A numerical
/// failure is not an error: the report says so and the graph holds the last good state.
pub fn optimize_loaded(
    loaded: LoadedGraph,
    input: &str,
    load_seconds: f64,
    output: Option<&Path>,
    options: &OptimizeOptions,
    mut progress: impl FnMut(OptimizeProgress<'_>),
) -> Result<Optimized, JobError> {
    let start = Instant::now();
    let repaired_edges = loaded.repaired_edges.len();
    let had_vertices = loaded.had_vertices;
    let format = loaded.format;
    let mut graph = loaded.graph;
    let init_start = Instant::now();
    let (dimension, vertices, edges, init_chi2) = match &mut graph {
        AnyGraph::Planar(g) => {
            let c = initialise(g, options.init, had_vertices, |g| {
                mapmerge_init::initialize_lago(g, &Default::default())
                    .map(|_| ())
                    .map_err(|e| JobError::context("LAGO initialisation", &e))
            })?;
            (2, g.num_vertices(), g.num_edges(), c)
        }
        AnyGraph::Spatial(g) => {
            let c = initialise(g, options.init, had_vertices, |g| {
                mapmerge_init::initialize_chordal(g, &Default::default())
                    .map(|_| ())
                    .map_err(|e| JobError::context("chordal initialisation", &e))
            })?;
            (3, g.num_vertices(), g.num_edges(), c)
        }
    };
    let init_seconds = init_start.elapsed().as_secs_f64();
    progress(OptimizeProgress::Initialised(&Initialised {
        input: input.to_owned(),
        dimension,
        vertices,
        edges,
        load_seconds,
        repaired_edges,
        init: options.init,
        init_chi2,
        init_seconds,
    }));
    let optimize_start = Instant::now();
    let outcome = match &mut graph {
        AnyGraph::Planar(g) => run_solver(g, options, &mut progress)?,
        AnyGraph::Spatial(g) => run_solver(g, options, &mut progress)?,
    };
    let optimize_seconds = optimize_start.elapsed().as_secs_f64();
    let rejected_edges = rejected_report(&graph, &outcome.rejected);
    if let Some(output) = output {
        // The output path is the user's: bad input (issue 67).
        write_graph(output, &graph, format).map_err(|e| JobError::bad_file(&e))?;
    }
    let info = outcome.info;
    let report = OptimizeReport {
        input: input.to_owned(),
        output: output.map(|p| p.display().to_string()),
        format: format!("{format:?}").to_lowercase(),
        dimension,
        vertices,
        edges,
        init: options.init,
        init_chi2,
        robust: options.robust,
        initial_chi2: info.initial_chi2,
        final_chi2: info.final_chi2,
        final_cost: info.final_cost,
        iterations: info.iterations.len(),
        termination: info.termination,
        gauge_fixed: info.gauge_fixed.iter().map(|id| id.0).collect(),
        rejected_edges,
        gnc_steps: outcome.gnc_steps,
        repaired_edges,
        load_seconds,
        init_seconds,
        optimize_seconds,
        seconds: load_seconds + start.elapsed().as_secs_f64(),
        iteration_log: info.iterations,
    };
    Ok(Optimized {
        graph,
        format,
        report,
    })
}

struct Outcome {
    info: OptimizerInfo,
    rejected: Vec<EdgeId>,
    gnc_steps: Option<usize>,
}

fn robust_kernel(choice: RobustChoice, width: Option<f64>, dof: usize) -> RobustKernel {
    let default_width = chi2_quantile_99(dof).sqrt();
    match choice {
        RobustChoice::None | RobustChoice::Gnc => RobustKernel::None,
        RobustChoice::Huber => RobustKernel::Huber {
            delta: width.unwrap_or(default_width),
        },
        RobustChoice::Cauchy => RobustKernel::Cauchy {
            c: width.unwrap_or(default_width),
        },
        RobustChoice::Dcs => RobustKernel::Dcs {
            phi: width.unwrap_or(1.0),
        },
    }
}

fn run_solver<G: LieGroup<D>, const D: usize>(
    graph: &mut PoseGraph<G, D>,
    options: &OptimizeOptions,
    progress: &mut impl FnMut(OptimizeProgress<'_>),
) -> Result<Outcome, JobError> {
    let params = OptimizerParams {
        algorithm: match options.algorithm {
            AlgorithmChoice::Lm => Algorithm::LevenbergMarquardt,
            AlgorithmChoice::Gn => Algorithm::GaussNewton,
        },
        robust: robust_kernel(options.robust, options.kernel_width, D),
        max_iterations: options.max_iterations,
        relative_decrease_tolerance: options.relative_tolerance,
        ..Default::default()
    };
    params.validate().map_err(JobError::bad_input)?;
    if options.robust == RobustChoice::Gnc {
        let gnc = GncParams {
            inlier_threshold_chi2: options.kernel_width,
            inner: OptimizerParams {
                robust: RobustKernel::None,
                ..GncParams::default().inner
            },
            ..Default::default()
        };
        let info =
            optimize_gnc(graph, &gnc).map_err(|e| JobError::context("GNC optimisation", &e))?;
        return Ok(Outcome {
            info: info.optimizer,
            rejected: info.rejected,
            gnc_steps: Some(info.steps),
        });
    }
    let info = optimize_with_progress(graph, &params, |s| {
        progress(OptimizeProgress::Iteration(s));
    })
    .map_err(|e| JobError::context("optimisation", &e))?;
    Ok(Outcome {
        info,
        rejected: Vec::new(),
        gnc_steps: None,
    })
}

/// Initialises per `choice`; returns the chi2 after initialisation when something was done.
fn initialise<G: LieGroup<D>, const D: usize>(
    graph: &mut PoseGraph<G, D>,
    choice: InitChoice,
    had_vertices: bool,
    global: impl FnOnce(&mut PoseGraph<G, D>) -> Result<(), JobError>,
) -> Result<Option<f64>, JobError> {
    let odometry = |graph: &mut PoseGraph<G, D>| {
        mapmerge_init::initialize_odometry(graph)
            .map(|_| ())
            .map_err(|e| JobError::context("odometry initialisation", &e))
    };
    match choice {
        InitChoice::None => Ok(None),
        InitChoice::Auto if had_vertices => Ok(None),
        InitChoice::Auto | InitChoice::Odometry => {
            odometry(graph)?;
            Ok(Some(graph.chi2()))
        }
        InitChoice::Global => {
            if !had_vertices {
                odometry(graph)?;
            }
            global(graph)?;
            Ok(Some(graph.chi2()))
        }
    }
}

fn rejected_report(graph: &AnyGraph, rejected: &[EdgeId]) -> Vec<RejectedEdge> {
    let ends = |id: EdgeId| match graph {
        AnyGraph::Planar(g) => g.edge(id).map(|e| (e.from, e.to)),
        AnyGraph::Spatial(g) => g.edge(id).map(|e| (e.from, e.to)),
    };
    rejected
        .iter()
        .filter_map(|id| {
            ends(*id).map(|(from, to)| RejectedEdge {
                edge: id.0,
                from: from.0,
                to: to.0,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    const SQUARE: &str = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1.1 0 0\nVERTEX_SE2 2 1 1.2 1.5\n\
        EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 0 1 1.5708 1 0 0 1 0 1\n\
        EDGE_SE2 0 2 1 1 1.5708 1 0 0 1 0 1\n";

    #[test]
    fn a_consistent_graph_is_optimised_to_zero_chi2_and_written_back() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("in.g2o");
        let output = dir.path().join("out.g2o");
        std::fs::write(&input, SQUARE).unwrap();
        let mut iterations = 0;
        let done = optimize_file(&input, Some(&output), &OptimizeOptions::default(), |p| {
            if let OptimizeProgress::Iteration(_) = p {
                iterations += 1;
            }
        })
        .unwrap();
        let r = &done.report;
        assert_eq!((r.dimension, r.vertices, r.edges), (2, 3, 3));
        assert!(r.initial_chi2 > 0.1 && r.final_chi2 < 1e-9, "{r:?}");
        assert_eq!(r.iterations, iterations);
        assert_eq!(r.format, "g2o");
        assert_eq!(r.output.as_deref(), Some(&*output.display().to_string()));
        let again = mapmerge_io::read_graph(&output).unwrap();
        assert_eq!(again.graph, done.graph);
        assert!(done.numerical_failure().is_none());
    }

    #[test]
    fn errors_carry_the_clis_messages_and_exit_codes() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("bad.g2o");
        std::fs::write(&input, "VERTEX_SE2 0 0 0\n").unwrap();
        let err = optimize_file(&input, None, &OptimizeOptions::default(), |_| {}).unwrap_err();
        assert_eq!(
            err,
            JobError::BadInput(format!(
                "{}:1: truncated VERTEX_SE2 line: expected 4 fields after the tag, found 3",
                input.display()
            ))
        );
        let options = OptimizeOptions {
            relative_tolerance: -1.0,
            ..Default::default()
        };
        std::fs::write(&input, SQUARE).unwrap();
        let err = optimize_file(&input, None, &options, |_| {}).unwrap_err();
        assert_eq!(err.exit_code(), 2, "{err}");
        assert_eq!(
            RobustChoice::from_name("tls").unwrap_err().to_string(),
            "invalid value 'tls' for robust: possible values are none, huber, cauchy, dcs, gnc"
        );
        assert_eq!(
            BadInformationChoice::from_name("keep-diagonal").unwrap(),
            BadInformationChoice::KeepDiagonal
        );
    }
}
