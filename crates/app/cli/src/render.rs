//! `mapmerge render`: a grid, pose graphs and trajectories drawn to one PNG.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::Args;
use mapmerge_geometry::Se2;
use mapmerge_grid::{ClassThresholds, GridGeometry, InsertParams, OccupancyGrid, Point2};
use mapmerge_io::AnyGraph;
use mapmerge_render::{session_color, GraphStyle, Picture, PictureStyle};
use serde::Serialize;

use crate::{bad_file, bad_input, check_resolution, load_graph, print_json};
use crate::{build_posed_grid as build_grid, load_posed_log};

/// Arguments of `mapmerge render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    /// A ROS map_server map (YAML) to draw underneath.
    #[arg(long, conflicts_with = "log")]
    pub map: Option<PathBuf>,
    /// Or a CARMEN log to build the grid from (with `--poses`, as `mapmerge grid`).
    #[arg(long)]
    pub log: Option<PathBuf>,
    /// Poses for `--log` (TUM or CARMEN), one per scan.
    #[arg(long, requires = "log")]
    pub poses: Option<PathBuf>,
    /// Cell side (m) when building from `--log` or when there is no grid at all.
    #[arg(long, default_value_t = 0.05)]
    pub resolution: f64,
    /// 2D pose graphs (g2o/TORO) to overlay: vertices and edges coloured by session, merge
    /// edges highlighted. Repeatable.
    #[arg(long)]
    pub graph: Vec<PathBuf>,
    /// TUM trajectories to overlay, each in its own colour. Repeatable.
    #[arg(long)]
    pub trajectory: Vec<PathBuf>,
    /// Pixels per cell.
    #[arg(long, default_value_t = 1)]
    pub scale: usize,
    /// Three colours (free / occupied / unknown) instead of probability shades.
    #[arg(long)]
    pub classes: bool,
    /// Output PNG.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Print one JSON summary instead of text.
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
struct RenderReport<'a> {
    png: &'a Path,
    width_px: usize,
    height_px: usize,
    metres_per_pixel: f64,
    graphs: usize,
    trajectories: usize,
}

/// Runs `mapmerge render`.
pub fn run(args: &RenderArgs) -> anyhow::Result<ExitCode> {
    crate::check_output_file(&args.output)?;
    check_resolution(args.resolution)?;
    if !(1..=64).contains(&args.scale) {
        return Err(bad_input(format!(
            "--scale must be 1..=64 pixels per cell, got {}",
            args.scale
        )));
    }
    // 1. The grid underneath (or an empty one).
    let mut grid = match (&args.map, &args.log) {
        (Some(map), _) => mapmerge_io::read_ros_map(map)
            .and_then(|m| m.to_grid())
            .map_err(bad_file)?,
        (None, Some(log)) => {
            let posed = load_posed_log(log, args.poses.as_deref(), &crate::BagTopics::default())?;
            build_grid(
                &posed,
                args.resolution,
                &InsertParams::default(),
                !args.json,
            )?
            .0
        }
        (None, None) => OccupancyGrid::new(args.resolution)?,
    };
    // 2. Overlays, and the area they need.
    let mut graphs = Vec::new();
    for path in &args.graph {
        match load_graph(path)?.graph {
            AnyGraph::Planar(graph) => graphs.push(graph),
            AnyGraph::Spatial(_) => {
                return Err(bad_input(format!(
                    "{}: only 2D graphs can be drawn",
                    path.display()
                )))
            }
        }
    }
    let mut trajectories: Vec<Vec<Se2>> = Vec::new();
    for path in &args.trajectory {
        let poses = mapmerge_io::read_tum_planar(path).map_err(bad_file)?;
        trajectories.push(poses.into_iter().map(|(_, pose)| pose).collect());
    }
    let overlay_points: Vec<Point2> = graphs
        .iter()
        .flat_map(|g| g.vertices().map(|(_, v)| v.pose.translation()))
        .chain(trajectories.iter().flatten().map(Se2::translation))
        .filter(|p| p.x.is_finite() && p.y.is_finite())
        .collect();
    if let Some(first) = overlay_points.first() {
        let (lo, hi) = overlay_points
            .iter()
            .fold((*first, *first), |(lo, hi), p| (lo.inf(p), hi.sup(p)));
        let margin = Point2::new(1.0, 1.0);
        let (lo, hi) = (lo - margin, hi + margin);
        if grid.geometry().is_empty() {
            // Nothing underneath: a canvas that fits the overlays (growing would add margins).
            let resolution_m = grid.resolution_m();
            let cells = (hi - lo) / resolution_m;
            grid = OccupancyGrid::with_geometry(GridGeometry {
                resolution_m,
                origin_m: lo,
                width: cells.x.ceil() as usize,
                height: cells.y.ceil() as usize,
            })?;
        } else {
            grid.grow_to_contain(&lo, &hi)?;
        }
    }
    // 3. Draw.
    let style = PictureStyle {
        pixels_per_cell: args.scale,
        classes: args.classes.then(ClassThresholds::default),
    };
    let mut picture = Picture::of_grid(&grid, &style);
    for graph in &graphs {
        picture.draw_graph(graph, &GraphStyle::default());
    }
    for (k, trajectory) in trajectories.iter().enumerate() {
        picture.draw_trajectory(trajectory, session_color(k as u64 + 3), 1.5);
    }
    picture
        .save_png(&args.output)
        .map_err(crate::writing(&args.output))?;
    let (width_px, height_px) = picture.size_px();
    let report = RenderReport {
        png: &args.output,
        width_px,
        height_px,
        metres_per_pixel: grid.resolution_m() / args.scale as f64,
        graphs: graphs.len(),
        trajectories: trajectories.len(),
    };
    if args.json {
        print_json(&report)?;
    } else {
        println!(
            "wrote {} ({width_px} × {height_px} px)",
            args.output.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}
