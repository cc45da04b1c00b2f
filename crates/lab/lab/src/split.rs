//! `mapmerge split`: cuts a corrected CARMEN log into overlapping segments for assembly
//! experiments (AutoMerge's setting, Yin et al. Sec. III-A: segments without any initial
//! guess), with the ground truth kept apart.
//!
//! The log is cut by scan index into `N` segments of `L` scans each, consecutive segments
//! sharing about `overlap · L` scans: `L = ⌈T / (N − (N − 1) · overlap)⌉` for `T` scans, and
//! the starts spread evenly over `[0, T − L]`, so the first segment starts at scan 0, the last
//! ends at the last scan and every scan belongs to some segment.
//!
//! Every segment is written as `OUT/STEM_NN.log` (`STEM`: the log's file name without
//! `-corrected`, `.log`, `.gz`, `.xz`; `NN` from 00) whose scan poses and `ODOM` messages hold
//! its odometry only, **re-based** so that its first scan is at the origin: the corrected poses
//! chained exactly (`--odometry-noise none`, the default) or with seeded simulated wheel
//! odometry (`default`, `harsh`: `mapmerge_eval::add_odometry_noise`, as `slam
//! --odometry-noise`, with seed `S + NN`). One `ODOM` per scan at the scan's stamp replaces the
//! log's own, which lie on the corrected trajectory in the original frame.
//!
//! The ground truth goes to `OUT/truth/`: `STEM_NN.tum` (line `k`: scan `k` of the segment,
//! its corrected pose in the *original log's* frame, stamped with the scan's time) and
//! `segments.json` (`{"log", "odometry_noise", "seed", "overlap", "segments": [{"file",
//! "truth", "first_scan", "last_scan", "scans"}]}`, scan indices of the original log,
//! inclusive).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use mapmerge_eval::{add_odometry_noise, scan_poses, OdometryNoiseProfile};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::{LaserLog, OdometryReading};
use serde::Serialize;

use crate::{bad_input, print_json};

/// Arguments of `mapmerge split`.
#[derive(Args, Debug)]
pub struct SplitArgs {
    /// Corrected CARMEN laser log (`.xz` accepted) or ROS 2 bag (`.mcap`, `.db3`, or a bag
    /// directory); its scan poses are the ground truth.
    pub log: PathBuf,
    /// Topics of a ROS 2 bag.
    #[command(flatten)]
    pub topics: crate::BagTopics,
    /// Number of segments.
    #[arg(long)]
    pub segments: usize,
    /// Fraction of a segment's scans shared with the next segment, in `[0, 1)`.
    #[arg(long, default_value_t = 0.1)]
    pub overlap: f64,
    /// Odometry of the segments: `none` (the corrected poses, re-based), `default` or
    /// `harsh` (seeded simulated wheel odometry).
    #[arg(long, default_value = "none")]
    pub odometry_noise: String,
    /// Seed of the odometry noise (segment `NN` uses `seed + NN`).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output folder: `STEM_NN.log` per segment, `truth/STEM_NN.tum`, `truth/segments.json`.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Print one JSON summary instead of text.
    #[arg(long)]
    pub json: bool,
}

/// One segment written (the `--json` output and `truth/segments.json`).
#[derive(Clone, Debug, Serialize)]
struct SegmentEntry {
    /// The segment's log, relative to the output folder.
    file: String,
    /// Its truth trajectory, relative to the output folder.
    truth: String,
    /// First scan (index in the original log).
    first_scan: usize,
    /// Last scan (inclusive).
    last_scan: usize,
    /// Number of scans.
    scans: usize,
}

/// `truth/segments.json` and the `--json` report.
#[derive(Serialize)]
struct SplitReport<'a> {
    log: &'a Path,
    output: &'a Path,
    odometry_noise: &'a str,
    seed: u64,
    overlap: f64,
    scans_per_segment: usize,
    segments: Vec<SegmentEntry>,
}

/// `[first, end)` scan ranges of `segments` segments of a `scans`-scan log (module doc), or
/// why the log cannot be cut so.
fn segment_ranges(
    scans: usize,
    segments: usize,
    overlap: f64,
) -> Result<Vec<(usize, usize)>, String> {
    if segments < 1 {
        return Err("--segments must be at least 1".to_owned());
    }
    if !(overlap.is_finite() && (0.0..1.0).contains(&overlap)) {
        return Err(format!("--overlap must lie in [0, 1), got {overlap}"));
    }
    let n = segments as f64;
    let length = ((scans as f64 / (n - (n - 1.0) * overlap)).ceil() as usize).min(scans);
    let span = scans - length;
    // At least 2 scans per segment, and no two segments starting at the same scan.
    if length < 2 || segments - 1 > span {
        return Err(format!(
            "{scans} scans are too few for {segments} segments of at least 2 scans each \
             with overlap {overlap}"
        ));
    }
    Ok((0..segments)
        .map(|i| {
            let first = if segments == 1 {
                0
            } else {
                // Evenly spread starts, rounded to the nearest scan.
                (i * span + (segments - 1) / 2) / (segments - 1)
            };
            (first, first + length)
        })
        .collect())
}

/// The scans `[first, end)` of `log` with `segment_from_robot` poses (re-based truth) and one
/// `ODOM` per scan carrying the same pose.
fn rebased_segment(log: &LaserLog, truth: &[Se2], first: usize, end: usize) -> LaserLog {
    let segment_from_world = truth
        .get(first)
        .copied()
        .unwrap_or_else(Se2::identity)
        .inverse();
    let mut out = LaserLog {
        params: log.params.clone(),
        ..LaserLog::default()
    };
    for (k, (record, world_from_robot)) in log.scans[first..end]
        .iter()
        .zip(&truth[first..end])
        .enumerate()
    {
        // Exactly the origin at the first scan, not x⁻¹·x up to rounding.
        let pose = if k == 0 {
            Se2::identity()
        } else {
            segment_from_world.compose(world_from_robot)
        };
        let mut record = record.clone();
        record.odom_from_robot = Some(pose);
        out.odometry.push(OdometryReading {
            stamp_secs: record.stamp_secs,
            odom_from_robot: pose,
            velocity_m_per_s: 0.0,
            turn_rate_rad_per_s: 0.0,
        });
        out.scans.push(record);
    }
    out
}

/// Runs `mapmerge split`.
pub fn run(args: &SplitArgs) -> anyhow::Result<ExitCode> {
    let profile = OdometryNoiseProfile::from_name(&args.odometry_noise).map_err(bad_input)?;
    let log = crate::read_log(&args.log, &args.topics)?;
    let ranges = segment_ranges(log.scans.len(), args.segments, args.overlap)
        .map_err(|reason| bad_input(format!("{}: {reason}", args.log.display())))?;
    let truth = scan_poses(&log).map_err(|e| bad_input(format!("{}: {e}", args.log.display())))?;
    let stem = crate::log_short_name(&args.log);
    let truth_dir = args.output.join("truth");
    std::fs::create_dir_all(&truth_dir)
        .with_context(|| format!("creating {}", truth_dir.display()))?;
    let digits = (args.segments.saturating_sub(1)).to_string().len().max(2);
    let mut entries = Vec::with_capacity(ranges.len());
    for (index, &(first, end)) in ranges.iter().enumerate() {
        let name = format!("{stem}_{index:0digits$}");
        let mut segment = rebased_segment(&log, &truth, first, end);
        if args.odometry_noise != "none" {
            let seed = args.seed.wrapping_add(index as u64);
            segment = add_odometry_noise(&segment, &profile, seed)
                .map_err(|e| bad_input(format!("{}: {e}", args.log.display())))?
                .log;
        }
        let file = format!("{name}.log");
        mapmerge_io::write_carmen(&args.output.join(&file), &segment)
            .map_err(|e| bad_input(format!("{}: {e}", args.log.display())))?;
        let stamped: Vec<(f64, Se2)> = log.scans[first..end]
            .iter()
            .zip(&truth[first..end])
            .map(|(record, pose)| (record.stamp_secs, *pose))
            .collect();
        let truth_file = format!("truth/{name}.tum");
        mapmerge_io::write_tum_planar(&args.output.join(&truth_file), &stamped)
            .map_err(|e| bad_input(format!("{}: {e}", args.log.display())))?;
        entries.push(SegmentEntry {
            file,
            truth: truth_file,
            first_scan: first,
            last_scan: end - 1,
            scans: end - first,
        });
    }
    let report = SplitReport {
        log: &args.log,
        output: &args.output,
        odometry_noise: &args.odometry_noise,
        seed: args.seed,
        overlap: args.overlap,
        scans_per_segment: entries.first().map_or(0, |e| e.scans),
        segments: entries,
    };
    let summary_path = truth_dir.join("segments.json");
    let text = serde_json::to_string_pretty(&report)?;
    std::fs::write(&summary_path, text + "\n")
        .with_context(|| format!("writing {}", summary_path.display()))?;
    if args.json {
        print_json(&report)?;
    } else {
        for entry in &report.segments {
            println!(
                "{}: scans {}..={} ({} scans)",
                args.output.join(&entry.file).display(),
                entry.first_scan,
                entry.last_scan,
                entry.scans
            );
        }
        println!("truth: {}", truth_dir.display());
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_cover_the_log_with_the_overlap() {
        let ranges = segment_ranges(910, 4, 0.1).unwrap();
        assert_eq!(ranges.first().unwrap().0, 0);
        assert_eq!(ranges.last().unwrap().1, 910);
        let length = ranges[0].1 - ranges[0].0;
        for pair in ranges.windows(2) {
            assert_eq!(pair[1].1 - pair[1].0, length);
            let shared = pair[0].1 - pair[1].0;
            assert!(
                (shared as f64 - 0.1 * length as f64).abs() <= 2.0,
                "{shared}"
            );
        }
        assert_eq!(segment_ranges(10, 1, 0.5).unwrap(), vec![(0, 10)]);
        assert!(segment_ranges(10, 0, 0.1).is_err());
        assert_eq!(segment_ranges(10, 8, 0.1).unwrap().len(), 8);
        assert!(segment_ranges(5, 5, 0.5).is_err());
        assert!(segment_ranges(3, 4, 0.0).is_err());
        assert!(segment_ranges(2, 2, 0.1).is_err());
        assert!(segment_ranges(0, 1, 0.1).is_err());
        assert!(segment_ranges(10, 2, 1.0).is_err());
        assert!(segment_ranges(10, 2, f64::NAN).is_err());
    }

    #[test]
    fn stems_drop_the_known_suffixes() {
        assert_eq!(
            crate::log_short_name(Path::new("/d/intel-corrected.log.xz")),
            "intel"
        );
        assert_eq!(crate::log_short_name(Path::new("run.log")), "run");
        assert_eq!(crate::log_short_name(Path::new("x.gz")), "x");
    }
}
