//! ROS 2 bags without ROS: rosbag2's two storage formats (MCAP and SQLite `.db3`, a single
//! file or a bag directory with `metadata.yaml`), CDR decoding of the messages a laser
//! session needs, and writing bags from laser logs.
//!
//! Entry points:
//! - [`read_log`]: a CARMEN log or a bag, whichever `path` is → [`LaserLog`], the one
//!   session type of every command that takes a LOG;
//! - [`read_bag`]: a bag → [`BagSession`] (the log and [`BagInfo`]: topics, frames, the
//!   laser's mount, scans left out); scans are paired with the odometry at their stamp,
//!   interpolated on SE(2), and the laser's mount comes from tf (`/tf_static`, else `/tf`);
//! - [`read_point_clouds`]: `sensor_msgs/msg/PointCloud2` messages → points;
//!   [`read_cloud_session`]: with the sensor's pose from odometry (interpolated on SE(3)) and
//!   tf, for the 3D path;
//! - [`write_bag`]: a [`LaserLog`] → `.mcap` or `.db3`; [`write_cloud_bag`]: clouds and poses;
//! - [`list_topics`]: what a bag holds;
//! - [`ScanAssembler`]: the same session assembled live, message by message (a robot's
//!   topics rather than a bag).
//!
//! Nothing here panics on input; every problem is an [`IoError`] naming the file and, for a
//! message, its topic and index.

mod clouds;
mod live;
mod maps;
mod messages;
mod msgdefs;
mod session;
mod storage;
mod write;

use std::path::Path;

use mapmerge_io::IoError;
use mapmerge_scan::LaserLog;

pub use clouds::{cloud_points, read_cloud_session, read_point_clouds, CloudSession, StampedCloud};
pub use live::{
    LiveDrops, LiveMount, ScanAssembler, LIVE_ODOMETRY_WAIT, LIVE_QUEUE_MAX, LIVE_WAIT,
};
pub use maps::{occupancy_grid_message, ros_map_of_message, MAP_CELLS_MAX};
pub use messages::{
    decode, encode, Header, LaserScanMessage, MapMetaData, OccupancyGridMessage, OdometryMessage,
    PointCloud2Message, PointField, Pose, Quaternion, TfMessage, Time, Transform, TransformStamped,
    Vector3, LASER_SCAN_TYPE, OCCUPANCY_GRID_TYPE, ODOMETRY_TYPE, POINT_CLOUD2_TYPE, TF_TYPE,
};
pub use msgdefs::definition as message_definition;
pub use session::{
    read_bag, BagInfo, BagSession, MountSource, TopicChoice, MAX_LASER_TILT_DEG, ODOMETRY_HOLD_S,
};
pub use storage::{is_bag, Storage, Topic};
pub use write::{write_bag, write_cloud_bag, BagWriteParams, BagWriteReport, MOUNT_TOLERANCE};

/// The topics of the bag at `path`, with their message counts.
pub fn list_topics(path: &Path) -> Result<Vec<Topic>, IoError> {
    Ok(storage::read_raw_bag(path, &|_| false)?.topics)
}

/// Reads a laser session from `path`: a rosbag2 bag (see [`is_bag`]) through [`read_bag`],
/// anything else as a CARMEN log (plain or xz).
pub fn read_log(path: &Path, choice: &TopicChoice) -> Result<LaserLog, IoError> {
    Ok(read_log_or_bag(path, choice)?.0)
}

/// [`read_log`], with what [`read_bag`] says of a bag (topics, frames, the laser's mount,
/// scans without odometry); `None` for a CARMEN log.
pub fn read_log_or_bag(
    path: &Path,
    choice: &TopicChoice,
) -> Result<(LaserLog, Option<BagInfo>), IoError> {
    if is_bag(path) {
        let session = read_bag(path, choice)?;
        Ok((session.log, Some(session.info)))
    } else {
        Ok((mapmerge_io::read_carmen(path)?, None))
    }
}

/// Reads the laser scans of one MCAP file's bytes, for fuzzing: every input gives a
/// session or an error, never a panic.
pub fn parse_mcap_session(bytes: &[u8], choice: &TopicChoice) -> Result<LaserLog, String> {
    let mut bag = storage::RawBag::default();
    storage::read_mcap(&mut bag, bytes, &|_| true)?;
    session::session_of(bag, choice).map(|session| session.log)
}
