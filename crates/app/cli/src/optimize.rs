//! `mapmerge optimize`: load a pose graph, initialise, optimise, write it back.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use clap::{Args, ValueEnum};
use mapmerge_geometry::LieGroup;
use mapmerge_io::{write_graph, AnyGraph, BadInformation, ReadParams};
use mapmerge_posegraph::{EdgeId, PoseGraph};
use mapmerge_solve::{
    chi2_quantile_99, optimize_gnc, optimize_with_progress, Algorithm, GncParams, IterationStats,
    OptimizerInfo, OptimizerParams, RobustKernel, Termination,
};
use serde::Serialize;

use crate::BadInput;

/// Robust cost choices on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize)]
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
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize)]
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
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum AlgorithmChoice {
    /// Levenberg–Marquardt.
    Lm,
    /// Gauss–Newton.
    Gn,
}

/// What to do with edges whose information matrix is not positive definite.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum BadInformationChoice {
    /// Stop with an error naming the line.
    Reject,
    /// Keep the diagonal when it is positive (drops correlations; SE-Sync's cubicle needs it).
    KeepDiagonal,
}

/// Arguments of `mapmerge optimize`.
#[derive(Args, Debug)]
pub struct OptimizeArgs {
    /// Input graph: g2o (VERTEX_SE2/EDGE_SE2, VERTEX_SE3:QUAT/EDGE_SE3:QUAT) or TORO
    /// (VERTEX2/EDGE2, VERTEX3/EDGE3); `.xz` is decompressed.
    pub input: PathBuf,
    /// Output graph, written in the input's format with the same ids.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Robust cost for outlier edges.
    #[arg(long, value_enum, default_value_t = RobustChoice::None)]
    pub robust: RobustChoice,
    /// Kernel width (Huber/Cauchy: Mahalanobis distance; DCS: Φ; GNC: inlier χ² threshold).
    #[arg(long)]
    pub kernel_width: Option<f64>,
    /// Initial guess.
    #[arg(long, value_enum, default_value_t = InitChoice::Auto)]
    pub init: InitChoice,
    /// Nonlinear least-squares method.
    #[arg(long, value_enum, default_value_t = AlgorithmChoice::Lm)]
    pub algorithm: AlgorithmChoice,
    /// Maximum iterations (0 only initialises and writes).
    #[arg(long, default_value_t = 100)]
    pub max_iterations: usize,
    /// Stop when an iteration lowers the cost by less than this fraction.
    #[arg(long, default_value_t = 1e-9)]
    pub relative_tolerance: f64,
    /// Edges whose information matrix is not positive definite.
    #[arg(long, value_enum, default_value_t = BadInformationChoice::Reject)]
    pub bad_information: BadInformationChoice,
    /// Print one JSON object on stdout instead of the human summary.
    #[arg(long)]
    pub json: bool,
}

/// A rejected edge, named by its index among the input file's edge lines.
#[derive(Serialize, Debug)]
struct RejectedEdge {
    edge: u64,
    from: u64,
    to: u64,
}

/// The `--json` report.
#[derive(Serialize, Debug)]
struct Report {
    input: String,
    output: String,
    format: String,
    dimension: usize,
    vertices: usize,
    edges: usize,
    init: InitChoice,
    init_chi2: Option<f64>,
    robust: RobustChoice,
    initial_chi2: f64,
    final_chi2: f64,
    final_cost: f64,
    iterations: usize,
    termination: Termination,
    gauge_fixed: Vec<u64>,
    rejected_edges: Vec<RejectedEdge>,
    gnc_steps: Option<usize>,
    repaired_edges: usize,
    load_seconds: f64,
    init_seconds: f64,
    optimize_seconds: f64,
    seconds: f64,
    iteration_log: Vec<IterationStats>,
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
    args: &OptimizeArgs,
) -> anyhow::Result<Outcome> {
    let params = OptimizerParams {
        algorithm: match args.algorithm {
            AlgorithmChoice::Lm => Algorithm::LevenbergMarquardt,
            AlgorithmChoice::Gn => Algorithm::GaussNewton,
        },
        robust: robust_kernel(args.robust, args.kernel_width, D),
        max_iterations: args.max_iterations,
        relative_decrease_tolerance: args.relative_tolerance,
        ..Default::default()
    };
    params.validate().map_err(|e| BadInput(e.to_string()))?;
    if args.robust == RobustChoice::Gnc {
        let gnc = GncParams {
            inlier_threshold_chi2: args.kernel_width,
            inner: OptimizerParams {
                robust: RobustKernel::None,
                ..GncParams::default().inner
            },
            ..Default::default()
        };
        let info = optimize_gnc(graph, &gnc).context("GNC optimisation")?;
        return Ok(Outcome {
            info: info.optimizer,
            rejected: info.rejected,
            gnc_steps: Some(info.steps),
        });
    }
    let quiet = args.json;
    let info = optimize_with_progress(graph, &params, |s| {
        if !quiet {
            eprintln!(
                "iteration {:>3}  chi2 {:<14.6}  cost {:<14.6}  lambda {:<9.2e}  |step| {:<9.3e}  {:.3} s",
                s.iteration, s.chi2, s.cost, s.lambda, s.step_norm, s.elapsed_secs
            );
        }
    })
    .context("optimisation")?;
    Ok(Outcome {
        info,
        rejected: Vec::new(),
        gnc_steps: None,
    })
}

/// Initialises per `--init`; returns the chi2 after initialisation when something was done.
fn initialise<G: LieGroup<D>, const D: usize>(
    graph: &mut PoseGraph<G, D>,
    choice: InitChoice,
    had_vertices: bool,
    global: impl FnOnce(&mut PoseGraph<G, D>) -> anyhow::Result<()>,
) -> anyhow::Result<Option<f64>> {
    match choice {
        InitChoice::None => Ok(None),
        InitChoice::Auto if had_vertices => Ok(None),
        InitChoice::Auto | InitChoice::Odometry => {
            mapmerge_init::initialize_odometry(graph).context("odometry initialisation")?;
            Ok(Some(graph.chi2()))
        }
        InitChoice::Global => {
            if !had_vertices {
                mapmerge_init::initialize_odometry(graph).context("odometry initialisation")?;
            }
            global(graph)?;
            Ok(Some(graph.chi2()))
        }
    }
}

/// Runs `mapmerge optimize`.
pub fn run(args: &OptimizeArgs) -> anyhow::Result<ExitCode> {
    let start = Instant::now();
    let read_params = ReadParams {
        bad_information: match args.bad_information {
            BadInformationChoice::Reject => BadInformation::Reject,
            BadInformationChoice::KeepDiagonal => BadInformation::KeepDiagonal,
        },
    };
    let loaded = crate::load_graph_with(&args.input, &read_params)?;
    let repaired_edges = loaded.repaired_edges.len();
    let load_seconds = start.elapsed().as_secs_f64();
    let had_vertices = loaded.had_vertices;
    let format = loaded.format;
    let mut graph = loaded.graph;
    let init_start = Instant::now();
    let (dimension, vertices, edges, init_chi2) = match &mut graph {
        AnyGraph::Planar(g) => {
            let c = initialise(g, args.init, had_vertices, |g| {
                mapmerge_init::initialize_lago(g, &Default::default())
                    .map(|_| ())
                    .context("LAGO initialisation")
            })?;
            (2, g.num_vertices(), g.num_edges(), c)
        }
        AnyGraph::Spatial(g) => {
            let c = initialise(g, args.init, had_vertices, |g| {
                mapmerge_init::initialize_chordal(g, &Default::default())
                    .map(|_| ())
                    .context("chordal initialisation")
            })?;
            (3, g.num_vertices(), g.num_edges(), c)
        }
    };
    let init_seconds = init_start.elapsed().as_secs_f64();
    if !args.json {
        eprintln!(
            "loaded {} ({}D, {vertices} vertices, {edges} edges) in {load_seconds:.3} s",
            args.input.display(),
            dimension
        );
        if repaired_edges > 0 {
            eprintln!("kept only the diagonal of {repaired_edges} non-positive-definite information matrices");
        }
        if let Some(c) = init_chi2 {
            eprintln!(
                "initialised ({:?}): chi2 {c:.6} in {init_seconds:.3} s",
                args.init
            );
        }
    }
    let optimize_start = Instant::now();
    let outcome = match &mut graph {
        AnyGraph::Planar(g) => run_solver(g, args)?,
        AnyGraph::Spatial(g) => run_solver(g, args)?,
    };
    let optimize_seconds = optimize_start.elapsed().as_secs_f64();
    let rejected_edges = rejected_report(&graph, &outcome.rejected);
    write_graph(&args.output, &graph, format)?;
    let info = &outcome.info;
    let report = Report {
        input: args.input.display().to_string(),
        output: args.output.display().to_string(),
        format: format!("{format:?}").to_lowercase(),
        dimension,
        vertices,
        edges,
        init: args.init,
        init_chi2,
        robust: args.robust,
        initial_chi2: info.initial_chi2,
        final_chi2: info.final_chi2,
        final_cost: info.final_cost,
        iterations: info.iterations.len(),
        termination: info.termination.clone(),
        gauge_fixed: info.gauge_fixed.iter().map(|id| id.0).collect(),
        rejected_edges,
        gnc_steps: outcome.gnc_steps,
        repaired_edges,
        load_seconds,
        init_seconds,
        optimize_seconds,
        seconds: start.elapsed().as_secs_f64(),
        iteration_log: info.iterations.clone(),
    };
    if args.json {
        crate::print_json(&report)?;
    } else {
        println!(
            "{}: chi2 {:.6} -> {:.6} in {} iterations ({:?}); {:.3} s total; wrote {}",
            report.input,
            report.initial_chi2,
            report.final_chi2,
            report.iterations,
            report.termination,
            report.seconds,
            report.output
        );
        if !report.rejected_edges.is_empty() {
            println!("rejected {} edges as outliers", report.rejected_edges.len());
        }
    }
    if let Termination::NumericalFailure(reason) = &info.termination {
        eprintln!("mapmerge: numerical failure ({reason}); wrote the last good state");
        return Ok(ExitCode::from(1));
    }
    Ok(ExitCode::SUCCESS)
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
