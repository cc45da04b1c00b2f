//! `mapmerge optimize`: load a pose graph, initialise, optimise, write it back
//! (`mapmerge_jobs::optimize_file`, shared with the Python module).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use mapmerge_jobs::{
    optimize_file, AlgorithmChoice, BadInformationChoice, InitChoice, OptimizeOptions,
    OptimizeProgress, RobustChoice,
};

/// The defaults of the options (one place: `mapmerge_jobs::OptimizeOptions::default`).
fn defaults() -> OptimizeOptions {
    OptimizeOptions::default()
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
    #[arg(long, value_enum, default_value_t = defaults().robust)]
    pub robust: RobustChoice,
    /// Kernel width (Huber/Cauchy: Mahalanobis distance; DCS: Φ; GNC: inlier χ² threshold).
    #[arg(long)]
    pub kernel_width: Option<f64>,
    /// Initial guess.
    #[arg(long, value_enum, default_value_t = defaults().init)]
    pub init: InitChoice,
    /// Nonlinear least-squares method.
    #[arg(long, value_enum, default_value_t = defaults().algorithm)]
    pub algorithm: AlgorithmChoice,
    /// Maximum iterations (0 only initialises and writes).
    #[arg(long, default_value_t = defaults().max_iterations)]
    pub max_iterations: usize,
    /// Stop when an iteration lowers the cost by less than this fraction.
    #[arg(long, default_value_t = defaults().relative_tolerance)]
    pub relative_tolerance: f64,
    /// Edges whose information matrix is not positive definite.
    #[arg(long, value_enum, default_value_t = defaults().bad_information)]
    pub bad_information: BadInformationChoice,
    /// Print one JSON object on stdout instead of the human summary.
    #[arg(long)]
    pub json: bool,
}

/// Runs `mapmerge optimize`.
pub fn run(args: &OptimizeArgs) -> anyhow::Result<ExitCode> {
    crate::check_output_file(&args.output)?;
    let options = OptimizeOptions {
        robust: args.robust,
        kernel_width: args.kernel_width,
        init: args.init,
        algorithm: args.algorithm,
        max_iterations: args.max_iterations,
        relative_tolerance: args.relative_tolerance,
        bad_information: args.bad_information,
    };
    let quiet = args.json;
    let done = optimize_file(&args.input, Some(&args.output), &options, |event| {
        if quiet {
            return;
        }
        match event {
            OptimizeProgress::Initialised(i) => {
                eprintln!(
                    "loaded {} ({}D, {} vertices, {} edges) in {:.3} s",
                    i.input, i.dimension, i.vertices, i.edges, i.load_seconds
                );
                if i.repaired_edges > 0 {
                    eprintln!(
                        "kept only the diagonal of {} non-positive-definite information matrices",
                        i.repaired_edges
                    );
                }
                if let Some(c) = i.init_chi2 {
                    eprintln!(
                        "initialised ({:?}): chi2 {c:.6} in {:.3} s",
                        i.init, i.init_seconds
                    );
                }
            }
            OptimizeProgress::Iteration(s) => eprintln!(
                "iteration {:>3}  chi2 {:<14.6}  cost {:<14.6}  lambda {:<9.2e}  |step| {:<9.3e}  {:.3} s",
                s.iteration, s.chi2, s.cost, s.lambda, s.step_norm, s.elapsed_secs
            ),
        }
    })
    .map_err(crate::job_error)?;
    let report = &done.report;
    if args.json {
        crate::print_json(report)?;
    } else {
        println!(
            "{}: chi2 {:.6} -> {:.6} in {} iterations ({:?}); {:.3} s total; wrote {}",
            report.input,
            report.initial_chi2,
            report.final_chi2,
            report.iterations,
            report.termination,
            report.seconds,
            args.output.display()
        );
        if !report.rejected_edges.is_empty() {
            println!("rejected {} edges as outliers", report.rejected_edges.len());
        }
    }
    if let Some(reason) = done.numerical_failure() {
        eprintln!(
            "mapmerge: {}",
            mapmerge_jobs::numerical_failure_message(reason)
        );
        return Ok(ExitCode::from(1));
    }
    Ok(ExitCode::SUCCESS)
}
