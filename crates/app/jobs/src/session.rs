//! Laser sessions: reading a CARMEN log or a ROS 2 bag, SLAM on it (`mapmerge slam`), the
//! map of a posed session (`mapmerge grid`).

use std::path::Path;

use mapmerge_engine::{run_slam, EngineParams, SlamInfo, SlamRun};
use mapmerge_geometry::Se2;
use mapmerge_grid::{ClassThresholds, InsertInfo, InsertParams, OccupancyGrid};
use mapmerge_io::{AnyGraph, GraphFormat, MapMode, RosMap};
use mapmerge_posegraph::PoseGraph2;
use mapmerge_render::{GraphStyle, Picture, PictureStyle, Rgb};
use mapmerge_rosbag::{BagInfo, TopicChoice};
use mapmerge_scan::LaserLog;
use serde::Serialize;

use crate::JobError;

/// Default cell side of a session's map (m).
pub const DEFAULT_RESOLUTION_M: f64 = 0.05;

/// Reads a laser session: a ROS 2 bag (MCAP or SQLite, file or bag folder, the topics found
/// by type) or a CARMEN log (plain or xz). Unreadable, malformed or scan-less input is bad
/// input naming the file.
pub fn read_session_log(path: &Path) -> Result<LaserLog, JobError> {
    read_session_log_with(path, &TopicChoice::default())
}

/// A CARMEN log, or a ROS 2 bag with what [`mapmerge_rosbag::read_bag`] says of it (topics,
/// frames, the laser's mount, scans without odometry). A log without scans is returned as
/// it is; unreadable or malformed input is bad input naming the file.
pub fn read_log_or_bag(
    path: &Path,
    topics: &TopicChoice,
) -> Result<(LaserLog, Option<BagInfo>), JobError> {
    mapmerge_rosbag::read_log_or_bag(path, topics).map_err(|e| JobError::bad_file(&e))
}

/// [`read_session_log`] with the bag's scan and odometry topics chosen.
pub fn read_session_log_with(path: &Path, topics: &TopicChoice) -> Result<LaserLog, JobError> {
    let (log, _) = read_log_or_bag(path, topics)?;
    if log.scans.is_empty() {
        return Err(JobError::bad_input(format!(
            "{}: no laser scans",
            path.display()
        )));
    }
    Ok(log)
}

/// The grid resolutions a command takes (m): 1 cm, finer than any laser's noise, keeps a
/// 100 m site within a grid's cell limit.
pub const RESOLUTION_RANGE_M: mapmerge_params::Real = mapmerge_params::Real::within(0.01, 100.0);

/// Rejects a resolution outside [`RESOLUTION_RANGE_M`].
pub fn check_resolution(resolution_m: f64) -> Result<(), JobError> {
    if RESOLUTION_RANGE_M.contains(resolution_m) {
        Ok(())
    } else {
        Err(JobError::bad_input(format!(
            "--resolution must be a number of metres in [0.01, 100], got {resolution_m}"
        )))
    }
}

/// Checks, before any work, that `dir` can take a command's outputs, and writes nothing
/// there: it is a folder, or can be made one in its nearest existing ancestor, and a file can
/// be written where it would be. Bad input otherwise, naming the folder.
pub fn check_output_dir(dir: &Path) -> Result<(), JobError> {
    check_output_place(dir, dir)
}

/// Checks, before any work, that the output file `file` can be written: it is no folder, and
/// its folder can take it (as [`check_output_dir`]). Nothing is written; an existing file is
/// left as it is until the command writes it.
pub fn check_output_file(file: &Path) -> Result<(), JobError> {
    if file.is_dir() || file.as_os_str().is_empty() {
        return Err(JobError::bad_input(format!(
            "{}: the output is a file, and this is a folder",
            file.display()
        )));
    }
    match file.parent() {
        Some(parent) if !parent.as_os_str().is_empty() => check_output_place(file, parent),
        _ => check_output_place(file, Path::new(".")),
    }
}

/// `folder` (that of `output`, or `output` itself) exists as a folder or can be made in its
/// nearest existing ancestor, which takes a probe file (removed at once).
fn check_output_place(output: &Path, folder: &Path) -> Result<(), JobError> {
    let refused = |reason: String| JobError::bad_input(format!("{}: {reason}", output.display()));
    let mut existing = folder;
    while !existing.exists() {
        match existing.parent() {
            Some(parent) if !parent.as_os_str().is_empty() => existing = parent,
            _ => {
                existing = Path::new(".");
                break;
            }
        }
    }
    if !existing.is_dir() {
        return Err(refused(if existing == output {
            "the output is a folder, and this is a file".to_owned()
        } else {
            format!("cannot make its folder: {} is a file", existing.display())
        }));
    }
    let probe = existing.join(format!(".mapmerge-write-check-{}", std::process::id()));
    std::fs::File::create_new(&probe)
        .and_then(|_| std::fs::remove_file(&probe))
        .map_err(|e| refused(format!("cannot write there: {e}")))
}

/// A log file's stem: its file name without `.xz` / `.gz`, then `.log`
/// (`…/intel_03.log.xz` → `intel_03`); a bag's without `.mcap` / `.db3` (a bag directory's
/// name is its stem).
pub fn log_file_stem(path: &Path) -> String {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| path.display().to_string());
    let name = name
        .strip_suffix(".xz")
        .or_else(|| name.strip_suffix(".gz"))
        .unwrap_or(&name);
    [".log", ".mcap", ".db3"]
        .iter()
        .find_map(|suffix| name.strip_suffix(suffix))
        .unwrap_or(name)
        .to_owned()
}

/// SLAM on `log` (read from `path`, which names it in errors): [`run_slam`] with `params`,
/// calling `progress(scans_done)` after every scan.
pub fn slam_log(
    path: &Path,
    log: &LaserLog,
    params: EngineParams,
    progress: impl FnMut(usize),
) -> Result<SlamRun, JobError> {
    run_slam(log, params, progress)
        .map_err(|e| JobError::bad_input(format!("{}: {e}", path.display())))
}

/// The map of a posed session: every scan inserted at its pose (`map_from_robot`, one per
/// scan in order), calling `progress()` after each.
pub fn build_grid(
    log: &LaserLog,
    poses: &[Se2],
    resolution_m: f64,
    params: &InsertParams,
    progress: impl FnMut(),
) -> Result<(OccupancyGrid, InsertInfo), JobError> {
    let scans: Vec<_> = poses
        .iter()
        .zip(&log.scans)
        .map(|(pose, record)| (*pose, &record.scan))
        .collect();
    OccupancyGrid::from_posed_scans(resolution_m, &scans, params, progress)
        .map_err(|e| JobError::context("building the grid", &e))
}

/// A SLAM run's figures (the part of `mapmerge slam --json` that does not score against a
/// reference).
#[derive(Clone, Debug, Serialize)]
pub struct SlamSummary {
    /// Scans (one pose each).
    pub scans: usize,
    /// Wall time of the loop (s) and per scan (ms).
    pub seconds: f64,
    /// See `seconds`.
    pub ms_per_scan: f64,
    /// The tracker's and the constraint builder's counters.
    pub front_end: SlamInfo,
    /// The final graph's size.
    pub graph_vertices: usize,
    /// See `graph_vertices`.
    pub graph_edges: usize,
}

impl SlamSummary {
    /// The figures of `run`.
    pub fn of(run: &SlamRun) -> Self {
        Self {
            scans: run.trajectory.len(),
            seconds: run.seconds,
            ms_per_scan: 1e3 * run.seconds / run.trajectory.len().max(1) as f64,
            front_end: run.info,
            graph_vertices: run.graph.num_vertices(),
            graph_edges: run.graph.num_edges(),
        }
    }
}

/// Seconds per scan of the clock a TUM file gets when the log's stamps do not increase.
pub const TUM_CLOCK_PERIOD_S: f64 = 0.1;

/// Writes a SLAM run's outputs into `dir` (created if missing): `trajectory.tum` (one pose per
/// scan, with the scan's stamp, or [`TUM_CLOCK_PERIOD_S`] apart when the log's stamps do not
/// increase: TUM readers such as evo pair poses by stamp), `graph.g2o`, the map from every scan at its final pose
/// (`map.yaml` + `map.pgm`) and `map.png` with the trajectory and graph over it. Each
/// product is freed once written or drawn, so the largest two never coexist with a third.
pub fn write_slam_outputs(
    dir: &Path,
    log: &LaserLog,
    trajectory: &[Se2],
    graph: &PoseGraph2,
    resolution_m: f64,
    progress: impl FnMut(),
) -> Result<(), JobError> {
    std::fs::create_dir_all(dir).map_err(|e| JobError::writing(dir, &e))?;
    let (stamps, _) = log.increasing_scan_stamps(TUM_CLOCK_PERIOD_S);
    let stamped: Vec<(f64, Se2)> = stamps.into_iter().zip(trajectory.iter().copied()).collect();
    let path = dir.join("trajectory.tum");
    mapmerge_io::write_tum_planar(&path, &stamped).map_err(|e| JobError::writing(&path, &e))?;
    let any = AnyGraph::Planar(graph.clone());
    let path = dir.join("graph.g2o");
    mapmerge_io::write_graph(&path, &any, GraphFormat::G2o)
        .map_err(|e| JobError::writing(&path, &e))?;
    let (grid, _) = build_grid(
        log,
        trajectory,
        resolution_m,
        &InsertParams::default(),
        progress,
    )?;
    let thresholds = ClassThresholds::default();
    let map = RosMap::from_grid(&grid, MapMode::Trinary, &thresholds);
    let path = dir.join("map.yaml");
    mapmerge_io::write_ros_map(&path, &map).map_err(|e| JobError::writing(&path, &e))?;
    // Written: its bytes go before the picture's are made.
    drop(map);
    let style = PictureStyle {
        pixels_per_cell: 1,
        classes: Some(thresholds),
    };
    let mut picture = Picture::of_grid(&grid, &style);
    drop(grid);
    picture.draw_trajectory(trajectory, Rgb::RED, 1.0);
    picture.draw_graph(graph, &GraphStyle::default());
    let path = dir.join("map.png");
    picture
        .save_png(&path)
        .map_err(|e| JobError::writing(&path, &e))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    #[test]
    fn a_log_without_scans_is_bad_input_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("odometry-only.log");
        std::fs::write(&path, "ODOM 1 2 0.5 0 0 0 10.0 host 10.0\n").unwrap();
        let err = read_session_log(&path).unwrap_err();
        assert_eq!(
            err,
            JobError::BadInput(format!("{}: no laser scans", path.display()))
        );
        let missing = read_session_log(&dir.path().join("missing.log")).unwrap_err();
        assert_eq!(missing.exit_code(), 2);
        assert!(missing.to_string().contains("missing.log"), "{missing}");
    }

    #[test]
    fn stems_drop_compression_and_log_suffixes() {
        assert_eq!(log_file_stem(Path::new("a/intel_03.log.xz")), "intel_03");
        assert_eq!(log_file_stem(Path::new("b.gz")), "b");
        assert_eq!(log_file_stem(Path::new("c.txt")), "c.txt");
        assert_eq!(log_file_stem(Path::new("d/run_2.mcap")), "run_2");
        assert_eq!(log_file_stem(Path::new("run_3.db3")), "run_3");
        assert!(check_resolution(0.05).is_ok());
        assert_eq!(
            check_resolution(0.0).unwrap_err().to_string(),
            "--resolution must be a number of metres in [0.01, 100], got 0"
        );
    }

    #[test]
    fn slam_on_a_simulated_session_maps_every_scan() {
        let path = Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../../testdata/sim/office-aliased/session_0.log.xz"
        ));
        let mut log = read_session_log(path).unwrap();
        log.scans.truncate(200);
        let run = slam_log(path, &log, EngineParams::default(), |_| {}).unwrap();
        let summary = SlamSummary::of(&run);
        assert_eq!(summary.scans, 200);
        assert!(summary.graph_vertices > 1, "{summary:?}");
        let (grid, info) = build_grid(
            &log,
            &run.trajectory,
            DEFAULT_RESOLUTION_M,
            &InsertParams::default(),
            || {},
        )
        .unwrap();
        assert!(info.hits > 0 && grid.geometry().width > 10);
    }
}
