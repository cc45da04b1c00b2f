//! Converting sessions between formats: a laser log (CARMEN or a ROS 2 bag) → a ROS 2 bag
//! (`.mcap`, `.db3`) or a CARMEN log; a KITTI-style folder → a bag of PointCloud2; and how
//! fast each was read.

use std::path::{Path, PathBuf};
use std::time::Instant;

use mapmerge_rosbag::TopicChoice;
use serde::Serialize;

use crate::JobError;

/// What `convert` did (the object `mapmerge convert --json` prints).
#[derive(Clone, Debug, Serialize)]
pub struct ConvertReport {
    /// The input.
    pub log: PathBuf,
    /// The output.
    pub output: PathBuf,
    /// Scans, or clouds from a KITTI-style folder.
    pub scans: usize,
    /// Odometry messages written.
    pub odometry_messages: usize,
    /// Bytes of the input (every file below a folder).
    pub input_bytes: u64,
    /// Time to read the input (s).
    pub read_secs: f64,
    /// Read speed (MB/s).
    pub read_mb_per_s: f64,
    /// Time to write the output (s).
    pub write_secs: f64,
    /// Bytes written.
    pub output_bytes: u64,
    /// Why the output's stamps are a new clock, if they are.
    pub stamps_rewritten: Option<String>,
}

/// Bytes of a file, or of every file below a folder (symbolic links not followed).
fn bytes_on_disk(path: &Path) -> u64 {
    match std::fs::symlink_metadata(path) {
        Ok(meta) if meta.is_dir() => std::fs::read_dir(path).map_or(0, |entries| {
            entries
                .filter_map(|e| e.ok())
                .map(|e| bytes_on_disk(&e.path()))
                .sum()
        }),
        Ok(meta) => meta.len(),
        Err(_) => 0,
    }
}

/// What a conversion wrote: messages (scans or clouds), odometry messages, why the stamps are
/// a new clock (if they are).
struct Written {
    messages: usize,
    odometry_messages: usize,
    stamps_rewritten: Option<String>,
}

/// A KITTI-style folder (a 3D segment: `velodyne/*.bin`, `poses.txt`) → a bag of PointCloud2
/// and odometry, every point kept. Returns the read time and what was written.
fn convert_kitti_folder(
    folder: &Path,
    output: &Path,
    params: &mapmerge_rosbag::BagWriteParams,
) -> Result<(f64, Written), JobError> {
    let every_point = mapmerge_assemble::KittiFolderOptions {
        voxel_m: 0.0,
        max_range_m: f64::MAX.sqrt(),
        stride: 1,
    };
    let started = Instant::now();
    let segment =
        mapmerge_assemble::load_kitti_folder(folder, &every_point).map_err(JobError::bad_input)?;
    let read_secs = started.elapsed().as_secs_f64();
    let written = mapmerge_rosbag::write_cloud_bag(output, &segment.poses, &segment.clouds, params)
        .map_err(|e| JobError::bad_file(&e))?;
    Ok((
        read_secs,
        Written {
            messages: written.scans,
            odometry_messages: written.odometry_messages,
            stamps_rewritten: Some("a KITTI folder's clouds carry no stamps".to_owned()),
        },
    ))
}

/// A laser log or bag → a bag or a CARMEN log. Returns the read time and what was written.
fn convert_log(
    path: &Path,
    output: &Path,
    topics: &TopicChoice,
    params: &mapmerge_rosbag::BagWriteParams,
) -> Result<(f64, Written), JobError> {
    let started = Instant::now();
    let log = crate::read_session_log_with(path, topics)?;
    let read_secs = started.elapsed().as_secs_f64();
    if log.scans.is_empty() {
        return Err(JobError::bad_input(format!(
            "{}: no laser scans",
            path.display()
        )));
    }
    let written = if mapmerge_rosbag::Storage::of_file(output).is_some() {
        let written =
            mapmerge_rosbag::write_bag(output, &log, params).map_err(|e| JobError::bad_file(&e))?;
        Written {
            messages: written.scans,
            odometry_messages: written.odometry_messages,
            stamps_rewritten: written.stamps_rewritten,
        }
    } else {
        let name = output.to_string_lossy();
        if !(name.ends_with(".log") || name.ends_with(".log.xz")) {
            return Err(JobError::bad_input(format!(
                "{}: name the output .mcap, .db3 (a ROS 2 bag) or .log / .log.xz (CARMEN)",
                output.display()
            )));
        }
        mapmerge_io::write_carmen(output, &log).map_err(|e| JobError::bad_file(&e))?;
        Written {
            messages: log.scans.len(),
            odometry_messages: log.odometry.len(),
            stamps_rewritten: None,
        }
    };
    Ok((read_secs, written))
}

/// Converts a laser log (CARMEN or a ROS 2 bag) into a bag (`.mcap`, `.db3`) or a CARMEN log,
/// or a KITTI-style folder into a bag of clouds; logs whose stamps do not increase get a
/// clock of `period_s` per scan (said in the report).
pub fn convert(
    log: &Path,
    output: &Path,
    topics: &TopicChoice,
    period_s: f64,
) -> Result<ConvertReport, JobError> {
    if !(period_s.is_finite() && period_s > 0.0) {
        return Err(JobError::bad_input(format!(
            "--period must be positive, got {period_s}"
        )));
    }
    let params = mapmerge_rosbag::BagWriteParams {
        rewritten_period_s: period_s,
        ..Default::default()
    };
    let started = Instant::now();
    let (read_secs, written) = if is_kitti_folder(log) {
        convert_kitti_folder(log, output, &params)?
    } else {
        convert_log(log, output, topics, &params)?
    };
    let write_secs = started.elapsed().as_secs_f64() - read_secs;
    let bytes = bytes_on_disk(log);
    Ok(ConvertReport {
        log: log.to_path_buf(),
        output: output.to_path_buf(),
        scans: written.messages,
        odometry_messages: written.odometry_messages,
        input_bytes: bytes,
        read_secs,
        read_mb_per_s: bytes as f64 / 1e6 / read_secs.max(1e-9),
        write_secs,
        output_bytes: bytes_on_disk(output),
        stamps_rewritten: written.stamps_rewritten,
    })
}

/// A KITTI-style folder (a 3D segment), not a bag directory.
pub fn is_kitti_folder(path: &Path) -> bool {
    path.is_dir() && !mapmerge_rosbag::is_bag(path)
}
