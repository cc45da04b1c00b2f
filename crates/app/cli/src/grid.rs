//! `mapmerge grid`: an occupancy grid from a laser log and known poses.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use mapmerge_geometry::Se2;
use mapmerge_grid::{CellClass, ClassThresholds, InsertParams, OccupancyGrid};
use mapmerge_io::{MapMode, RosMap};
use mapmerge_render::{Picture, PictureStyle, Rgb};
use mapmerge_scan::LaserLog;
use serde::Serialize;

use crate::{bad_file, bad_input, check_resolution, print_json};

/// Arguments of `mapmerge grid`.
#[derive(Args, Debug)]
pub struct GridArgs {
    /// CARMEN laser log (`.xz` accepted) or ROS 2 bag (`.mcap`, `.db3`, or a bag directory).
    #[arg(long)]
    pub log: PathBuf,
    /// Topics of a ROS 2 bag.
    #[command(flatten)]
    pub topics: crate::BagTopics,
    /// Poses of the scans, one per scan in log order: a TUM trajectory (`.tum`/`.txt`) or
    /// a CARMEN log whose scan poses are used (e.g. a corrected log). Default: the poses in
    /// `--log` itself.
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// Cell side (m).
    #[arg(long, default_value_t = 0.05)]
    pub resolution: f64,
    /// Returns farther than this (m) only clear free space (default: all returns are hits).
    #[arg(long)]
    pub max_range: Option<f32>,
    /// Output map: ROS map_server YAML; the PGM is written next to it.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Also draw the map (with the trajectory) to this PNG.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Print one JSON summary instead of text.
    #[arg(long)]
    pub json: bool,
}

/// What `grid` did.
#[derive(Serialize)]
struct GridReport<'a> {
    log: &'a Path,
    scans: usize,
    hits: usize,
    cells_visited: usize,
    resolution_m: f64,
    width: usize,
    height: usize,
    origin_m: [f64; 2],
    occupied_cells: usize,
    free_cells: usize,
    unknown_cells: usize,
    build_secs: f64,
    map_yaml: &'a Path,
    png: Option<&'a Path>,
}

/// A log and one pose per scan (`map_from_robot`).
pub struct PosedLog {
    /// The log.
    pub log: LaserLog,
    /// One pose per scan, in scan order.
    pub poses: Vec<Se2>,
}

/// Reads `log` and the poses of its scans: from `poses` (TUM, or a CARMEN log's scan poses)
/// or from the log itself. Scans are paired with poses by order, not by stamp (some public
/// logs have broken stamps).
pub fn load_posed_log(
    log: &Path,
    poses_path: Option<&Path>,
    topics: &crate::BagTopics,
) -> anyhow::Result<PosedLog> {
    let laser_log = crate::read_log(log, topics)?;
    let scan_count = laser_log.scans.len();
    let poses = match poses_path {
        None => poses_of(&laser_log, log)?,
        Some(path) if is_tum(path) => mapmerge_io::read_tum_planar(path)
            .map_err(bad_file)?
            .into_iter()
            .map(|(_, pose)| pose)
            .collect(),
        Some(path) => poses_of(&crate::read_log(path, topics)?, path)?,
    };
    if poses.len() != scan_count {
        return Err(bad_input(format!(
            "{}: {} poses for the {scan_count} scans of {} (poses pair with scans by order)",
            poses_path.unwrap_or(log).display(),
            poses.len(),
            log.display()
        )));
    }
    Ok(PosedLog {
        log: laser_log,
        poses,
    })
}

fn is_tum(path: &Path) -> bool {
    let name = path.to_string_lossy();
    let name = name.strip_suffix(".xz").unwrap_or(&name);
    name.ends_with(".tum") || name.ends_with(".txt")
}

/// The poses a log attaches to its scans; an error names the first scan without one.
fn poses_of(log: &LaserLog, path: &Path) -> anyhow::Result<Vec<Se2>> {
    log.scans
        .iter()
        .enumerate()
        .map(|(k, record)| {
            record.odom_from_robot.ok_or_else(|| {
                bad_input(format!(
                    "{}: scan {k} ({}) carries no pose; give --poses",
                    path.display(),
                    record.source_tag
                ))
            })
        })
        .collect()
}

/// Builds the grid of a posed log, with a progress bar on stderr when it is a terminal (and
/// `progress` is set).
pub fn build_grid(
    posed: &PosedLog,
    resolution_m: f64,
    params: &InsertParams,
    progress: bool,
) -> anyhow::Result<(OccupancyGrid, mapmerge_grid::InsertInfo)> {
    let bar = crate::progress_bar(posed.poses.len(), "scans", "grid", progress);
    let built = mapmerge_jobs::build_grid(&posed.log, &posed.poses, resolution_m, params, || {
        bar.inc(1)
    });
    bar.finish_and_clear();
    built.map_err(crate::job_error)
}

/// Runs `mapmerge grid`.
pub fn run(args: &GridArgs) -> anyhow::Result<ExitCode> {
    check_resolution(args.resolution)?;
    let posed = load_posed_log(&args.log, args.poses.as_deref(), &args.topics)?;
    let mut params = InsertParams::default();
    if let Some(max_range) = args.max_range {
        params.max_hit_range_m = max_range;
    }
    let started = Instant::now();
    let (grid, info) = build_grid(&posed, args.resolution, &params, !args.json)?;
    let build_secs = started.elapsed().as_secs_f64();
    let thresholds = ClassThresholds::default();
    let map = RosMap::from_grid(&grid, MapMode::Trinary, &thresholds);
    mapmerge_io::write_ros_map(&args.output, &map).context("writing the map")?;
    if let Some(png) = &args.png {
        let style = PictureStyle {
            pixels_per_cell: 1,
            classes: Some(thresholds),
        };
        let mut picture = Picture::of_grid(&grid, &style);
        picture.draw_trajectory(&posed.poses, Rgb::RED, 1.0);
        picture.save_png(png)?;
    }
    let count = |class| {
        grid.log_odds()
            .iter()
            .filter(|&&l| thresholds.classify(l) == class)
            .count()
    };
    let geometry = grid.geometry();
    let report = GridReport {
        log: &args.log,
        scans: posed.poses.len(),
        hits: info.hits,
        cells_visited: info.cells_visited,
        resolution_m: geometry.resolution_m,
        width: geometry.width,
        height: geometry.height,
        origin_m: [geometry.origin_m.x, geometry.origin_m.y],
        occupied_cells: count(CellClass::Occupied),
        free_cells: count(CellClass::Free),
        unknown_cells: count(CellClass::Unknown),
        build_secs,
        map_yaml: &args.output,
        png: args.png.as_deref(),
    };
    if args.json {
        print_json(&report)?;
    } else {
        println!(
            "{} scans → {} × {} cells at {} m ({} occupied, {} free) in {:.3} s; wrote {}{}",
            report.scans,
            report.width,
            report.height,
            report.resolution_m,
            report.occupied_cells,
            report.free_cells,
            build_secs,
            args.output.display(),
            args.png
                .as_ref()
                .map(|p| format!(" and {}", p.display()))
                .unwrap_or_default()
        );
    }
    Ok(ExitCode::SUCCESS)
}
