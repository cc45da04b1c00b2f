//! `mapmerge grid`: an occupancy grid from a laser log and known poses.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use clap::Args;
use mapmerge_grid::{CellClass, ClassThresholds, InsertParams};
use mapmerge_io::{MapMode, RosMap};
use mapmerge_render::{Picture, PictureStyle, Rgb};
use serde::Serialize;

use crate::{build_posed_grid as build_grid, check_resolution, load_posed_log, print_json};

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

/// Runs `mapmerge grid`.
pub fn run(args: &GridArgs) -> anyhow::Result<ExitCode> {
    crate::check_output_file(&args.output)?;
    if let Some(png) = &args.png {
        crate::check_output_file(png)?;
    }
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
    mapmerge_io::write_ros_map(&args.output, &map).map_err(crate::writing(&args.output))?;
    if let Some(png) = &args.png {
        let style = PictureStyle {
            pixels_per_cell: 1,
            classes: Some(thresholds),
        };
        let mut picture = Picture::of_grid(&grid, &style);
        picture.draw_trajectory(&posed.poses, Rgb::RED, 1.0);
        picture.save_png(png).map_err(crate::writing(png))?;
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
