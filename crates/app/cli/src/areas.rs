//! `mapmerge areas` and `mapmerge route`: the map manager of Ehlers et al. on one log or one
//! simulated session (`mapmerge_areas`): door passings split it into areas, each area is
//! mapped by the SLAM pipeline with its environment's preset, and the link points at the
//! doors join the maps into a hybrid map; `route` finds the shortest route between two
//! poses in any two maps of it.

use std::path::PathBuf;

use clap::Args;
use mapmerge_areas::ManagerParams;
use mapmerge_jobs::{AreasOptions, AreasProgress};
use mapmerge_lab::sim::simulated_sessions;
use mapmerge_scan::LaserLog;

use crate::{bad_input, job_error, print_json};

/// Arguments of `mapmerge areas`.
#[derive(Args, Debug)]
pub struct AreasArgs {
    /// CARMEN laser logs (`.xz` accepted) or ROS 2 bags, one session each, in order: their scans' odometry
    /// poses drive door detection and each area's SLAM. A later session is placed in the
    /// first one's frame once it passes a door seen before. With `--store` and no logs, the
    /// stored areas are written out.
    pub logs: Vec<PathBuf>,
    /// Topics of a ROS 2 bag.
    #[command(flatten)]
    pub topics: crate::BagTopics,
    /// Instead of logs, the sessions of a simulated world (a preset of `mapmerge sim`),
    /// without kidnaps.
    #[arg(long, conflicts_with = "logs")]
    pub sim: Option<String>,
    /// Seed of `--sim`.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Sessions of `--sim`.
    #[arg(long, default_value_t = 1)]
    pub sessions: usize,
    /// Simulate only this session of the world (its changes, route and noise as in the
    /// whole simulation): one session per run, as a robot lives with `--store`.
    #[arg(long, requires = "sim", conflicts_with = "sessions")]
    pub session_index: Option<usize>,
    /// Robot time of each `--sim` session (s).
    #[arg(long, default_value_t = 120.0)]
    pub duration: f64,
    /// Cell side of the maps (m).
    #[arg(long, default_value_t = 0.05)]
    pub resolution: f64,
    /// Map-manager parameters as JSON (any subset of `mapmerge_areas::ManagerParams`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Output folder: areas.json, hybrid.json, tracking.json, overview.png and area_K/
    /// (graph.g2o, map.yaml + map.pgm, map.png, trajectory.tum) for each area.
    #[arg(short, long)]
    pub output: PathBuf,
    /// The lifelong store (created when missing): its newest version's sessions come first,
    /// this run's sessions are added after them, and the result is committed as a new
    /// version.
    #[arg(long)]
    pub store: Option<PathBuf>,
    /// Print one JSON summary instead of text.
    #[arg(long)]
    pub json: bool,
}

/// The sessions `areas` runs on, with their names.
fn input_logs(args: &AreasArgs) -> anyhow::Result<Vec<(String, LaserLog)>> {
    match (&args.logs[..], &args.sim) {
        ([], None) if args.store.is_some() => Ok(Vec::new()),
        (logs, None) if !logs.is_empty() => logs
            .iter()
            .map(|path| {
                let log = crate::read_log(path, &args.topics)?;
                Ok((path.display().to_string(), log))
            })
            .collect(),
        // The map manager tracks the robot; a kidnap is another problem (the atlas's).
        ([], Some(world)) => Ok(simulated_sessions(
            world,
            args.sessions,
            args.duration,
            args.seed,
            args.session_index,
            false,
        )?
        .into_iter()
        .map(|s| {
            let name = format!("sim {world} seed {} session {}", args.seed, s.index);
            (name, s.log)
        })
        .collect()),
        _ => Err(bad_input("give LOG..., --sim WORLD or --store FILE")),
    }
}

/// Runs `mapmerge areas`.
pub fn run(args: &AreasArgs) -> anyhow::Result<std::process::ExitCode> {
    crate::check_output_dir(&args.output)?;
    crate::check_resolution(args.resolution)?;
    let options = AreasOptions {
        params: crate::read_config::<ManagerParams>(args.config.as_deref())?,
        resolution_m: args.resolution,
        store: args.store.clone(),
    };
    let logs = input_logs(args)?;
    let mut bar = None;
    let report = mapmerge_jobs::manage_areas(logs, &options, &args.output, |step| match step {
        AreasProgress::Session { scans } => {
            bar = Some(crate::progress_bar(scans, "scans", "areas", !args.json));
        }
        AreasProgress::Mapped { scans } => {
            if let Some(bar) = &bar {
                bar.inc(scans as u64);
            }
        }
        AreasProgress::SessionDone => {
            if let Some(bar) = bar.take() {
                bar.finish_and_clear();
            }
        }
    })
    .map_err(job_error)?;
    let stored_sessions = report.stored_sessions;
    let committed_version = report.committed_version;
    if args.json {
        print_json(&report)?;
    } else {
        println!(
            "{} sessions ({} placed), {} scans: {} door passings, {} topological loop closures, {} areas ({} indoor, {} large), {} link points; wrote {} in {:.1} s",
            report.sessions,
            report.sessions_placed,
            report.scans,
            report.door_passings,
            report.closures,
            report.areas,
            report.indoor,
            report.large,
            report.link_points,
            args.output.display(),
            report.seconds
        );
        if let Some(path) = &args.store {
            match committed_version {
                Some(version) => println!(
                    "store {}: {stored_sessions} sessions continued, committed version {version}",
                    path.display()
                ),
                None => println!(
                    "store {}: {stored_sessions} sessions written out, nothing committed",
                    path.display()
                ),
            }
        }
    }
    Ok(std::process::ExitCode::SUCCESS)
}

/// Arguments of `mapmerge route`.
#[derive(Args, Debug)]
pub struct RouteArgs {
    /// A folder written by `mapmerge areas` (its hybrid.json).
    pub dir: PathBuf,
    /// Start: `AREA:x,y` (a position in that area's frame, m).
    #[arg(long)]
    pub from: String,
    /// Goal: `AREA:x,y`.
    #[arg(long)]
    pub to: String,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `mapmerge route`.
pub fn route(args: &RouteArgs) -> anyhow::Result<std::process::ExitCode> {
    let route = mapmerge_jobs::route_between(&args.dir, &args.from, &args.to).map_err(job_error)?;
    let Some(found) = route else {
        let area = |text: &str| mapmerge_jobs::parse_area_position(text).map(|(area, _)| area);
        let (start_area, goal_area) = (
            area(&args.from).map_err(job_error)?,
            area(&args.to).map_err(job_error)?,
        );
        if args.json {
            print_json(&serde_json::json!({"route": null}))?;
        } else {
            println!(
                "no route: no chain of link points joins area {start_area} to area {goal_area}"
            );
        }
        return Ok(std::process::ExitCode::from(3));
    };
    if args.json {
        print_json(&serde_json::json!({"route": found}))?;
    } else {
        let areas: Vec<String> = found.areas.iter().map(|a| a.to_string()).collect();
        let links: Vec<String> = found.link_points.iter().map(|l| l.to_string()).collect();
        println!(
            "{:.2} m through areas {} via link points [{}]",
            found.length_m,
            areas.join(" → "),
            links.join(", ")
        );
    }
    Ok(std::process::ExitCode::SUCCESS)
}
