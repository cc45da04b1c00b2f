//! `mapmerge`: merge, optimise and inspect robot pose graphs.
//!
//! Exit codes: 0 success, 2 bad input (unreadable or malformed files, bad arguments),
//! 1 any other failure (including a numerical failure, after writing the last good state).

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod areas;
mod areas_eval;
mod assemble;
mod assemble_eval;
mod atlas;
mod calibrate_eval;
mod compare;
mod convert;
mod corrupt;
mod door_eval;
mod eval;
mod grid;
mod grid_merge;
mod grid_merge_eval;
mod invalid_merge_eval;
mod optimize;
mod protrusion_eval;
mod render;
mod sim;
mod simulate;
mod slam;
mod split;
mod store;

/// Merges robot maps across sessions, robots and scales; optimises pose graphs.
#[derive(Parser, Debug)]
#[command(name = "mapmerge", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Lifelong mapping over sessions (logs or a simulation): epochs, merges by place
    /// recognition, invalid-merge detection and undo; events, graphs and pictures.
    Atlas(atlas::AtlasArgs),
    /// The map manager (Ehlers et al.): one map per area, split at door passings, each built
    /// with its environment's preset, joined by link points into a topological graph.
    Areas(areas::AreasArgs),
    /// The shortest route between two poses in the maps of `mapmerge areas` (exit code 3: no
    /// route).
    Route(areas::RouteArgs),
    /// Assemble trajectory segments (CARMEN logs) without initial guesses, in any order
    /// (AutoMerge): groups, inter-segment loop edges, poses per group, pictures.
    Assemble(assemble::AssembleArgs),
    /// Optimise a pose graph (g2o or TORO, 2D or 3D; `.xz` accepted).
    Optimize(optimize::OptimizeArgs),
    /// Add random false loop closures to a graph (vertigo's pattern) for robustness tests.
    Corrupt(corrupt::CorruptArgs),
    /// Compare two graphs' trajectories (same vertex ids): ATE after optional alignment.
    Compare(compare::CompareArgs),
    /// Generate a synthetic pose graph with known ground truth (Manhattan world).
    #[command(name = "sim-graph", alias = "simulate")]
    Simulate(simulate::SimulateArgs),
    /// Simulate robot sessions in a 2D office world: CARMEN logs, ground truth, world map.
    Sim(sim::SimArgs),
    /// Build an occupancy grid (ROS map_server YAML + PGM) from a laser log and poses.
    Grid(grid::GridArgs),
    /// Convert a laser log (CARMEN or ROS 2 bag) to a ROS 2 bag (`.mcap`, `.db3`) or a
    /// CARMEN log; a KITTI-style folder to a bag of PointCloud2.
    Convert(convert::ConvertArgs),
    /// Merge two ROS map_server maps of any resolution without an initial guess (exit code 3:
    /// no acceptable hypothesis).
    GridMerge(grid_merge::GridMergeArgs),
    /// Draw a grid, pose graphs and trajectories to a PNG.
    Render(render::RenderArgs),
    /// SLAM evaluation on corrected logs: odometry noise, relations, ATE/RPE.
    Eval(eval::EvalArgs),
    /// 2D graph SLAM on a laser log: pose graph, map, picture, one pose per scan.
    Slam(slam::SlamArgs),
    /// Cut a corrected laser log into overlapping segments, each re-based to its own origin
    /// (optionally with noisy odometry), with the ground truth kept apart.
    Split(split::SplitArgs),
    /// Inspect, check and roll back a lifelong store (a SQLite file of map versions).
    Store(store::StoreArgs),
}

/// An error that maps to exit code 2.
#[derive(Debug)]
pub struct BadInput(pub String);

impl std::fmt::Display for BadInput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for BadInput {}

/// Parameters from a JSON file, or the defaults without one. The file may give any subset
/// of the fields at any depth: it is laid over `T::default()` written as JSON, so a field it
/// leaves out keeps the value `T`'s default has there, also inside a nested object (a
/// nested struct's own default can differ: the atlas's `recognition.place` is not
/// `PlaceParams::default()`). Unknown fields are still refused where the types deny them. A
/// file that cannot be read or parsed is bad input (exit code 2).
pub fn read_config<T: serde::de::DeserializeOwned + serde::Serialize + Default>(
    path: Option<&std::path::Path>,
) -> anyhow::Result<T> {
    let Some(path) = path else {
        return Ok(T::default());
    };
    let bad = |e: &dyn std::fmt::Display| bad_input(format!("{}: {e}", path.display()));
    let text = std::fs::read_to_string(path).map_err(|e| bad(&e))?;
    let given: serde_json::Value = serde_json::from_str(&text).map_err(|e| bad(&e))?;
    let mut merged = serde_json::to_value(T::default()).map_err(|e| bad(&e))?;
    overlay(&mut merged, given);
    serde_json::from_value(merged).map_err(|e| bad(&e))
}

/// `given` laid over `base`: objects field by field, recursively; anything else replaces,
/// and so does an object naming another variant of a tagged enum than `base`'s (a different
/// `"kind"`, the tag of the parameters' enums, e.g. `RobustKernel`): its fields are the new
/// variant's own.
fn overlay(base: &mut serde_json::Value, given: serde_json::Value) {
    let other_variant = |base: &serde_json::Value, given: &serde_json::Value| matches!((base.get("kind"), given.get("kind")), (Some(b), Some(g)) if b != g);
    match (base, given) {
        (base, given) if other_variant(base, &given) => *base = given,
        (serde_json::Value::Object(base), serde_json::Value::Object(given)) => {
            for (key, value) in given {
                match base.get_mut(&key) {
                    Some(slot) => overlay(slot, value),
                    None => {
                        base.insert(key, value);
                    }
                }
            }
        }
        (base, given) => *base = given,
    }
}

pub use mapmerge_jobs::log_file_stem;

/// `--scan-topic` / `--odom-topic`: which topics of a ROS 2 bag to read, for every command
/// that takes a LOG (a CARMEN log or a bag: `.mcap`, `.db3` or a bag directory).
#[derive(clap::Args, Debug, Clone, Default)]
pub struct BagTopics {
    /// The bag's `sensor_msgs/msg/LaserScan` topic (default: the only one).
    #[arg(long)]
    pub scan_topic: Option<String>,
    /// The bag's `nav_msgs/msg/Odometry` topic (default: the only one; none: scans without
    /// poses).
    #[arg(long)]
    pub odom_topic: Option<String>,
}

impl BagTopics {
    /// The reader's form of the choice.
    pub fn choice(&self) -> mapmerge_rosbag::TopicChoice {
        mapmerge_rosbag::TopicChoice {
            scan_topic: self.scan_topic.clone(),
            odom_topic: self.odom_topic.clone(),
        }
    }
}

/// Reads a laser session from a CARMEN log or a ROS 2 bag; failures are bad input (exit 2).
/// For a bag, one line on stderr says which topics and frames were used, where the laser's
/// mount came from and how many scans had no odometry.
pub fn read_log(
    path: &std::path::Path,
    topics: &BagTopics,
) -> anyhow::Result<mapmerge_scan::LaserLog> {
    let (log, info) = mapmerge_jobs::read_log_or_bag(path, &topics.choice()).map_err(job_error)?;
    if let Some(info) = info {
        let mount = &info.robot_from_sensor;
        eprintln!(
            "{}: {} scans on {} ({}), odometry {}; laser at ({:.3} m, {:.3} m, {:.2}°) on {} {}{}{}",
            path.display(),
            log.scans.len(),
            info.scan_topic,
            info.laser_frame,
            info.odom_topic.as_deref().unwrap_or("none"),
            mount.x_m,
            mount.y_m,
            mount.theta_rad.to_degrees(),
            info.base_frame,
            info.mount_from.describe(),
            if info.laser_upside_down { ", upside down" } else { "" },
            match info.scans_without_odometry {
                0 => String::new(),
                n => format!("; {n} scans without odometry left out"),
            }
        );
    }
    Ok(log)
}

/// A public log's short name: its stem without `-corrected` (`…/intel-corrected.log.xz` →
/// `intel`).
pub fn log_short_name(path: &std::path::Path) -> String {
    let stem = log_file_stem(path);
    match stem.strip_suffix("-corrected") {
        Some(short) if !short.is_empty() => short.to_owned(),
        _ => stem,
    }
}

/// A progress bar of `len` `unit`s with a message, or a hidden one when `visible` is false.
pub fn progress_bar(
    len: usize,
    unit: &str,
    message: &'static str,
    visible: bool,
) -> indicatif::ProgressBar {
    let bar = if visible {
        indicatif::ProgressBar::new(len as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(&format!(
            "{{msg}} {{bar:40}} {{pos}}/{{len}} {unit} ({{eta}})"
        ))
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message(message);
    bar
}

/// Prints `report` as one JSON object on its own line (the `--json` output of every command).
pub fn print_json(report: &impl serde::Serialize) -> anyhow::Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    serde_json::to_writer(&mut out, report)?;
    writeln!(out)?;
    Ok(())
}

/// Reads a graph file; any failure is bad input (exit code 2), with the reason chain kept.
pub fn load_graph(path: &std::path::Path) -> anyhow::Result<mapmerge_io::LoadedGraph> {
    load_graph_with(path, &mapmerge_io::ReadParams::default())
}

/// [`load_graph`] with reader options.
pub fn load_graph_with(
    path: &std::path::Path,
    params: &mapmerge_io::ReadParams,
) -> anyhow::Result<mapmerge_io::LoadedGraph> {
    mapmerge_io::read_graph_with(path, params).map_err(bad_file)
}

/// Rejects a `--resolution` that is not a positive, finite number of metres (exit code 2).
pub fn check_resolution(resolution_m: f64) -> anyhow::Result<()> {
    mapmerge_jobs::check_resolution(resolution_m).map_err(job_error)
}

/// A job's error as the binary's: bad input keeps exit code 2 ([`BadInput`]), anything else
/// exit code 1; the text is the job's.
pub fn job_error(err: mapmerge_jobs::JobError) -> anyhow::Error {
    match err {
        mapmerge_jobs::JobError::BadInput(message) => bad_input(message),
        other => anyhow::anyhow!("{other}"),
    }
}

/// A bad-input error (exit code 2) with `reason`.
pub fn bad_input(reason: impl std::fmt::Display) -> anyhow::Error {
    anyhow::Error::new(BadInput(reason.to_string()))
}

/// A bad-input error (exit code 2) from a reader's error, its cause chain kept in the text.
pub fn bad_file(err: impl std::error::Error) -> anyhow::Error {
    bad_input(mapmerge_jobs::error_chain(&err))
}

fn main() -> ExitCode {
    // `mapmerge … | head` must end quietly, like other Unix tools, instead of panicking in
    // `println!` on a closed pipe: restore the default SIGPIPE action Rust turns off.
    #[cfg(unix)]
    // SAFETY: called before any thread starts; SIG_DFL is a valid handler for SIGPIPE.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Atlas(args) => atlas::run(args),
        Command::Assemble(args) => assemble::run(args).map(|()| ExitCode::SUCCESS),
        Command::Optimize(args) => optimize::run(args),
        Command::Corrupt(args) => corrupt::run(args),
        Command::Compare(args) => compare::run(args),
        Command::Simulate(args) => simulate::run(args),
        Command::Sim(args) => sim::run(args),
        Command::Convert(args) => convert::run(args),
        Command::Areas(args) => areas::run(args),
        Command::Route(args) => areas::route(args),
        Command::Grid(args) => grid::run(args),
        Command::GridMerge(args) => grid_merge::run(args),
        Command::Render(args) => render::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Slam(args) => slam::run(args),
        Command::Split(args) => split::run(args),
        Command::Store(args) => store::run(args),
    };
    match result {
        Ok(code) => code,
        Err(err) => {
            eprintln!("mapmerge: error: {err:#}");
            if err.downcast_ref::<BadInput>().is_some() {
                ExitCode::from(2)
            } else {
                ExitCode::from(1)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    /// `read_config` of `text` (written to a scratch file).
    fn config<T: serde::de::DeserializeOwned + serde::Serialize + Default>(
        name: &str,
        text: &str,
    ) -> anyhow::Result<T> {
        let path = std::env::temp_dir().join(format!(
            "mapmerge-config-{}-{name}.json",
            std::process::id()
        ));
        std::fs::write(&path, text).unwrap();
        let read = read_config(Some(&path));
        std::fs::remove_file(&path).unwrap();
        read
    }

    /// An empty object gives the defaults of every parameter type a command reads: each
    /// default survives being written as JSON and read back.
    #[test]
    fn an_empty_config_is_every_types_default() {
        fn same<T: serde::de::DeserializeOwned + serde::Serialize + Default>(name: &str) {
            let read: T = config(name, "{}").unwrap();
            assert_eq!(
                serde_json::to_value(read).unwrap(),
                serde_json::to_value(T::default()).unwrap(),
                "{name}"
            );
        }
        same::<mapmerge_engine::EngineParams>("engine");
        same::<mapmerge_areas::ManagerParams>("manager");
        same::<mapmerge_areas::DoorParams>("doors");
        same::<mapmerge_assemble::AssembleParams>("assemble");
        same::<mapmerge_gridmatch::GridMatchParams>("gridmatch");
    }

    /// A field given deep inside keeps its siblings at the enclosing default, which differs
    /// from the nested type's own (the atlas's recognition accepts from 0.975, a bare
    /// `PlaceParams` from 0.5); a misspelt field is still refused.
    #[test]
    fn a_nested_field_keeps_its_siblings_at_the_enclosing_default() {
        let params: mapmerge_engine::EngineParams = config(
            "nested",
            r#"{"atlas": {"recognition": {"place": {"candidates_per_query": 6}}}}"#,
        )
        .unwrap();
        let defaults = mapmerge_engine::EngineParams::default();
        let place = &params.atlas.recognition.place;
        assert_eq!(place.candidates_per_query, 6);
        assert_eq!(place.min_score, defaults.atlas.recognition.place.min_score);
        assert_eq!(place.min_score, 0.975);
        assert!(config::<mapmerge_engine::EngineParams>(
            "typo",
            r#"{"atlas": {"recognition": {"place": {"min_scor": 0.5}}}}"#
        )
        .is_err());
        assert!(config::<mapmerge_engine::EngineParams>("broken", "{").is_err());
    }

    /// Another variant of a tagged enum replaces the default's (whose fields it does not
    /// have); the same variant takes the given fields.
    #[test]
    fn another_variant_of_a_tagged_enum_replaces_the_defaults() {
        use mapmerge_solve::RobustKernel;
        let params: mapmerge_engine::EngineParams = config(
            "variant",
            r#"{"atlas": {"loops": {"optimizer": {"robust": {"kind": "huber", "delta": 2.0}}}}}"#,
        )
        .unwrap();
        assert_eq!(
            params.atlas.loops.optimizer.robust,
            RobustKernel::Huber { delta: 2.0 }
        );
        let params: mapmerge_engine::EngineParams = config(
            "same-variant",
            r#"{"atlas": {"loops": {"optimizer": {"robust": {"phi": 3.0}}}}}"#,
        )
        .unwrap();
        assert_eq!(
            params.atlas.loops.optimizer.robust,
            RobustKernel::Dcs { phi: 3.0 }
        );
    }
}
