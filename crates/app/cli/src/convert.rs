//! `mapmerge convert`: a laser log (CARMEN or a ROS 2 bag) → a ROS 2 bag (`.mcap`, `.db3`) or a
//! CARMEN log, and how fast each was read.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use clap::Args;
use serde::Serialize;

use crate::{bad_file, bad_input, print_json};

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

#[derive(Serialize)]
struct ConvertReport<'a> {
    log: &'a Path,
    output: &'a Path,
    scans: usize,
    odometry_messages: usize,
    input_bytes: u64,
    read_secs: f64,
    read_mb_per_s: f64,
    write_secs: f64,
    output_bytes: u64,
    /// Why the output's stamps are a new clock, if they are.
    stamps_rewritten: Option<String>,
}

fn input_bytes(path: &Path) -> u64 {
    if path.is_dir() {
        std::fs::read_dir(path)
            .map(|entries| {
                entries
                    .filter_map(|e| e.ok()?.metadata().ok())
                    .map(|m| m.len())
                    .sum()
            })
            .unwrap_or(0)
    } else {
        std::fs::metadata(path).map_or(0, |m| m.len())
    }
}

/// A KITTI-style folder (a 3D segment: `velodyne/*.bin`, `poses.txt`) → a bag of PointCloud2
/// and odometry, every point kept.
fn convert_kitti_folder(args: &ConvertArgs) -> anyhow::Result<ExitCode> {
    let every_point = mapmerge_assemble::KittiFolderOptions {
        voxel_m: 0.0,
        max_range_m: f64::MAX.sqrt(),
        stride: 1,
    };
    let started = Instant::now();
    let segment = mapmerge_assemble::load_kitti_folder(&args.log, &every_point).map_err(|e| bad_input(e.to_string()))?;
    let read_secs = started.elapsed().as_secs_f64();
    let started = Instant::now();
    let params = mapmerge_rosbag::BagWriteParams {
        rewritten_period_s: args.period,
        ..Default::default()
    };
    let written = mapmerge_rosbag::write_cloud_bag(&args.output, &segment.poses, &segment.clouds, &params)
        .map_err(bad_file)?;
    let write_secs = started.elapsed().as_secs_f64();
    let bytes = input_bytes(&args.log.join("velodyne"));
    let report = ConvertReport {
        log: &args.log,
        output: &args.output,
        scans: written.scans,
        odometry_messages: written.odometry_messages,
        input_bytes: bytes,
        read_secs,
        read_mb_per_s: bytes as f64 / 1e6 / read_secs.max(1e-9),
        write_secs,
        output_bytes: written.bytes,
        stamps_rewritten: Some(format!("a KITTI folder's clouds are stamped {} s apart", args.period)),
    };
    if args.json {
        print_json(&report)?;
    } else {
        println!(
            "{} clouds: read {} in {:.3} s, wrote {} in {:.3} s",
            report.scans,
            args.log.display(),
            read_secs,
            args.output.display(),
            write_secs
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// Runs `mapmerge convert`.
pub fn run(args: &ConvertArgs) -> anyhow::Result<ExitCode> {
    if !(args.period.is_finite() && args.period > 0.0) {
        return Err(bad_input(format!("--period must be positive, got {}", args.period)));
    }
    if args.log.is_dir() && !mapmerge_rosbag::is_bag(&args.log) {
        return convert_kitti_folder(args);
    }
    let started = Instant::now();
    let log = crate::read_log(&args.log, &args.topics)?;
    let read_secs = started.elapsed().as_secs_f64();
    if log.scans.is_empty() {
        return Err(bad_input(format!("{}: no laser scans", args.log.display())));
    }
    let started = Instant::now();
    let (odometry_messages, stamps_rewritten) = if mapmerge_rosbag::Storage::of_file(&args.output).is_some() {
        let params = mapmerge_rosbag::BagWriteParams {
            rewritten_period_s: args.period,
            ..Default::default()
        };
        let written = mapmerge_rosbag::write_bag(&args.output, &log, &params).map_err(bad_file)?;
        (written.odometry_messages, written.stamps_rewritten)
    } else {
        let name = args.output.to_string_lossy();
        if !(name.ends_with(".log") || name.ends_with(".log.xz")) {
            return Err(bad_input(format!(
                "{}: name the output .mcap, .db3 (a ROS 2 bag) or .log / .log.xz (CARMEN)",
                args.output.display()
            )));
        }
        mapmerge_io::write_carmen(&args.output, &log).map_err(bad_file)?;
        (log.odometry.len(), None)
    };
    let write_secs = started.elapsed().as_secs_f64();
    let bytes = input_bytes(&args.log);
    let report = ConvertReport {
        log: &args.log,
        output: &args.output,
        scans: log.scans.len(),
        odometry_messages,
        input_bytes: bytes,
        read_secs,
        read_mb_per_s: bytes as f64 / 1e6 / read_secs.max(1e-9),
        write_secs,
        output_bytes: input_bytes(&args.output),
        stamps_rewritten,
    };
    if args.json {
        print_json(&report)?;
    } else {
        println!(
            "{} scans, {} odometry messages: read {} in {:.3} s ({:.1} MB/s), wrote {} in {:.3} s",
            report.scans,
            report.odometry_messages,
            args.log.display(),
            read_secs,
            report.read_mb_per_s,
            args.output.display(),
            write_secs
        );
        if let Some(reason) = &report.stamps_rewritten {
            println!("stamps rewritten at {} s per scan: {reason}", args.period);
        }
    }
    Ok(ExitCode::SUCCESS)
}
