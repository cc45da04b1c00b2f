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
    /// Scans, or clouds from a KITTI-style folder.
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

/// Bytes of a file, or of every file below a folder (symbolic links not followed).
fn bytes_on_disk(path: &Path) -> u64 {
    match std::fs::symlink_metadata(path) {
        Ok(meta) if meta.is_dir() => std::fs::read_dir(path).map_or(0, |entries| {
            entries
                .filter_map(|e| e.ok())
                .map(|e| bytes_on_disk(&e.path()))
                .sum()
        }),
        Ok(meta) => meta.len(),
        Err(_) => 0,
    }
}

/// What a conversion wrote: messages (scans or clouds), odometry messages, why the stamps are
/// a new clock (if they are).
struct Written {
    messages: usize,
    odometry_messages: usize,
    stamps_rewritten: Option<String>,
}

/// A KITTI-style folder (a 3D segment: `velodyne/*.bin`, `poses.txt`) → a bag of PointCloud2
/// and odometry, every point kept. Returns the read time and what was written.
fn convert_kitti_folder(
    args: &ConvertArgs,
    params: &mapmerge_rosbag::BagWriteParams,
) -> anyhow::Result<(f64, Written)> {
    let every_point = mapmerge_assemble::KittiFolderOptions {
        voxel_m: 0.0,
        max_range_m: f64::MAX.sqrt(),
        stride: 1,
    };
    let started = Instant::now();
    let segment = mapmerge_assemble::load_kitti_folder(&args.log, &every_point)
        .map_err(|e| bad_input(e.to_string()))?;
    let read_secs = started.elapsed().as_secs_f64();
    let written =
        mapmerge_rosbag::write_cloud_bag(&args.output, &segment.poses, &segment.clouds, params)
            .map_err(bad_file)?;
    Ok((
        read_secs,
        Written {
            messages: written.scans,
            odometry_messages: written.odometry_messages,
            stamps_rewritten: Some("a KITTI folder's clouds carry no stamps".to_owned()),
        },
    ))
}

/// A laser log or bag → a bag or a CARMEN log. Returns the read time and what was written.
fn convert_log(
    args: &ConvertArgs,
    params: &mapmerge_rosbag::BagWriteParams,
) -> anyhow::Result<(f64, Written)> {
    let started = Instant::now();
    let log = crate::read_log(&args.log, &args.topics)?;
    let read_secs = started.elapsed().as_secs_f64();
    if log.scans.is_empty() {
        return Err(bad_input(format!("{}: no laser scans", args.log.display())));
    }
    let written = if mapmerge_rosbag::Storage::of_file(&args.output).is_some() {
        let written = mapmerge_rosbag::write_bag(&args.output, &log, params).map_err(bad_file)?;
        Written {
            messages: written.scans,
            odometry_messages: written.odometry_messages,
            stamps_rewritten: written.stamps_rewritten,
        }
    } else {
        let name = args.output.to_string_lossy();
        if !(name.ends_with(".log") || name.ends_with(".log.xz")) {
            return Err(bad_input(format!(
                "{}: name the output .mcap, .db3 (a ROS 2 bag) or .log / .log.xz (CARMEN)",
                args.output.display()
            )));
        }
        mapmerge_io::write_carmen(&args.output, &log).map_err(bad_file)?;
        Written {
            messages: log.scans.len(),
            odometry_messages: log.odometry.len(),
            stamps_rewritten: None,
        }
    };
    Ok((read_secs, written))
}

/// Runs `mapmerge convert`.
pub fn run(args: &ConvertArgs) -> anyhow::Result<ExitCode> {
    if !(args.period.is_finite() && args.period > 0.0) {
        return Err(bad_input(format!(
            "--period must be positive, got {}",
            args.period
        )));
    }
    let params = mapmerge_rosbag::BagWriteParams {
        rewritten_period_s: args.period,
        ..Default::default()
    };
    let started = Instant::now();
    let kitti_folder = args.log.is_dir() && !mapmerge_rosbag::is_bag(&args.log);
    let (read_secs, written) = if kitti_folder {
        convert_kitti_folder(args, &params)?
    } else {
        convert_log(args, &params)?
    };
    let write_secs = started.elapsed().as_secs_f64() - read_secs;
    let bytes = bytes_on_disk(&args.log);
    let report = ConvertReport {
        log: &args.log,
        output: &args.output,
        scans: written.messages,
        odometry_messages: written.odometry_messages,
        input_bytes: bytes,
        read_secs,
        read_mb_per_s: bytes as f64 / 1e6 / read_secs.max(1e-9),
        write_secs,
        output_bytes: bytes_on_disk(&args.output),
        stamps_rewritten: written.stamps_rewritten,
    };
    if args.json {
        print_json(&report)?;
    } else {
        println!(
            "{} {}, {} odometry messages: read {} in {:.3} s ({:.1} MB/s), wrote {} in {:.3} s",
            report.scans,
            if kitti_folder { "clouds" } else { "scans" },
            report.odometry_messages,
            args.log.display(),
            read_secs,
            report.read_mb_per_s,
            args.output.display(),
            write_secs
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
