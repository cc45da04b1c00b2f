//! `mapmerge slam`: 2D graph SLAM on a laser log (the lifelong engine with one epoch: the
//! local tracker and the atlas's loop closing), writing the pose graph, the map, a picture and
//! one pose per scan (`mapmerge_jobs`); with `--odometry-noise`, on a corrected log, judged
//! against the log's own poses (`mapmerge_lab::slam_judge`).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::Args;
use mapmerge_engine::EngineParams;
use mapmerge_geometry::Se2;
use mapmerge_jobs::{write_slam_outputs, TUM_CLOCK_PERIOD_S};
use mapmerge_lab::slam_judge::{judge_slam, noisy_session, LoopPrecision, TrajectoryReport};
use serde::Serialize;

use crate::{bad_input, check_resolution, job_error, print_json};

/// Arguments of `mapmerge slam`.
#[derive(Args, Debug)]
pub struct SlamArgs {
    /// CARMEN laser log (`.xz` accepted) or ROS 2 bag (`.mcap`, `.db3`, or a bag
    /// directory); its scans' odometry poses are the wheel odometry.
    pub log: PathBuf,
    /// Topics of a ROS 2 bag.
    #[command(flatten)]
    pub topics: crate::BagTopics,
    /// Output folder: graph.g2o, map.yaml + map.pgm, map.png, trajectory.tum.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Replace the log's odometry by seeded noisy odometry first (`default` or `harsh`; for
    /// the public *corrected* logs, whose odometry is the corrected path). The result is
    /// then scored against the log's own poses, which are written as `reference.tum`.
    #[arg(long)]
    pub odometry_noise: Option<String>,
    /// Seed of `--odometry-noise`.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Cell side of the map (m).
    #[arg(long, default_value_t = 0.05)]
    pub resolution: f64,
    /// Engine parameters as JSON (any subset of the fields `--json` reports under
    /// `params`; the rest keep their defaults). Default: the one configuration used for
    /// every public log.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print one JSON summary instead of text.
    #[arg(long)]
    pub json: bool,
}

/// What `slam` did.
#[derive(Serialize)]
struct SlamReport<'a> {
    log: &'a Path,
    #[serde(flatten)]
    run: mapmerge_jobs::SlamSummary,
    /// With `--odometry-noise`: the SLAM trajectory and the noisy odometry scored against
    /// the log's own (corrected) poses.
    score: Option<TrajectoryReport>,
    odometry_score: Option<TrajectoryReport>,
    /// With `--odometry-noise`: the accepted loop edges judged against the log's poses.
    loops: Option<LoopPrecision>,
    /// Why `trajectory.tum` (and `reference.tum`) are stamped by a clock of
    /// `TUM_CLOCK_PERIOD_S` per scan instead of the log's stamps, if they are.
    tum_stamps_rewritten: Option<String>,
    output: &'a Path,
    params: &'a EngineParams,
}

/// Runs `mapmerge slam`.
pub fn run(args: &SlamArgs) -> anyhow::Result<ExitCode> {
    crate::check_output_dir(&args.output)?;
    check_resolution(args.resolution)?;
    let mut log = crate::read_log(&args.log, &args.topics)?;
    if log.scans.is_empty() {
        return Err(bad_input(format!("{}: no laser scans", args.log.display())));
    }
    // With noise: the log's poses become the reference, its odometry the noisy one.
    let mut reference = None;
    if let Some(name) = &args.odometry_noise {
        let mut noisy = noisy_session(&log, name, args.seed)
            .map_err(|e| bad_input(format!("{}: {e}", args.log.display())))?;
        log = std::mem::take(&mut noisy.log);
        reference = Some(noisy);
    }
    let bar = crate::progress_bar(log.scans.len(), "scans", "slam", !args.json);
    let params: EngineParams = crate::read_config(args.config.as_deref())?;
    let run = mapmerge_jobs::slam_log(&args.log, &log, params.clone(), |done| {
        bar.set_position(done as u64);
    })
    .map_err(job_error)?;
    bar.finish_and_clear();
    crate::return_freed_memory();
    let (stamps, tum_stamps_rewritten) = log.increasing_scan_stamps(TUM_CLOCK_PERIOD_S);
    if let Some(reference) = &reference {
        std::fs::create_dir_all(&args.output).map_err(crate::writing(&args.output))?;
        let stamped: Vec<(f64, Se2)> = stamps
            .iter()
            .copied()
            .zip(reference.corrected.iter().copied())
            .collect();
        let path = args.output.join("reference.tum");
        mapmerge_io::write_tum_planar(&path, &stamped).map_err(crate::writing(&path))?;
    }
    let bar = crate::progress_bar(log.scans.len(), "scans", "grid", !args.json);
    write_slam_outputs(
        &args.output,
        &log,
        &run.trajectory,
        &run.graph,
        args.resolution,
        || bar.inc(1),
    )
    .map_err(job_error)?;
    bar.finish_and_clear();
    let (score, odometry_score, loops) = match &reference {
        Some(reference) => {
            let scores = judge_slam(&run, reference)?;
            (
                Some(scores.score),
                Some(scores.odometry_score),
                Some(scores.loops),
            )
        }
        None => (None, None, None),
    };
    let report = SlamReport {
        log: &args.log,
        run: mapmerge_jobs::SlamSummary::of(&run),
        score,
        odometry_score,
        loops,
        tum_stamps_rewritten,
        output: &args.output,
        params: &params,
    };
    if args.json {
        print_json(&report)?;
    } else {
        let (tracker, info) = (
            &report.run.front_end.tracker,
            &report.run.front_end.constraints,
        );
        println!(
            "{} scans in {:.2} s ({:.1} ms/scan): {} keyframes, {} submaps, {} loops ({} local, {} by place recognition), {} optimisations; wrote {}",
            report.run.scans,
            report.run.seconds,
            report.run.ms_per_scan,
            tracker.keyframes,
            tracker.submaps,
            info.local_loops + info.place_loops,
            info.local_loops,
            info.place_loops,
            info.optimizations,
            args.output.display()
        );
        if let (Some(score), Some(odometry)) = (&report.score, &report.odometry_score) {
            println!(
                "ATE against the log's poses: {:.3} m (noisy odometry: {:.3} m)",
                score.ate.rms_m, odometry.ate.rms_m
            );
        }
        if let Some(loops) = &report.loops {
            println!(
                "loop edges within 0.5 m / 10° of the log's poses: {} of {}",
                loops.true_local + loops.true_place,
                loops.accepted
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}
