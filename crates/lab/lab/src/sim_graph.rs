//! `mapmerge simulate`: a synthetic Manhattan-world pose graph with known ground truth
//! (grid random walk, quarter turns, noisy odometry, loop closures on revisits).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::Args;
use mapmerge_eval::{
    count_loop_closures, simulate_manhattan_2d, trajectory_error, ManhattanParams,
};
use mapmerge_io::{write_graph, AnyGraph, GraphFormat};
use serde::Serialize;

use crate::BadInput;

/// Arguments of `mapmerge simulate`.
#[derive(Args, Debug)]
pub struct SimulateArgs {
    /// Output graph with the odometry-chained initial guess: g2o, or TORO when the name ends in
    /// `.graph` (`.xz` compresses).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Also write the ground truth (same edges, exact poses) here.
    #[arg(long, value_name = "GT")]
    pub ground_truth: Option<PathBuf>,
    /// Number of poses.
    #[arg(long, default_value_t = 500)]
    pub poses: usize,
    /// Seed of the random generator (ChaCha8): same arguments, same files.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Side of the square world, m (default: 12 · √(poses / 500), at least 2, so the density
    /// of revisits stays about the same).
    #[arg(long)]
    pub world_size_m: Option<f64>,
    /// Standard deviation of the x/y noise of every measurement, m.
    #[arg(long, default_value_t = ManhattanParams::default().sigma_xy_m)]
    pub sigma_xy_m: f64,
    /// Standard deviation of the heading noise of every measurement, rad.
    #[arg(long, default_value_t = ManhattanParams::default().sigma_theta_rad)]
    pub sigma_theta_rad: f64,
    /// Probability that a revisit (same grid cell, at least 10 poses apart) gets a loop closure.
    #[arg(long, default_value_t = ManhattanParams::default().loop_probability)]
    pub loop_probability: f64,
    /// Print one JSON object on stdout instead of the human summary.
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize, Debug)]
struct Report {
    output: String,
    ground_truth: Option<String>,
    seed: u64,
    params: ManhattanParams,
    vertices: usize,
    edges: usize,
    loop_closures: usize,
    /// chi2 of the initial guess.
    initial_chi2: f64,
    /// chi2 at the ground truth (≈ 3 · edges for consistent noise).
    truth_chi2: f64,
    /// Position RMS error of the initial guess against the ground truth (no alignment), m.
    initial_rms_m: f64,
}

fn format_for(path: &Path) -> GraphFormat {
    let name = path.to_string_lossy();
    let name = name.strip_suffix(".xz").unwrap_or(&name);
    if name.ends_with(".graph") {
        GraphFormat::Toro
    } else {
        GraphFormat::G2o
    }
}

/// Runs `mapmerge simulate`.
pub fn run(args: &SimulateArgs) -> anyhow::Result<ExitCode> {
    let world_size_m = args
        .world_size_m
        .unwrap_or_else(|| (12.0 * (args.poses as f64 / 500.0).sqrt()).max(2.0));
    let params = ManhattanParams {
        num_poses: args.poses,
        world_size_m,
        sigma_xy_m: args.sigma_xy_m,
        sigma_theta_rad: args.sigma_theta_rad,
        loop_probability: args.loop_probability,
        ..ManhattanParams::default()
    };
    let (noisy, truth) = simulate_manhattan_2d(&params, args.seed)
        .map_err(|err| anyhow::Error::new(BadInput(err.to_string())))?;
    let initial_rms_m = trajectory_error(&truth, &noisy, false)
        .map(|e| e.rms_m)
        .unwrap_or(0.0);
    let report = Report {
        output: args.output.display().to_string(),
        ground_truth: args.ground_truth.as_ref().map(|p| p.display().to_string()),
        seed: args.seed,
        params,
        vertices: noisy.num_vertices(),
        edges: noisy.num_edges(),
        loop_closures: count_loop_closures(&noisy),
        initial_chi2: noisy.chi2(),
        truth_chi2: truth.chi2(),
        initial_rms_m,
    };
    write_graph(
        &args.output,
        &AnyGraph::Planar(noisy),
        format_for(&args.output),
    )?;
    if let Some(path) = &args.ground_truth {
        write_graph(path, &AnyGraph::Planar(truth), format_for(path))?;
    }
    if args.json {
        crate::print_json(&report)?;
    } else {
        println!(
            "simulated {} poses, {} edges ({} loop closures); initial chi2 {:.3}, chi2 at truth \
             {:.3}, initial RMS error {:.3} m; wrote {}{}",
            report.vertices,
            report.edges,
            report.loop_closures,
            report.initial_chi2,
            report.truth_chi2,
            report.initial_rms_m,
            report.output,
            report
                .ground_truth
                .as_deref()
                .map(|g| format!(" and {g}"))
                .unwrap_or_default()
        );
    }
    Ok(ExitCode::SUCCESS)
}
