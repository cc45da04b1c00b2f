//! Maps and sessions: `grid_merge`, `read_log`, `slam`, `assemble`.

use std::path::PathBuf;
use std::time::Instant;

use mapmerge_engine::EngineParams;
use mapmerge_grid::InsertParams;
use mapmerge_gridmatch::GridMatchParams;
use mapmerge_io::AnyGraph;
use mapmerge_jobs::{
    arrival_order, assemble as assemble_segments, build_grid, check_resolution, default_params,
    load_segments, read_session_log_with, slam_log, Choice, LoadedSegment, Order, SlamSummary,
    TrajectorySource, DEFAULT_HYPOTHESES, DEFAULT_RESOLUTION_M,
};
use mapmerge_rosbag::TopicChoice;
use numpy::ndarray::Array2;
use numpy::IntoPyArray;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::convert::{add_grid, planar_poses, rows, to_dict, to_python, vector};
use crate::graph::Graph;
use crate::job_error;

// The defaults are written as literals so that Python's signatures show them; they are the
// jobs' (checked when this compiles).
const _: () = assert!(DEFAULT_HYPOTHESES == 4);
const _: () = assert!(DEFAULT_RESOLUTION_M == 0.05);

/// Merges map `b` into map `a` (ROS map_server YAML files, any resolutions) without an
/// initial guess. Returns the dict `mapmerge grid-merge --json` prints (`accepted`,
/// `reason`, `transform` of B in A, `acceptance`, `sm`, `dm`, `hypotheses`, …) plus the
/// merged grid (`grid`, `grid_origin_m`, `grid_resolution_m`; `None` when not merged). Not
/// merging is not an error. With `output` (a YAML path) it writes what the CLI writes there.
#[pyfunction]
#[pyo3(signature = (a_yaml, b_yaml, *, output = None, hypotheses = 4))]
pub fn grid_merge<'py>(
    py: Python<'py>,
    a_yaml: PathBuf,
    b_yaml: PathBuf,
    output: Option<PathBuf>,
    hypotheses: usize,
) -> PyResult<Bound<'py, PyDict>> {
    let params = GridMatchParams::default();
    let merged = py
        .detach(|| {
            mapmerge_jobs::grid_merge(&a_yaml, &b_yaml, &params, hypotheses, output.as_deref())
        })
        .map_err(|e| job_error(py, e))?;
    let dict = to_dict(py, &merged.report)?;
    add_grid(py, &dict, merged.merged.as_ref())?;
    Ok(dict)
}

/// Reads a laser session (a CARMEN log, plain or xz, or a ROS 2 bag) as arrays, one row per
/// scan: `stamps` (N,), `odometry` (N, 3) `[x, y, yaw]` of the robot in the odometry frame
/// (NaN where a scan carries none), `ranges` (N, B) float32 when every scan has B beams, else
/// a list of arrays, and the scans' geometry: `angle_min`, `angle_increment`, `range_min`,
/// `range_max` (N,) and `robot_from_sensor` (N, 3). A bag's topics are found by type;
/// `scan_topic` / `odom_topic` choose when it has several.
#[pyfunction]
#[pyo3(signature = (log_or_bag, *, scan_topic = None, odom_topic = None))]
pub fn read_log<'py>(
    py: Python<'py>,
    log_or_bag: PathBuf,
    scan_topic: Option<String>,
    odom_topic: Option<String>,
) -> PyResult<Bound<'py, PyDict>> {
    let topics = TopicChoice {
        scan_topic,
        odom_topic,
    };
    let log = py
        .detach(|| read_session_log_with(&log_or_bag, &topics))
        .map_err(|e| job_error(py, e))?;
    let scans = &log.scans;
    let dict = PyDict::new(py);
    dict.set_item("log", log_or_bag.display().to_string())?;
    dict.set_item(
        "stamps",
        vector(py, scans.iter().map(|s| s.stamp_secs).collect()),
    )?;
    dict.set_item(
        "odometry",
        rows(
            py,
            scans.iter().map(|s| match s.odom_from_robot {
                Some(p) => [p.x_m, p.y_m, p.theta_rad],
                None => [f64::NAN; 3],
            }),
        ),
    )?;
    let beams = scans.first().map_or(0, |s| s.scan.ranges_m.len());
    if scans.iter().all(|s| s.scan.ranges_m.len() == beams) {
        let flat: Vec<f32> = scans
            .iter()
            .flat_map(|s| s.scan.ranges_m.iter().copied())
            .collect();
        let array = Array2::from_shape_vec((scans.len(), beams), flat)
            .map_err(|e| crate::MapmergeError::new_err(format!("ranges: {e}")))?;
        dict.set_item("ranges", array.into_pyarray(py))?;
    } else {
        let list = PyList::empty(py);
        for s in scans {
            list.append(vector(py, s.scan.ranges_m.clone()))?;
        }
        dict.set_item("ranges", list)?;
    }
    let column = |f: &dyn Fn(&mapmerge_scan::LaserScan) -> f64| {
        vector(py, scans.iter().map(|s| f(&s.scan)).collect())
    };
    dict.set_item("angle_min", column(&|s| s.angle_min_rad))?;
    dict.set_item("angle_increment", column(&|s| s.angle_increment_rad))?;
    dict.set_item("range_min", column(&|s| f64::from(s.range_min_m)))?;
    dict.set_item("range_max", column(&|s| f64::from(s.range_max_m)))?;
    let mounts: Vec<_> = scans.iter().map(|s| s.scan.robot_from_sensor).collect();
    dict.set_item("robot_from_sensor", planar_poses(py, &mounts))?;
    Ok(dict)
}

/// 2D graph SLAM on a laser session (a CARMEN log or a ROS 2 bag): the engine with one
/// epoch, as `mapmerge slam` runs it. Returns a dict: `trajectory` (N, 3) `[x, y, yaw]` of
/// every scan, `stamps` (N,), the map built from every scan at its pose (`grid`,
/// `grid_origin_m`, `grid_resolution_m`), the pose `graph` (a `Graph`), and the figures of
/// `mapmerge slam --json` (`scans`, `seconds`, `ms_per_scan`, `front_end`, `graph_vertices`,
/// `graph_edges`). `scan_topic` / `odom_topic` as for `read_log`.
#[pyfunction]
#[pyo3(signature = (
    log_or_bag, *, resolution = 0.05, scan_topic = None, odom_topic = None
))]
pub fn slam<'py>(
    py: Python<'py>,
    log_or_bag: PathBuf,
    resolution: f64,
    scan_topic: Option<String>,
    odom_topic: Option<String>,
) -> PyResult<Bound<'py, PyDict>> {
    let topics = TopicChoice {
        scan_topic,
        odom_topic,
    };
    let (log, run, grid) = py
        .detach(|| {
            check_resolution(resolution)?;
            let log = read_session_log_with(&log_or_bag, &topics)?;
            let run = slam_log(&log_or_bag, &log, EngineParams::default(), |_| {})?;
            let (grid, _) = build_grid(
                &log,
                &run.trajectory,
                resolution,
                &InsertParams::default(),
                || {},
            )?;
            Ok((log, run, grid))
        })
        .map_err(|e| job_error(py, e))?;
    let dict = to_dict(py, &SlamSummary::of(&run))?;
    dict.set_item("log", log_or_bag.display().to_string())?;
    dict.set_item("trajectory", planar_poses(py, &run.trajectory))?;
    dict.set_item(
        "stamps",
        vector(py, log.scans.iter().map(|s| s.stamp_secs).collect()),
    )?;
    add_grid(py, &dict, Some(&grid))?;
    let graph = Graph::made(
        AnyGraph::Planar(run.graph),
        log_or_bag.display().to_string(),
    );
    dict.set_item("graph", Bound::new(py, graph)?)?;
    Ok(dict)
}

/// Assembles trajectory segments without initial guesses, in any order (AutoMerge), as
/// `mapmerge assemble` does: each segment a CARMEN log or ROS 2 bag (its trajectory by SLAM,
/// or its odometry with `trajectory="odometry"`) or a KITTI-style folder. Returns a dict:
/// the fields of `mapmerge assemble --json` (`segments`, `order`, `seed`, `trajectory`,
/// `arrivals`, `groups`, `loops` as a count, `pairs_associated`, timings), `loop_edges` (the
/// lines of `loops.jsonl`) and `poses` / `stamps`: per segment name, every scan's pose in
/// its group's frame (N, 3) and its stamp.
#[pyfunction]
#[pyo3(signature = (paths, *, order = "given", seed = 0, trajectory = "slam"))]
pub fn assemble<'py>(
    py: Python<'py>,
    paths: Vec<PathBuf>,
    order: &str,
    seed: u64,
    trajectory: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let order = Order::from_name(order).map_err(|e| job_error(py, e))?;
    let source = TrajectorySource::from_name(trajectory).map_err(|e| job_error(py, e))?;
    let (assembled, trajectory_secs) = py
        .detach(|| {
            let started = Instant::now();
            let segments = load_segments(&paths, &Default::default(), source, || {})?;
            let spatial = segments
                .iter()
                .any(|s| matches!(s, LoadedSegment::Spatial(_)));
            let trajectory_secs = started.elapsed().as_secs_f64();
            let arrivals = arrival_order(segments.len(), order, seed);
            let assembled =
                assemble_segments(segments, default_params(spatial), &arrivals, |_, _| {})?;
            Ok((assembled, trajectory_secs))
        })
        .map_err(|e| job_error(py, e))?;
    let dict = PyDict::new(py);
    dict.set_item("segments", assembled.arrivals.len())?;
    dict.set_item("order", to_python(py, &order)?)?;
    dict.set_item("seed", seed)?;
    dict.set_item("trajectory", to_python(py, &source)?)?;
    dict.set_item("arrivals", to_python(py, &assembled.arrivals)?)?;
    let groups = PyList::empty(py);
    let poses = PyDict::new(py);
    let stamps = PyDict::new(py);
    for solution in &assembled.solutions {
        let group = PyDict::new(py);
        group.set_item("segments", solution.segments.clone())?;
        group.set_item(
            "scans",
            solution.scan_poses.values().map(Vec::len).sum::<usize>(),
        )?;
        group.set_item("loop_edges", solution.loop_edges)?;
        group.set_item("iterations", solution.iterations)?;
        group.set_item("numerical_failure", solution.numerical_failure)?;
        groups.append(group)?;
        for (name, scan_poses) in &solution.scan_poses {
            poses.set_item(name, planar_poses(py, scan_poses))?;
            if let Some((segment, _)) = assembled.assembler.segment(name) {
                stamps.set_item(name, vector(py, segment.stamps_secs.clone()))?;
            }
        }
    }
    dict.set_item("groups", groups)?;
    let loop_edges = assembled.loop_lines();
    dict.set_item("loops", loop_edges.len())?;
    dict.set_item("pairs_associated", assembled.pairs_associated())?;
    dict.set_item("trajectory_secs", trajectory_secs)?;
    dict.set_item("association_secs", assembled.association_secs)?;
    dict.set_item("optimisation_secs", assembled.optimisation_secs)?;
    dict.set_item("loop_edges", to_python(py, &loop_edges)?)?;
    dict.set_item("poses", poses)?;
    dict.set_item("stamps", stamps)?;
    Ok(dict)
}
