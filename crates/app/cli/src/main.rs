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

/// Parameters from a JSON file (any subset of the fields; the rest keep their defaults, as
/// the types' `#[serde(default)]` says), or the defaults without one. A file that cannot be
/// read or parsed is bad input (exit code 2).
pub fn read_config<T: serde::de::DeserializeOwned + Default>(
    path: Option<&std::path::Path>,
) -> anyhow::Result<T> {
    let Some(path) = path else {
        return Ok(T::default());
    };
    let text =
        std::fs::read_to_string(path).map_err(|e| bad_input(format!("{}: {e}", path.display())))?;
    serde_json::from_str(&text).map_err(|e| bad_input(format!("{}: {e}", path.display())))
}

/// A log file's stem: its file name without `.xz` / `.gz`, then `.log`
/// (`…/intel_03.log.xz` → `intel_03`).
pub fn log_file_stem(path: &std::path::Path) -> String {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| path.display().to_string());
    let name = name
        .strip_suffix(".xz")
        .or_else(|| name.strip_suffix(".gz"))
        .unwrap_or(&name);
    name.strip_suffix(".log").unwrap_or(name).to_owned()
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
    if resolution_m.is_finite() && resolution_m > 0.0 {
        Ok(())
    } else {
        Err(bad_input(format!(
            "--resolution must be a positive number of metres, got {resolution_m}"
        )))
    }
}

/// A bad-input error (exit code 2) with `reason`.
pub fn bad_input(reason: impl std::fmt::Display) -> anyhow::Error {
    anyhow::Error::new(BadInput(reason.to_string()))
}

/// A bad-input error (exit code 2) from a reader's error, its cause chain kept in the text.
pub fn bad_file(err: impl std::error::Error) -> anyhow::Error {
    let mut message = err.to_string();
    let mut source = err.source();
    while let Some(cause) = source {
        message.push_str(&format!(": {cause}"));
        source = cause.source();
    }
    bad_input(message)
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
