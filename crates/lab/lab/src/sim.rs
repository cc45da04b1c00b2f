//! `mapmerge sim`: a simulated multi-session data set written to a folder.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{ClassThresholds, OccupancyGrid};
use mapmerge_io::{MapMode, RosMap};
use mapmerge_render::{Picture, PictureStyle, Rgb};
use mapmerge_scan::LaserLog;
use mapmerge_sim::{
    simulate, simulate_session_alone, Dataset, SessionData, SimParams, SlipSchedule, World,
    WorldPreset,
};
use serde::Serialize;

use crate::{bad_input, check_resolution, print_json};

/// Arguments of `mapmerge sim`.
#[derive(Args, Debug)]
pub struct SimArgs {
    /// World preset: office, office-aliased, corridor-loop, warehouse, symmetric-hall.
    #[arg(long, default_value = "office")]
    pub world: String,
    /// Number of sessions (session 0 sees the generated world, later ones a changed one).
    #[arg(long, default_value_t = 3)]
    pub sessions: usize,
    /// Seed: the same seed gives the same data set, bit for bit.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Robot time per session (s).
    #[arg(long, default_value_t = 180.0)]
    pub duration: f64,
    /// Lidar beams per scan (over 360°).
    #[arg(long, default_value_t = 360)]
    pub beams: usize,
    /// Lidar maximum range (m).
    #[arg(long, default_value_t = 30.0)]
    pub range_max: f32,
    /// Lidar range noise, standard deviation (m).
    #[arg(long, default_value_t = 0.015)]
    pub range_sigma: f64,
    /// Wheel-slip events per minute of robot time.
    #[arg(long, default_value_t = 0.5)]
    pub slip_rate: f64,
    /// Most kidnaps per session (each happens with `--kidnap-probability`).
    #[arg(long, default_value_t = 1)]
    pub kidnaps: usize,
    /// Probability of each possible kidnap.
    #[arg(long, default_value_t = 0.5)]
    pub kidnap_probability: f64,
    /// Cell side of the ground-truth world maps (m).
    #[arg(long, default_value_t = 0.05)]
    pub resolution: f64,
    /// Write the logs and map images xz-compressed (`session_K.log.xz`, about 6× smaller;
    /// `world.pgm.xz` while the YAML names `world.pgm`: run `xz -d` before ROS tools read it).
    #[arg(long)]
    pub compress: bool,
    /// Skip the PNG pictures (faster).
    #[arg(long)]
    pub no_pictures: bool,
    /// Also write each session as a ROS 2 bag, `session_K.mcap` or `session_K.db3` (`/scan`,
    /// `/odom`, `/tf_static`; see `mapmerge convert`).
    #[arg(long, value_parser = ["mcap", "db3"])]
    pub bag: Option<String>,
    /// Also write `corrected.log`: every session's scans at their true poses (world frame),
    /// one session after another, stamps shifted to increase — a corrected log, e.g. for
    /// `eval make-merge-cases --split-at-jumps-m 1` (its segments then end at the jumps
    /// between sessions and at kidnaps).
    #[arg(long)]
    pub corrected_log: bool,
    /// Output folder (created if missing).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Print one JSON summary instead of text.
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
struct SimReport<'a> {
    world: &'a str,
    seed: u64,
    sessions: usize,
    robot_secs: f64,
    scans: usize,
    beams: usize,
    kidnaps: usize,
    slips: usize,
    world_changes: usize,
    simulate_secs: f64,
    write_secs: f64,
    output: &'a Path,
}

/// Per-session facts for `dataset.json` (the logs and trajectories are in their own files).
#[derive(Serialize)]
struct SessionSummary<'a> {
    index: usize,
    log: String,
    /// `--bag`'s file.
    #[serde(skip_serializing_if = "Option::is_none")]
    bag: Option<String>,
    truth: String,
    world_map: String,
    start_room: String,
    scans: usize,
    odometry_messages: usize,
    kidnaps: &'a [mapmerge_sim::Kidnap],
    slips: &'a [mapmerge_sim::SlipEvent],
    world_changes: &'a [mapmerge_sim::WorldChange],
    motion: &'a mapmerge_sim::MotionInfo,
    /// Every passing of a door, for scoring door detection.
    door_passings: Vec<mapmerge_sim::DoorPassing>,
}

/// A door of the world, for scoring door detection (world frame).
#[derive(Serialize)]
struct DoorSummary {
    id: u32,
    x: f64,
    y: f64,
    width_m: f64,
}

#[derive(Serialize)]
struct DatasetSummary<'a> {
    world: &'a str,
    seed: u64,
    params: &'a SimParams,
    world_map: &'static str,
    /// Every door of session 0's world (later sessions close some; none moves).
    doors: Vec<DoorSummary>,
    /// `--corrected-log`'s file.
    #[serde(skip_serializing_if = "Option::is_none")]
    corrected_log: Option<String>,
    sessions: Vec<SessionSummary<'a>>,
}

/// The sessions of a simulated world (`preset`, `sessions` of `duration_secs` each) that the
/// product's commands run on with `--sim`; with `session_index`, that session alone (its
/// changes, route and noise as in the whole simulation), as a robot lives with a store.
/// Without `kidnaps` the robot is never kidnapped.
pub fn simulated_sessions(
    preset: &str,
    sessions: usize,
    duration_secs: f64,
    seed: u64,
    session_index: Option<usize>,
    kidnaps: bool,
) -> anyhow::Result<Vec<SessionData>> {
    let mut params = SimParams::default()
        .with_preset_name(preset)
        .map_err(bad_input)?
        .with_sessions(sessions)
        .with_duration_secs(duration_secs);
    if !kidnaps {
        params.kidnap.max_per_session = 0;
    }
    Ok(match session_index {
        Some(index) => vec![simulate_session_alone(&params, seed, index).map_err(bad_input)?],
        None => simulate(&params, seed).map_err(bad_input)?.sessions,
    })
}

/// Runs `mapmerge sim`.
pub fn run(args: &SimArgs) -> anyhow::Result<ExitCode> {
    let params = params_of(args)?;
    let started = Instant::now();
    let dataset = simulate(&params, args.seed).map_err(bad_input)?;
    let simulate_secs = started.elapsed().as_secs_f64();
    let started = Instant::now();
    write_dataset(&dataset, args)?;
    let write_secs = started.elapsed().as_secs_f64();
    let sessions = &dataset.sessions;
    let report = SimReport {
        world: &dataset.world_name,
        seed: dataset.seed,
        sessions: sessions.len(),
        robot_secs: params.duration_secs * sessions.len() as f64,
        scans: sessions.iter().map(|s| s.log.scans.len()).sum(),
        beams: sessions
            .iter()
            .flat_map(|s| s.log.scans.iter().map(|r| r.scan.len()))
            .sum(),
        kidnaps: sessions.iter().map(|s| s.kidnaps.len()).sum(),
        slips: sessions.iter().map(|s| s.slips.len()).sum(),
        world_changes: sessions.iter().map(|s| s.world_changes.len()).sum(),
        simulate_secs,
        write_secs,
        output: &args.output,
    };
    if args.json {
        print_json(&report)?;
    } else {
        println!(
            "{}: {} sessions, {} scans, {} kidnaps, {} slips, {} world changes; simulated in {:.2} s, wrote {} in {:.2} s",
            report.world,
            report.sessions,
            report.scans,
            report.kidnaps,
            report.slips,
            report.world_changes,
            simulate_secs,
            args.output.display(),
            write_secs
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// The simulator's parameters from the arguments.
fn params_of(args: &SimArgs) -> anyhow::Result<SimParams> {
    let preset = WorldPreset::from_name(&args.world).map_err(bad_input)?;
    let mut params = SimParams::default()
        .with_preset(preset)
        .with_sessions(args.sessions)
        .with_duration_secs(args.duration);
    params.lidar.beam_count = args.beams;
    params.lidar.range_max_m = args.range_max;
    params.lidar.range_sigma_m = args.range_sigma;
    params.odometry.slip_schedule = SlipSchedule::by_time(args.slip_rate);
    params.kidnap.max_per_session = args.kidnaps;
    params.kidnap.probability = args.kidnap_probability;
    check_resolution(args.resolution)?;
    Ok(params)
}

/// Writes every file of the data set (see docs/formats.md, "Simulated data sets").
fn write_dataset(dataset: &Dataset, args: &SimArgs) -> anyhow::Result<()> {
    let dir = &args.output;
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let world_grid = write_world(&dataset.world, &dir.join("world.yaml"), args)?;
    let mut summaries = Vec::new();
    for session in &dataset.sessions {
        let stem = format!("session_{}", session.index);
        let log = format!("{stem}.log{}", if args.compress { ".xz" } else { "" });
        let truth = format!("{stem}.truth.tum");
        mapmerge_io::write_carmen(&dir.join(&log), &session.log)?;
        let bag = match &args.bag {
            Some(extension) => {
                let name = format!("{stem}.{extension}");
                let params = mapmerge_rosbag::BagWriteParams::default();
                mapmerge_rosbag::write_bag(&dir.join(&name), &session.log, &params)?;
                Some(name)
            }
            None => None,
        };
        mapmerge_io::write_tum_planar(&dir.join(&truth), &session.truth)?;
        // A changed world gets its own map, so detectors can be scored against it.
        let world_map = if session.world_changes.is_empty() {
            "world.yaml".to_owned()
        } else {
            let name = format!("{stem}.world.yaml");
            write_world(&session.world, &dir.join(&name), args)?;
            name
        };
        if !args.no_pictures {
            let grid = if session.world_changes.is_empty() {
                world_grid.clone()
            } else {
                session.world.to_grid(args.resolution).map_err(bad_input)?
            };
            session_picture(&grid, session).save_png(&dir.join(format!("{stem}.png")))?;
        }
        let start_room = session
            .world
            .room(session.start_room)
            .map(|room| room.name.clone())
            .unwrap_or_default();
        summaries.push(SessionSummary {
            index: session.index,
            log,
            bag,
            truth,
            world_map,
            start_room,
            scans: session.log.scans.len(),
            odometry_messages: session.log.odometry.len(),
            kidnaps: &session.kidnaps,
            slips: &session.slips,
            world_changes: &session.world_changes,
            motion: &session.motion,
            door_passings: session.door_passings(),
        });
    }
    let corrected_log = if args.corrected_log {
        let name = format!("corrected.log{}", if args.compress { ".xz" } else { "" });
        mapmerge_io::write_carmen(&dir.join(&name), &corrected_log(&dataset.sessions))?;
        Some(name)
    } else {
        None
    };
    let summary = DatasetSummary {
        world: &dataset.world_name,
        seed: dataset.seed,
        params: &dataset.params,
        world_map: "world.yaml",
        doors: dataset
            .world
            .doors
            .iter()
            .map(|door| DoorSummary {
                id: door.id.0,
                x: door.center_m.x,
                y: door.center_m.y,
                width_m: door.width_m,
            })
            .collect(),
        corrected_log,
        sessions: summaries,
    };
    let json = serde_json::to_string_pretty(&summary)?;
    std::fs::write(dir.join("dataset.json"), json + "\n")
        .with_context(|| format!("writing {}", dir.join("dataset.json").display()))?;
    Ok(())
}

/// The sessions' scans at their true poses, in session order, as one corrected log (no
/// odometry messages); each session's stamps shifted to start 1 s after the previous one's
/// last scan.
fn corrected_log(sessions: &[SessionData]) -> LaserLog {
    let mut log = LaserLog {
        params: sessions
            .first()
            .map(|s| s.log.params.clone())
            .unwrap_or_default(),
        ..LaserLog::default()
    };
    let mut next_start_secs = 0.0;
    for session in sessions {
        let first_secs = session.log.scans.first().map_or(0.0, |r| r.stamp_secs);
        let shift_secs = next_start_secs - first_secs;
        for (record, (_, world_from_robot)) in session.log.scans.iter().zip(&session.truth) {
            let mut record = record.clone();
            record.stamp_secs += shift_secs;
            record.odom_from_robot = Some(*world_from_robot);
            next_start_secs = record.stamp_secs + 1.0;
            log.scans.push(record);
        }
    }
    log
}

/// Rasterises `world` and writes it as a map_server map (the PGM xz-compressed with
/// `--compress`); returns the grid.
fn write_world(world: &World, yaml: &Path, args: &SimArgs) -> anyhow::Result<OccupancyGrid> {
    let grid = world.to_grid(args.resolution).map_err(bad_input)?;
    let map = RosMap::from_grid(&grid, MapMode::Trinary, &ClassThresholds::default());
    mapmerge_io::write_ros_map_with(yaml, &map, args.compress)?;
    Ok(grid)
}

/// The session's world with the true path (red), the odometry path started at the true start
/// pose (blue; its drift and the kidnaps it does not see) and each kidnap's jump (magenta).
fn session_picture(grid: &OccupancyGrid, session: &SessionData) -> Picture {
    let style = PictureStyle {
        pixels_per_cell: 1,
        classes: Some(ClassThresholds::default()),
    };
    let mut picture = Picture::of_grid(grid, &style);
    let truth: Vec<Se2> = session.truth.iter().map(|(_, pose)| *pose).collect();
    let odometry: Vec<Se2> = session
        .log
        .scans
        .iter()
        .filter_map(|record| record.odom_from_robot)
        .collect();
    if let (Some(world_from_start), Some(odom_from_start)) = (truth.first(), odometry.first()) {
        let world_from_odom = world_from_start.compose(&odom_from_start.inverse());
        let drifting: Vec<Se2> = odometry
            .iter()
            .map(|p| world_from_odom.compose(p))
            .collect();
        picture.draw_trajectory(&drifting, Rgb([40, 90, 220]), 1.0);
    }
    // The true path, broken at kidnaps so the jump is not drawn as driving.
    let mut start = 0;
    for kidnap in &session.kidnaps {
        let end = kidnap.scan_index.min(truth.len());
        picture.draw_trajectory(truth.get(start..end).unwrap_or_default(), Rgb::RED, 1.5);
        picture.draw_line(
            &kidnap.from.translation(),
            &kidnap.to.translation(),
            Rgb::MAGENTA,
            2.0,
        );
        start = end;
    }
    picture.draw_trajectory(truth.get(start..).unwrap_or_default(), Rgb::RED, 1.5);
    picture
}
