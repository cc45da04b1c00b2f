//! What every command of the `mapmerge` binary shares (feature `cli`): the bad-input error
//! that maps to exit code 2, reading a JSON config over a type's defaults, reading a log or a
//! bag, progress bars and `--json` output. The binary's product commands and the lab's
//! experiment commands (`mapmerge eval …`) both use these, so each exists once.

use std::path::{Path, PathBuf};

use mapmerge_assemble::AssembleParams;
use mapmerge_geometry::Se2;
use mapmerge_grid::{InsertParams, OccupancyGrid};
use mapmerge_scan::LaserLog;

use crate::{LoadedSegment, TrajectorySource};

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
/// file that cannot be read or parsed, or a value out of its range (checked by
/// [`mapmerge_params::Validate`], the field named by its path), is bad input (exit code 2).
pub fn read_config<T>(path: Option<&std::path::Path>) -> anyhow::Result<T>
where
    T: serde::de::DeserializeOwned + serde::Serialize + Default + mapmerge_params::Validate,
{
    let Some(path) = path else {
        return Ok(T::default());
    };
    let bad = |e: &dyn std::fmt::Display| bad_input(format!("{}: {e}", path.display()));
    let text = mapmerge_io::read_document(path).map_err(bad_file)?;
    let given: serde_json::Value = serde_json::from_str(&text).map_err(|e| bad(&e))?;
    let mut merged = serde_json::to_value(T::default()).map_err(|e| bad(&e))?;
    overlay(&mut merged, given);
    let params: T = serde_json::from_value(merged).map_err(|e| bad(&e))?;
    params.validate().map_err(|e| bad(&e))?;
    Ok(params)
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

pub use crate::log_file_stem;

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
    let (log, info) = crate::read_log_or_bag(path, &topics.choice()).map_err(job_error)?;
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
    crate::check_resolution(resolution_m).map_err(job_error)
}

/// [`crate::check_output_dir`] for the command line (exit code 2).
pub fn check_output_dir(dir: &std::path::Path) -> anyhow::Result<()> {
    crate::check_output_dir(dir).map_err(job_error)
}

/// [`crate::check_output_file`] for the command line (exit code 2).
pub fn check_output_file(file: &std::path::Path) -> anyhow::Result<()> {
    crate::check_output_file(file).map_err(job_error)
}

/// The error of a failed write to the user's output `path`: bad input (exit code 2), naming
/// it, as [`crate::JobError::writing`]. For `.map_err(writing(&path))`.
pub fn writing<E: std::error::Error>(
    path: &std::path::Path,
) -> impl FnOnce(E) -> anyhow::Error + '_ {
    move |e| job_error(crate::JobError::writing(path, &e))
}

/// A job's error as the binary's: bad input keeps exit code 2 ([`BadInput`]), anything else
/// exit code 1; the text is the job's.
pub fn job_error(err: crate::JobError) -> anyhow::Error {
    match err {
        crate::JobError::BadInput(message) => bad_input(message),
        other => anyhow::anyhow!("{other}"),
    }
}

/// A bad-input error (exit code 2) with `reason`.
pub fn bad_input(reason: impl std::fmt::Display) -> anyhow::Error {
    anyhow::Error::new(BadInput(reason.to_string()))
}

/// A bad-input error (exit code 2) from a reader's error, its cause chain kept in the text.
pub fn bad_file(err: impl std::error::Error) -> anyhow::Error {
    bad_input(crate::error_chain(&err))
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
    topics: &BagTopics,
) -> anyhow::Result<PosedLog> {
    let laser_log = read_log(log, topics)?;
    let scan_count = laser_log.scans.len();
    let poses = match poses_path {
        None => poses_of(&laser_log, log)?,
        Some(path) if is_tum(path) => mapmerge_io::read_tum_planar(path)
            .map_err(bad_file)?
            .into_iter()
            .map(|(_, pose)| pose)
            .collect(),
        Some(path) => poses_of(&read_log(path, topics)?, path)?,
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
pub fn build_posed_grid(
    posed: &PosedLog,
    resolution_m: f64,
    params: &InsertParams,
    progress: bool,
) -> anyhow::Result<(OccupancyGrid, mapmerge_grid::InsertInfo)> {
    let bar = progress_bar(posed.poses.len(), "scans", "grid", progress);
    let built = crate::build_grid(&posed.log, &posed.poses, resolution_m, params, || {
        bar.inc(1)
    });
    bar.finish_and_clear();
    built.map_err(job_error)
}

/// Reads the segments ([`crate::load_segments`]) with a progress bar.
pub fn load_segments_with_progress(
    paths: &[PathBuf],
    topics: &BagTopics,
    source: TrajectorySource,
    progress: bool,
) -> anyhow::Result<Vec<LoadedSegment>> {
    let bar = progress_bar(paths.len(), "segments", "trajectories", progress);
    let loaded = crate::load_segments(paths, &topics.choice(), source, || bar.inc(1));
    bar.finish_and_clear();
    loaded.map_err(job_error)
}

/// Reads `--config`; without one, [`crate::default_params`] (3D segments get the
/// paper's outdoor submaps, 5 m / 50 m).
pub fn load_assemble_params(
    config: Option<&Path>,
    spatial: bool,
) -> anyhow::Result<AssembleParams> {
    match config {
        None => Ok(crate::default_params(spatial)),
        config => read_config(config),
    }
}
