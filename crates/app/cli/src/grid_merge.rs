//! `mapmerge grid-merge A.yaml B.yaml -o MERGED.yaml`: merge two ROS map_server maps of any
//! resolution without an initial guess (Andersone's framework: decision table, Carpin's
//! matching, quality-weighted Bayes fusion into A's frame and resolution;
//! `mapmerge_jobs::grid_merge`, shared with the Python module).
//!
//! Exit codes: 0 merged, 3 no acceptable hypothesis (or the decision table refused; the reason
//! is printed), 2 bad input.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use mapmerge_gridmatch::GridMatchParams;
use mapmerge_jobs::{grid_merge, GridMergeReport, DEFAULT_HYPOTHESES};

use crate::job_error;
use crate::print_json;

/// Exit code when no hypothesis is acceptable.
const NOT_MERGED: u8 = 3;

/// Arguments of `mapmerge grid-merge`.
#[derive(Args, Debug)]
pub struct GridMergeArgs {
    /// The receiving map (ROS map_server YAML); the merged map has its frame and resolution.
    pub a: PathBuf,
    /// The map to merge in (ROS map_server YAML), any resolution.
    pub b: PathBuf,
    /// The merged map (YAML; the PGM is written next to it, the picture as `.png`).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Matching parameters (JSON file, `mapmerge_gridmatch::GridMatchParams`; absent fields
    /// keep their defaults).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Runner-up hypotheses reported.
    #[arg(long, default_value_t = DEFAULT_HYPOTHESES)]
    pub hypotheses: usize,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Runs `mapmerge grid-merge`.
pub fn run(args: &GridMergeArgs) -> anyhow::Result<ExitCode> {
    crate::check_output_file(&args.output)?;
    let params: GridMatchParams = crate::read_config(args.config.as_deref())?;
    let done = grid_merge(
        &args.a,
        &args.b,
        &params,
        args.hypotheses,
        Some(&args.output),
    )
    .map_err(job_error)?;
    finish(args, &done.report)
}

fn finish(args: &GridMergeArgs, report: &GridMergeReport) -> anyhow::Result<ExitCode> {
    if args.json {
        print_json(report)?;
    } else if report.accepted {
        if let Some(t) = report.transform {
            println!(
                "merged: B in A at x {:.3} m, y {:.3} m, yaw {:.2}° (acceptance {:.3}, DM {:.2} cells) in {:.3} s; wrote {}{}",
                t.x,
                t.y,
                t.yaw.to_degrees(),
                report.acceptance.unwrap_or(0.0),
                report.dm.unwrap_or(0.0),
                report.seconds,
                args.output.display(),
                report
                    .png
                    .as_ref()
                    .map(|p| format!(" and {}", p.display()))
                    .unwrap_or_default()
            );
        }
    } else {
        eprintln!(
            "mapmerge: not merged: {}",
            report
                .reason
                .as_deref()
                .unwrap_or("no acceptable hypothesis")
        );
    }
    Ok(if report.accepted {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(NOT_MERGED)
    })
}
