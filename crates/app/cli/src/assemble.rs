//! `mapmerge assemble SEGMENT... -o OUT`: assembles segments without initial guesses, in any
//! order (AutoMerge, `mapmerge-assemble`). A 2D segment is a CARMEN log named by its file
//! stem; its trajectory comes from the SLAM front-end on its scans and odometry (or the
//! odometry alone, `--trajectory odometry`). A 3D segment is a KITTI-style folder
//! (`velodyne/*.bin` + `poses.txt`, optional `calib.txt`) named by the folder: described in 3D,
//! verified and optimised in the ground plane (`mapmerge_assemble::three_d`); one assembly
//! takes one kind. Writes `OUT/groups.json`, `OUT/loops.jsonl`, `OUT/poses/STEM.tum` (every
//! scan's pose in its group's frame; 3D: stamps are cloud indices) and `OUT/group_NN.png`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use mapmerge_assemble::{Arrival, Assembler, GroupSolution};
use mapmerge_geometry::Se2;
use mapmerge_grid::{ClassThresholds, InsertParams, OccupancyGrid};
use mapmerge_render::{session_color, Picture, PictureStyle};
use serde::Serialize;

pub use mapmerge_jobs::{arrival_order, LoadedSegment, Order, TrajectorySource};

use crate::{
    check_resolution, load_assemble_params as load_params,
    load_segments_with_progress as load_segments, print_json,
};

#[derive(Args, Debug)]
pub struct AssembleArgs {
    /// Segments: CARMEN logs (`.log`, `.log.xz`) or ROS 2 bags (`.mcap`, `.db3`, bag
    /// directories) named by their file stems, or KITTI-style folders (3D) named by the folder.
    #[arg(required = true)]
    pub segments: Vec<PathBuf>,
    /// Topics of a ROS 2 bag.
    #[command(flatten)]
    pub topics: crate::BagTopics,
    /// Output folder.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Arrival order.
    #[arg(long, value_enum, default_value = "given")]
    pub order: Order,
    /// Seed of `--order random`.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Trajectory of each segment.
    #[arg(long, value_enum, default_value = "slam")]
    pub trajectory: TrajectorySource,
    /// Parameters (JSON, `mapmerge_assemble::AssembleParams`; missing fields default).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Cell size of the group pictures (m).
    #[arg(long, default_value_t = 0.05)]
    pub resolution: f64,
    /// Skip the pictures.
    #[arg(long)]
    pub no_pictures: bool,
    /// Print one JSON summary instead of text.
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
struct GroupLine<'a> {
    segments: &'a [String],
}

#[derive(Serialize)]
struct GroupReport {
    segments: Vec<String>,
    scans: usize,
    loop_edges: usize,
    iterations: usize,
    numerical_failure: bool,
    picture: Option<PathBuf>,
}

#[derive(Serialize)]
struct AssembleReport<'a> {
    segments: usize,
    order: Order,
    seed: u64,
    trajectory: TrajectorySource,
    arrivals: &'a [Arrival],
    groups: Vec<GroupReport>,
    loops: usize,
    pairs_associated: usize,
    trajectory_secs: f64,
    association_secs: f64,
    optimisation_secs: f64,
    output: &'a Path,
}

pub fn run(args: &AssembleArgs) -> anyhow::Result<()> {
    crate::check_output_dir(&args.output)?;
    check_resolution(args.resolution)?;
    let started = Instant::now();
    let loaded = load_segments(&args.segments, &args.topics, args.trajectory, !args.json)?;
    let spatial = loaded
        .iter()
        .any(|s| matches!(s, LoadedSegment::Spatial(_)));
    let params = load_params(args.config.as_deref(), spatial)?;
    let trajectory_secs = started.elapsed().as_secs_f64();
    let order = arrival_order(loaded.len(), args.order, args.seed);
    let assembled = mapmerge_jobs::assemble(loaded, params, &order, |k, arrival| {
        if !args.json {
            eprintln!(
                "[{}/{}] {}: {} submaps, {} pairs, connected to [{}], {} groups ({:.1} s)",
                k + 1,
                order.len(),
                arrival.segment,
                arrival.submaps,
                arrival.pairs,
                arrival.connected.join(", "),
                arrival.groups,
                arrival.prepare_secs + arrival.association_secs + arrival.grouping_secs
            );
        }
    })
    .map_err(crate::job_error)?;
    let out = &args.output;
    let poses_dir = out.join("poses");
    std::fs::create_dir_all(&poses_dir).map_err(crate::writing(&poses_dir))?;
    // groups.json and loops.jsonl.
    let group_lines: Vec<GroupLine> = assembled
        .groups
        .iter()
        .map(|g| GroupLine { segments: g })
        .collect();
    let groups_path = out.join("groups.json");
    std::fs::write(
        &groups_path,
        serde_json::to_string_pretty(&group_lines)? + "\n",
    )
    .map_err(crate::writing(&groups_path))?;
    let loop_lines = assembled.loop_lines();
    let mut loops_text = String::new();
    for line in &loop_lines {
        loops_text.push_str(&serde_json::to_string(line)?);
        loops_text.push('\n');
    }
    let loops_path = out.join("loops.jsonl");
    std::fs::write(&loops_path, loops_text).map_err(crate::writing(&loops_path))?;
    // Poses and pictures per group.
    let assembler = &assembled.assembler;
    let mut reports = Vec::with_capacity(assembled.solutions.len());
    for (g, solution) in assembled.solutions.iter().enumerate() {
        for (name, poses) in &solution.scan_poses {
            let Some((segment, _)) = assembler.segment(name) else {
                continue;
            };
            let stamped: Vec<(f64, Se2)> = segment
                .stamps_secs
                .iter()
                .copied()
                .zip(poses.iter().copied())
                .collect();
            let path = poses_dir.join(format!("{name}.tum"));
            mapmerge_io::write_tum_planar(&path, &stamped).map_err(crate::writing(&path))?;
        }
        let picture = if args.no_pictures {
            None
        } else {
            let path = out.join(format!("group_{g:02}.png"));
            draw_group(solution, assembler, args.resolution, &path)?;
            Some(path)
        };
        reports.push(GroupReport {
            scans: solution.scan_poses.values().map(Vec::len).sum(),
            segments: solution.segments.clone(),
            loop_edges: solution.loop_edges,
            iterations: solution.iterations,
            numerical_failure: solution.numerical_failure,
            picture,
        });
    }
    let pairs_associated = assembled.pairs_associated();
    if args.json {
        print_json(&AssembleReport {
            segments: assembled.arrivals.len(),
            order: args.order,
            seed: args.seed,
            trajectory: args.trajectory,
            arrivals: &assembled.arrivals,
            groups: reports,
            loops: loop_lines.len(),
            pairs_associated,
            trajectory_secs,
            association_secs: assembled.association_secs,
            optimisation_secs: assembled.optimisation_secs,
            output: out,
        })?;
    } else {
        println!(
            "{} segments -> {} groups, {} loop edges over {} pairs ({:.1} s trajectories, {:.1} s association, {:.1} s optimisation) -> {}",
            assembled.arrivals.len(),
            reports.len(),
            loop_lines.len(),
            pairs_associated,
            trajectory_secs,
            assembled.association_secs,
            assembled.optimisation_secs,
            out.display()
        );
        for (g, r) in reports.iter().enumerate() {
            println!("  group {g}: {}", r.segments.join(", "));
        }
    }
    Ok(())
}

/// The group's map from every scan at its assembled pose, trajectories coloured by segment.
fn draw_group(
    solution: &GroupSolution,
    assembler: &Assembler,
    resolution_m: f64,
    path: &Path,
) -> anyhow::Result<()> {
    let scans = solution.scan_poses.iter().flat_map(|(name, poses)| {
        assembler
            .segment(name)
            .into_iter()
            .flat_map(move |(segment, _)| poses.iter().copied().zip(segment.scans.iter()))
    });
    let (grid, _) = OccupancyGrid::from_scans(resolution_m, scans, &InsertParams::default())
        .context("building the group's grid")?;
    let style = PictureStyle {
        pixels_per_cell: 1,
        classes: Some(ClassThresholds::default()),
    };
    let mut picture = Picture::of_grid(&grid, &style);
    for (k, poses) in solution.scan_poses.values().enumerate() {
        picture.draw_trajectory(poses, session_color(k as u64), 1.0);
    }
    picture.save_png(path).map_err(crate::writing(path))?;
    Ok(())
}
