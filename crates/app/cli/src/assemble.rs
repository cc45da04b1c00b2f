//! `mapmerge assemble SEGMENT... -o OUT`: assembles segments without initial guesses, in any
//! order (AutoMerge, `mapmerge-assemble`). A 2D segment is a CARMEN log named by its file
//! stem; its trajectory comes from the SLAM front-end on its scans and odometry (or the
//! odometry alone, `--trajectory odometry`). A 3D segment is a KITTI-style folder
//! (`velodyne/*.bin` + `poses.txt`, optional `calib.txt`) named by the folder: described in 3D,
//! verified and optimised in the ground plane (`mapmerge_assemble::three_d`); one assembly
//! takes one kind. Writes `OUT/groups.json`, `OUT/loops.jsonl`, `OUT/poses/STEM.tum` (every
//! scan's pose in its group's frame; 3D: stamps are cloud indices) and `OUT/group_NN.png`.

use std::collections::BTreeMap;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use clap::{Args, ValueEnum};
use mapmerge_assemble::{
    load_kitti_folder, segment3_from_clouds, solve_group, Arrival, AssembleParams, Assembler, GroundSlice, GroupSolution,
    KittiFolderOptions, RingSpectrum3Params, RingSpectrumDescriptor3, Segment, Segment3,
    SubmapParams,
};
use mapmerge_engine::{run_slam, EngineParams};
use mapmerge_geometry::Se2;
use mapmerge_grid::{ClassThresholds, InsertParams, OccupancyGrid};
use mapmerge_render::{session_color, Picture, PictureStyle};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;

use crate::{bad_file, bad_input, check_resolution, print_json, progress_bar};

/// Arrival order of the segments.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Order {
    /// As on the command line.
    Given,
    /// Shuffled with `--seed`.
    Random,
}

/// Where each segment's trajectory comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TrajectorySource {
    /// The project's 2D SLAM front-end on the segment's scans and odometry.
    Slam,
    /// The log's odometry as it is.
    Odometry,
}

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

/// A segment's name: a log's file stem (`crate::log_file_stem`), a folder's name.
pub fn segment_name(path: &Path) -> String {
    crate::log_file_stem(path)
}

/// A segment as read: 2D (a log with its trajectory) or 3D (a KITTI-style folder).
pub enum LoadedSegment {
    Planar(Segment),
    Spatial(Segment3),
}

/// Reads the segments (in parallel): logs or laser bags with their trajectories (one
/// front-end each), or 3D segments: KITTI-style folders, and bags of PointCloud2 with
/// odometry. Mixing 2D and 3D is bad input.
pub fn load_segments(
    paths: &[PathBuf],
    topics: &crate::BagTopics,
    source: TrajectorySource,
    progress: bool,
) -> anyhow::Result<Vec<LoadedSegment>> {
    let is_kitti_folder = |p: &Path| p.is_dir() && !mapmerge_rosbag::is_bag(p);
    let mut spatial = Vec::with_capacity(paths.len());
    for path in paths {
        spatial.push(is_kitti_folder(path) || is_cloud_bag(path)?);
    }
    if let Some(k) = spatial.iter().position(|&s| s).filter(|_| spatial.contains(&false)) {
        return Err(bad_input(format!(
            "{}: a 3D segment among 2D ones; segments are either laser logs or bags (2D), or \
             KITTI-style folders and PointCloud2 bags (3D), not both",
            paths[k].display()
        )));
    }
    let mut names = BTreeMap::new();
    for path in paths {
        if let Some(other) = names.insert(segment_name(path), path) {
            return Err(bad_input(format!(
                "{} and {} have the same name `{}`",
                other.display(),
                path.display(),
                segment_name(path)
            )));
        }
    }
    let bar = progress_bar(paths.len(), "segments", "trajectories", progress);
    let loaded: Vec<anyhow::Result<LoadedSegment>> = paths
        .par_iter()
        .zip(&spatial)
        .map(|(path, &spatial)| {
            if spatial {
                let segment = if is_kitti_folder(path) {
                    load_kitti_folder(path, &KittiFolderOptions::default())
                } else {
                    let session =
                        mapmerge_rosbag::read_cloud_session(path, None, topics.odom_topic.as_deref())
                            .map_err(bad_file)?;
                    let clouds: Vec<_> = session.clouds.into_iter().map(|c| c.points).collect();
                    segment3_from_clouds(
                        segment_name(path),
                        &session.odom_from_sensor,
                        &clouds,
                        &KittiFolderOptions::default(),
                    )
                }
                .map_err(|e| bad_input(e.to_string()))?;
                bar.inc(1);
                return Ok(LoadedSegment::Spatial(segment));
            }
            let log = crate::read_log(path, topics)?;
            if log.scans.is_empty() {
                return Err(bad_input(format!("{}: no laser scans", path.display())));
            }
            let name = segment_name(path);
            let segment = match source {
                TrajectorySource::Odometry => Segment::from_log_odometry(name, &log),
                TrajectorySource::Slam => {
                    let run = run_slam(&log, EngineParams::default(), |_| {})
                        .map_err(|e| bad_input(format!("{}: {e}", path.display())))?;
                    Segment::from_log(name, &log, &run.trajectory)
                }
            }
            .map_err(|e| bad_input(format!("{}: {e}", path.display())))?;
            bar.inc(1);
            Ok(LoadedSegment::Planar(segment))
        })
        .collect();
    bar.finish_and_clear();
    loaded.into_iter().collect()
}

/// True when `path` is a bag of PointCloud2 without LaserScan (a 3D segment).
fn is_cloud_bag(path: &Path) -> anyhow::Result<bool> {
    if !mapmerge_rosbag::is_bag(path) {
        return Ok(false);
    }
    let topics = mapmerge_rosbag::list_topics(path).map_err(bad_file)?;
    let has = |message_type: &str| topics.iter().any(|t| t.message_type == message_type);
    Ok(has(mapmerge_rosbag::POINT_CLOUD2_TYPE) && !has(mapmerge_rosbag::LASER_SCAN_TYPE))
}

/// Reads `--config`; without one, 3D segments get the paper's outdoor submaps (5 m / 50 m).
pub fn load_params(config: Option<&Path>, spatial: bool) -> anyhow::Result<AssembleParams> {
    match config {
        None if spatial => {
            let submaps = SubmapParams::outdoor();
            let mut params = AssembleParams::default();
            params.descriptor.max_radius_m = submaps.radius_m;
            params.submaps = submaps;
            Ok(params)
        }
        config => crate::read_config(config),
    }
}

/// The arrival order: indices into `count` segments.
pub fn arrival_order(count: usize, order: Order, seed: u64) -> Vec<usize> {
    let mut indices: Vec<usize> = (0..count).collect();
    if order == Order::Random {
        indices.shuffle(&mut ChaCha8Rng::seed_from_u64(seed));
    }
    indices
}

/// One line of `loops.jsonl`.
#[derive(Serialize)]
struct LoopLine<'a> {
    from: ScanRef<'a>,
    to: ScanRef<'a>,
    transform: [f64; 3],
    score: f64,
}

#[derive(Serialize)]
struct ScanRef<'a> {
    segment: &'a str,
    scan: usize,
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
    check_resolution(args.resolution)?;
    let started = Instant::now();
    let mut loaded = load_segments(&args.segments, &args.topics, args.trajectory, !args.json)?;
    let spatial = loaded
        .iter()
        .any(|s| matches!(s, LoadedSegment::Spatial(_)));
    let params = load_params(args.config.as_deref(), spatial)?;
    let trajectory_secs = started.elapsed().as_secs_f64();
    let descriptor3 = RingSpectrumDescriptor3::new(&RingSpectrum3Params {
        max_radius_m: params.submaps.radius_m,
        ..RingSpectrum3Params::default()
    });
    let mut assembler = Assembler::new(params).map_err(|e| bad_input(e.to_string()))?;
    let order = arrival_order(loaded.len(), args.order, args.seed);
    let mut slots: Vec<Option<LoadedSegment>> = loaded.drain(..).map(Some).collect();
    let started = Instant::now();
    let mut arrivals = Vec::with_capacity(order.len());
    for (k, &i) in order.iter().enumerate() {
        let Some(segment) = slots.get_mut(i).and_then(Option::take) else {
            continue;
        };
        let arrival = match segment {
            LoadedSegment::Planar(segment) => assembler.add_segment(segment)?,
            LoadedSegment::Spatial(segment) => assembler.add_segment_3d(
                &segment,
                &descriptor3,
                &GroundSlice::default(),
                &BTreeMap::new(),
            )?,
        };
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
        arrivals.push(arrival);
    }
    let association_secs = started.elapsed().as_secs_f64();
    let out = &args.output;
    std::fs::create_dir_all(out.join("poses"))
        .with_context(|| format!("creating {}", out.display()))?;
    // groups.json and loops.jsonl.
    let groups = assembler.groups()?;
    let group_lines: Vec<GroupLine> = groups.iter().map(|g| GroupLine { segments: g }).collect();
    std::fs::write(
        out.join("groups.json"),
        serde_json::to_string_pretty(&group_lines)? + "\n",
    )
    .with_context(|| format!("writing {}", out.join("groups.json").display()))?;
    let mut loops_file = std::io::BufWriter::new(
        std::fs::File::create(out.join("loops.jsonl"))
            .with_context(|| format!("writing {}", out.join("loops.jsonl").display()))?,
    );
    let mut loops = 0;
    for l in assembler.loops() {
        let line = LoopLine {
            from: ScanRef {
                segment: &l.from_segment,
                scan: l.from_scan,
            },
            to: ScanRef {
                segment: &l.to_segment,
                scan: l.to_scan,
            },
            transform: [
                l.from_from_to.x_m,
                l.from_from_to.y_m,
                l.from_from_to.theta_rad,
            ],
            score: l.score,
        };
        serde_json::to_writer(&mut loops_file, &line)?;
        writeln!(loops_file)?;
        loops += 1;
    }
    loops_file.flush()?;
    // One pose graph per group; poses and pictures.
    let started = Instant::now();
    let mut reports = Vec::with_capacity(groups.len());
    for (g, group) in groups.iter().enumerate() {
        let solution = solve_group(&assembler, group, &assembler.params().graph)?;
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
            mapmerge_io::write_tum_planar(
                &out.join("poses").join(format!("{name}.tum")),
                &stamped,
            )?;
        }
        let picture = if args.no_pictures {
            None
        } else {
            let path = out.join(format!("group_{g:02}.png"));
            draw_group(&solution, &assembler, args.resolution, &path)?;
            Some(path)
        };
        reports.push(GroupReport {
            scans: solution.scan_poses.values().map(Vec::len).sum(),
            segments: solution.segments,
            loop_edges: solution.loop_edges,
            iterations: solution.iterations,
            numerical_failure: solution.numerical_failure,
            picture,
        });
    }
    let optimisation_secs = started.elapsed().as_secs_f64();
    let pairs_associated = assembler
        .pairs()
        .iter()
        .filter(|(key, p)| p.weight > 0.0 && !assembler.rejected_pairs().contains(*key))
        .count();
    if args.json {
        print_json(&AssembleReport {
            segments: arrivals.len(),
            order: args.order,
            seed: args.seed,
            trajectory: args.trajectory,
            arrivals: &arrivals,
            groups: reports,
            loops,
            pairs_associated,
            trajectory_secs,
            association_secs,
            optimisation_secs,
            output: out,
        })?;
    } else {
        println!(
            "{} segments -> {} groups, {} loop edges over {} pairs ({:.1} s trajectories, {:.1} s association, {:.1} s optimisation) -> {}",
            arrivals.len(),
            reports.len(),
            loops,
            pairs_associated,
            trajectory_secs,
            association_secs,
            optimisation_secs,
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
    picture.save_png(path)?;
    Ok(())
}
