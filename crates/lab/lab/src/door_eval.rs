//! `mapmerge eval doors`: door-passing detection (Ehlers et al., Sec. II-B) against the
//! simulator's doors ([`crate::area_truth`]).

use std::path::PathBuf;

use crate::area_truth::{evaluate, DoorReport, DoorScoring};
use clap::Args;
use mapmerge_areas::DoorParams;

use crate::protrusion_eval::seeds;
use crate::{bad_input, print_json};

/// Arguments of `mapmerge eval doors`.
#[derive(Args, Debug)]
pub struct DoorEvalArgs {
    /// World presets.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "office,warehouse,symmetric-hall"
    )]
    pub worlds: Vec<String>,
    /// Seeds (`A-B` or a comma list; the tuning seeds are 1-20, the held-out 101-110).
    #[arg(long, default_value = "101-110")]
    pub seeds: String,
    /// Sessions per world and seed.
    #[arg(long, default_value_t = 2)]
    pub sessions: usize,
    /// Robot time per session (s).
    #[arg(long, default_value_t = 120.0)]
    pub duration: f64,
    /// Detector parameters as JSON (any subset of `mapmerge_areas::DoorParams`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print the whole report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `mapmerge eval doors`.
pub fn run(args: &DoorEvalArgs) -> anyhow::Result<()> {
    let params: DoorParams = crate::read_config(args.config.as_deref())?;
    let seeds = seeds(&args.seeds)?;
    let report: DoorReport = evaluate(
        &args.worlds,
        &seeds,
        args.sessions,
        args.duration,
        &params,
        &DoorScoring::default(),
    )
    .map_err(bad_input)?;
    if args.json {
        print_json(&report)?;
    } else {
        println!("| world | seed | passings | detections | true | precision | recall |");
        println!("|---|---|---|---|---|---|---|");
        for run in &report.runs {
            let c = &run.counts;
            println!(
                "| {} | {} | {} | {} | {} | {:.3} | {:.3} |",
                run.world,
                run.seed,
                c.passings,
                c.detections,
                c.true_detections,
                c.precision(),
                c.recall()
            );
        }
        let t = &report.total;
        println!(
            "| all | | {} | {} | {} | {:.3} | {:.3} |\n\n{:.4} ms per scan in the detector ({} scans).",
            t.passings,
            t.detections,
            t.true_detections,
            report.precision,
            report.recall,
            report.ms_per_scan,
            t.scans
        );
    }
    Ok(())
}
