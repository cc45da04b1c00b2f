//! `mapmerge convert`: a laser log (CARMEN or a ROS 2 bag) → a ROS 2 bag (`.mcap`, `.db3`) or a
//! CARMEN log, and how fast each was read (`mapmerge_jobs::convert`).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;

use crate::{job_error, print_json};

/// Arguments of `mapmerge convert`.
#[derive(Args, Debug)]
pub struct ConvertArgs {
    /// CARMEN laser log (`.xz` accepted), ROS 2 bag (`.mcap`, `.db3`, or a bag directory), or
    /// a KITTI-style folder (a 3D segment of `mapmerge assemble`).
    pub log: PathBuf,
    /// Output: a bag (`.mcap` or `.db3`) with `/scan`, `/odom` and `/tf_static` (from a
    /// folder: `/points` and `/odom`), or a CARMEN log (`.log`, `.log.xz`). Logs whose stamps
    /// do not increase get a clock of `--period` s per scan (reported).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Topics of a ROS 2 bag.
    #[command(flatten)]
    pub topics: crate::BagTopics,
    /// Seconds per scan of the clock written when the log's stamps do not increase.
    #[arg(long, default_value_t = 0.1)]
    pub period: f64,
    /// Print one JSON summary instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Runs `mapmerge convert`.
pub fn run(args: &ConvertArgs) -> anyhow::Result<ExitCode> {
    crate::check_output_file(&args.output)?;
    let report =
        mapmerge_jobs::convert(&args.log, &args.output, &args.topics.choice(), args.period)
            .map_err(job_error)?;
    if args.json {
        print_json(&report)?;
    } else {
        println!(
            "{} {}, {} odometry messages: read {} in {:.3} s ({:.1} MB/s), wrote {} in {:.3} s",
            report.scans,
            if mapmerge_jobs::is_kitti_folder(&args.log) {
                "clouds"
            } else {
                "scans"
            },
            report.odometry_messages,
            args.log.display(),
            report.read_secs,
            report.read_mb_per_s,
            args.output.display(),
            report.write_secs
        );
        if let Some(reason) = &report.stamps_rewritten {
            println!(
                "stamps rewritten at {} s per message: {reason}",
                args.period
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}
