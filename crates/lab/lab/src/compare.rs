//! `mapmerge compare`: absolute trajectory error between two graphs over their common vertex
//! ids (position errors; optionally after the best rigid alignment, Horn/Umeyama without scale).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use mapmerge_eval::{trajectory_error, TrajectoryError};
use mapmerge_io::AnyGraph;
use serde::Serialize;

use crate::corrupt::load;
use crate::BadInput;

/// Arguments of `mapmerge compare`.
#[derive(Args, Debug)]
pub struct CompareArgs {
    /// Reference graph (e.g. ground truth or a trusted optimum); g2o or TORO, `.xz` accepted.
    pub reference: PathBuf,
    /// Estimated graph, same dimension; vertices are matched by id.
    pub estimate: PathBuf,
    /// Rigidly align the estimate onto the reference first (rotation + translation, no scale).
    #[arg(long)]
    pub align: bool,
    /// Print one JSON object on stdout instead of the human summary.
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize, Debug)]
struct Report {
    reference: String,
    estimate: String,
    aligned: bool,
    reference_vertices: usize,
    estimate_vertices: usize,
    matched: usize,
    rms_m: f64,
    mean_m: f64,
    max_m: f64,
}

/// Runs `mapmerge compare`.
pub fn run(args: &CompareArgs) -> anyhow::Result<ExitCode> {
    let reference = load(&args.reference)?;
    let estimate = load(&args.estimate)?;
    for (loaded, path) in [(&reference, &args.reference), (&estimate, &args.estimate)] {
        if !loaded.had_vertices {
            let msg = format!(
                "{}: no vertex lines, so no poses to compare",
                path.display()
            );
            return Err(anyhow::Error::new(BadInput(msg)));
        }
    }
    let result: Result<TrajectoryError, _> = match (&reference.graph, &estimate.graph) {
        (AnyGraph::Planar(r), AnyGraph::Planar(e)) => trajectory_error(r, e, args.align),
        (AnyGraph::Spatial(r), AnyGraph::Spatial(e)) => trajectory_error(r, e, args.align),
        _ => {
            let msg = format!(
                "{} and {} differ in dimension (2D vs 3D)",
                args.reference.display(),
                args.estimate.display()
            );
            return Err(anyhow::Error::new(BadInput(msg)));
        }
    };
    let err = result.map_err(|e| {
        BadInput(format!(
            "{} vs {}: {e}",
            args.reference.display(),
            args.estimate.display()
        ))
    })?;
    let report = Report {
        reference: args.reference.display().to_string(),
        estimate: args.estimate.display().to_string(),
        aligned: args.align,
        reference_vertices: reference.graph.num_vertices(),
        estimate_vertices: estimate.graph.num_vertices(),
        matched: err.matched,
        rms_m: err.rms_m,
        mean_m: err.mean_m,
        max_m: err.max_m,
    };
    if args.json {
        crate::print_json(&report)?;
    } else {
        println!(
            "{} vertices matched{}: position error rms {:.6} m, mean {:.6} m, max {:.6} m",
            report.matched,
            if args.align { " (aligned)" } else { "" },
            report.rms_m,
            report.mean_m,
            report.max_m
        );
    }
    Ok(ExitCode::SUCCESS)
}
