//! `mapmerge slam`: 2D graph SLAM on a laser log (the lifelong engine with one epoch: the
//! local tracker and the atlas's loop closing), writing the pose graph, the map, a picture and
//! one pose per scan.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use mapmerge_atlas::LoopSource;
use mapmerge_engine::{EngineParams, SlamRun};
use mapmerge_eval::{
    add_odometry_noise, make_relations, scan_poses, trajectory_report, OdometryNoiseProfile,
    RelationsParams, TrajectoryReport, DEFAULT_RPE_DELTAS,
};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{ClassThresholds, InsertParams, OccupancyGrid};
use mapmerge_io::{AnyGraph, GraphFormat, MapMode, RosMap};
use mapmerge_posegraph::PoseGraph2;
use mapmerge_render::{GraphStyle, Picture, PictureStyle, Rgb};
use mapmerge_scan::LaserLog;
use serde::Serialize;

use crate::{bad_input, check_resolution, print_json};
use crate::{build_posed_grid as build_grid, PosedLog};

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

/// Seconds per scan of the clock a TUM file gets when the log's stamps do not increase.
pub(crate) const TUM_CLOCK_PERIOD_S: f64 = 0.1;

/// Writes a SLAM run's outputs into `dir` (created if missing): `trajectory.tum` (one pose per
/// scan, with the scan's stamp, or [`TUM_CLOCK_PERIOD_S`] apart when the log's stamps do not
/// increase: TUM readers such as evo pair poses by stamp), `graph.g2o`, the map from every scan at its final pose
/// (`map.yaml` + `map.pgm`) and `map.png` with the trajectory and graph over it. Returns the
/// map.
pub(crate) fn write_map_outputs(
    dir: &Path,
    log: LaserLog,
    trajectory: &[Se2],
    graph: &PoseGraph2,
    resolution_m: f64,
    progress: bool,
) -> anyhow::Result<OccupancyGrid> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let (stamps, _) = log.increasing_scan_stamps(TUM_CLOCK_PERIOD_S);
    let stamped: Vec<(f64, Se2)> = stamps.into_iter().zip(trajectory.iter().copied()).collect();
    mapmerge_io::write_tum_planar(&dir.join("trajectory.tum"), &stamped)?;
    let any = AnyGraph::Planar(graph.clone());
    mapmerge_io::write_graph(&dir.join("graph.g2o"), &any, GraphFormat::G2o)?;
    let posed = PosedLog {
        log,
        poses: trajectory.to_vec(),
    };
    let (grid, _) = build_grid(&posed, resolution_m, &InsertParams::default(), progress)?;
    let thresholds = ClassThresholds::default();
    let map = RosMap::from_grid(&grid, MapMode::Trinary, &thresholds);
    mapmerge_io::write_ros_map(&dir.join("map.yaml"), &map).context("writing the map")?;
    let style = PictureStyle {
        pixels_per_cell: 1,
        classes: Some(thresholds),
    };
    let mut picture = Picture::of_grid(&grid, &style);
    picture.draw_trajectory(trajectory, Rgb::RED, 1.0);
    picture.draw_graph(graph, &GraphStyle::default());
    picture.save_png(&dir.join("map.png"))?;
    Ok(grid)
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

/// Accepted loop edges judged against reference poses: true when within 0.5 m and 10° of
/// the reference relative pose (the rule for a verified candidate).
#[derive(Serialize)]
struct LoopPrecision {
    accepted: usize,
    accepted_local: usize,
    accepted_place: usize,
    true_local: usize,
    true_place: usize,
    precision: Option<f64>,
    worst_translation_error_m: f64,
    worst_rotation_error_deg: f64,
    /// The loop edges that are not true, with their errors.
    false_loops: Vec<FalseLoop>,
}

/// A loop edge beyond 0.5 m or 10° of the reference.
#[derive(Serialize)]
struct FalseLoop {
    from: u64,
    to: u64,
    from_scan: usize,
    to_scan: usize,
    source: LoopSource,
    score: f64,
    translation_error_m: f64,
    rotation_error_deg: f64,
}

/// Judges every loop of `run` against `reference` (one pose per scan).
fn loop_precision(run: &SlamRun, reference: &[Se2]) -> LoopPrecision {
    let mut precision = LoopPrecision {
        accepted: run.loops.len(),
        accepted_local: 0,
        accepted_place: 0,
        true_local: 0,
        true_place: 0,
        precision: None,
        worst_translation_error_m: 0.0,
        worst_rotation_error_deg: 0.0,
        false_loops: Vec::new(),
    };
    let scan_of = |node: mapmerge_posegraph::NodeId| {
        run.keyframe_scans
            .get(usize::try_from(node.0).ok()?)
            .copied()
    };
    let pose_of = |node| reference.get(scan_of(node)?).copied();
    for record in &run.loops {
        let is_place = record.source == LoopSource::Place;
        if is_place {
            precision.accepted_place += 1;
        } else {
            precision.accepted_local += 1;
        }
        let (Some(from), Some(to)) = (pose_of(record.from), pose_of(record.to)) else {
            continue;
        };
        let error = from.between(&to).between(&record.measurement);
        let (translation_m, rotation_deg) = (
            error.translation().norm(),
            error.theta_rad.abs().to_degrees(),
        );
        precision.worst_translation_error_m =
            precision.worst_translation_error_m.max(translation_m);
        precision.worst_rotation_error_deg = precision.worst_rotation_error_deg.max(rotation_deg);
        if translation_m <= 0.5 && rotation_deg <= 10.0 {
            if is_place {
                precision.true_place += 1;
            } else {
                precision.true_local += 1;
            }
        } else {
            precision.false_loops.push(FalseLoop {
                from: record.from.0,
                to: record.to.0,
                from_scan: scan_of(record.from).unwrap_or_default(),
                to_scan: scan_of(record.to).unwrap_or_default(),
                source: record.source,
                score: record.score,
                translation_error_m: translation_m,
                rotation_error_deg: rotation_deg,
            });
        }
    }
    if precision.accepted > 0 {
        precision.precision =
            Some((precision.true_local + precision.true_place) as f64 / precision.accepted as f64);
    }
    precision
}

/// Runs `mapmerge slam`.
pub fn run(args: &SlamArgs) -> anyhow::Result<ExitCode> {
    check_resolution(args.resolution)?;
    let mut log = crate::read_log(&args.log, &args.topics)?;
    if log.scans.is_empty() {
        return Err(bad_input(format!("{}: no laser scans", args.log.display())));
    }
    // With noise: the log's poses become the reference, its odometry the noisy one.
    let mut reference = None;
    if let Some(name) = &args.odometry_noise {
        let profile = OdometryNoiseProfile::from_name(name).map_err(bad_input)?;
        let corrected =
            scan_poses(&log).map_err(|e| bad_input(format!("{}: {e}", args.log.display())))?;
        let noisy = add_odometry_noise(&log, &profile, args.seed)
            .map_err(|e| bad_input(format!("{}: {e}", args.log.display())))?;
        reference = Some((corrected, noisy.odometry_poses()));
        log = noisy.log;
    }
    let bar = crate::progress_bar(log.scans.len(), "scans", "slam", !args.json);
    let params: EngineParams = crate::read_config(args.config.as_deref())?;
    let run = mapmerge_jobs::slam_log(&args.log, &log, params.clone(), |done| {
        bar.set_position(done as u64);
    })
    .map_err(crate::job_error)?;
    bar.finish_and_clear();
    let (stamps, tum_stamps_rewritten) = log.increasing_scan_stamps(TUM_CLOCK_PERIOD_S);
    if let Some((corrected, _)) = &reference {
        std::fs::create_dir_all(&args.output)?;
        let stamped: Vec<(f64, Se2)> = stamps
            .iter()
            .copied()
            .zip(corrected.iter().copied())
            .collect();
        mapmerge_io::write_tum_planar(&args.output.join("reference.tum"), &stamped)?;
    }
    write_map_outputs(
        &args.output,
        log,
        &run.trajectory,
        &run.graph,
        args.resolution,
        !args.json,
    )?;
    let (score, odometry_score, loops) = match &reference {
        Some((corrected, odometry)) => {
            let relations = make_relations(corrected, &RelationsParams::default())?;
            (
                Some(trajectory_report(
                    corrected,
                    &run.trajectory,
                    &relations,
                    &DEFAULT_RPE_DELTAS,
                )?),
                Some(trajectory_report(
                    corrected,
                    odometry,
                    &relations,
                    &DEFAULT_RPE_DELTAS,
                )?),
                Some(loop_precision(&run, corrected)),
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
