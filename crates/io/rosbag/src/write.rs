//! A laser session → a rosbag2 bag (one `.mcap` or `.db3` file): `/scan` (LaserScan), `/odom`
//! (Odometry, one per scan at its stamp when the scans carry poses, else the log's odometry
//! messages) and `/tf_static` (the laser's mount).

use std::collections::BTreeMap;
use std::path::Path;

use mapmerge_geometry::{LieGroup as _, Se2, Se3};
use mapmerge_io::IoError;
use mapmerge_scan::LaserLog;

use crate::messages::{
    encode, Header, LaserScanMessage, OdometryMessage, PointCloud2Message, PointField, Quaternion,
    TfMessage, Time, Transform, TransformStamped, Vector3, LASER_SCAN_TYPE, ODOMETRY_TYPE,
    POINT_CLOUD2_TYPE, TF_TYPE,
};
use crate::storage::Storage;

/// Names and clock of a written bag.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BagWriteParams {
    /// Topic of the scans.
    pub scan_topic: String,
    /// Topic of the odometry.
    pub odom_topic: String,
    /// The odometry's frame.
    pub odom_frame: String,
    /// The robot's frame.
    pub base_frame: String,
    /// The laser's frame.
    pub laser_frame: String,
    /// Scan period (s) of the clock written when the log's own stamps are unusable.
    pub rewritten_period_s: f64,
}

impl Default for BagWriteParams {
    fn default() -> Self {
        Self {
            scan_topic: "/scan".into(),
            odom_topic: "/odom".into(),
            odom_frame: "odom".into(),
            base_frame: "base_link".into(),
            laser_frame: "laser".into(),
            rewritten_period_s: 0.1,
        }
    }
}

/// What was written.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct BagWriteReport {
    /// MCAP or SQLite.
    pub storage: Storage,
    /// Scans written.
    pub scans: usize,
    /// Odometry messages written.
    pub odometry_messages: usize,
    /// Why the log's stamps were replaced by a clock of `rewritten_period_s`, if they were
    /// (a bag needs increasing stamps to pair scans with odometry; some CARMEN logs have
    /// constant or broken ones).
    pub stamps_rewritten: Option<String>,
    /// Bytes of the file.
    pub bytes: u64,
}

/// Largest difference between the scans' mounts (m or rad) that one `/tf_static` still stands
/// for; the CARMEN reader derives each scan's mount from two rounded poses.
pub const MOUNT_TOLERANCE: f64 = 1e-3;

/// One message to write: topic index into the written topics, stamp, CDR bytes.
struct Outgoing {
    topic: usize,
    stamp: Time,
    data: Vec<u8>,
}

/// Largest stamp (s) a ROS `Time` holds (its `sec` is an i32).
const MAX_ROS_TIME_S: f64 = i32::MAX as f64;

fn stamp_of(seconds: f64) -> Time {
    Time::from_nanoseconds((seconds * 1e9).round() as i64).unwrap_or_default()
}

fn transform_of(pose: &Se2) -> Transform {
    Transform {
        translation: Vector3 {
            x: pose.x_m,
            y: pose.y_m,
            z: 0.0,
        },
        rotation: Quaternion::from_yaw(pose.theta_rad),
    }
}

/// The messages of `log`, sorted by stamp, and the report's counts.
fn messages_of(
    log: &LaserLog,
    params: &BagWriteParams,
) -> Result<(Vec<Outgoing>, BagWriteReport), String> {
    let first = log.scans.first().ok_or("the log has no scans")?;
    let mount = first.scan.robot_from_sensor;
    if let Some(i) = log.scans.iter().position(|r| {
        let d = mount.between(&r.scan.robot_from_sensor);
        d.x_m.abs().max(d.y_m.abs()).max(d.theta_rad.abs()) > MOUNT_TOLERANCE
    }) {
        return Err(format!(
            "scan {} has another laser mount than the first; one /tf_static cannot hold both",
            i + 1
        ));
    }
    let (mut seconds, mut rewritten) = log.increasing_scan_stamps(params.rewritten_period_s);
    if rewritten.is_none() {
        if let Some(i) = seconds
            .iter()
            .position(|t| !(0.0..MAX_ROS_TIME_S).contains(t))
        {
            rewritten = Some(format!(
                "scan {} is stamped {} s, outside a ROS time",
                i + 1,
                seconds[i]
            ));
            seconds = (0..seconds.len())
                .map(|k| k as f64 * params.rewritten_period_s)
                .collect();
        }
    }
    let stamps: Vec<Time> = seconds.iter().map(|&t| stamp_of(t)).collect();
    let header = |stamp: Time, frame: &str| Header {
        stamp,
        frame_id: frame.to_owned(),
    };
    let mut outgoing = Vec::with_capacity(2 * log.scans.len() + 1);
    let tf = TfMessage {
        transforms: vec![TransformStamped {
            header: header(stamps[0], &params.base_frame),
            child_frame_id: params.laser_frame.clone(),
            transform: transform_of(&mount),
        }],
    };
    outgoing.push(Outgoing {
        topic: 2,
        stamp: stamps[0],
        data: encode(&tf)?,
    });
    for (record, stamp) in log.scans.iter().zip(&stamps) {
        let scan = &record.scan;
        let beams = scan.ranges_m.len().saturating_sub(1) as f64;
        let message = LaserScanMessage {
            header: header(*stamp, &params.laser_frame),
            angle_min: scan.angle_min_rad as f32,
            angle_max: (scan.angle_min_rad + beams * scan.angle_increment_rad) as f32,
            angle_increment: scan.angle_increment_rad as f32,
            time_increment: 0.0,
            scan_time: 0.0,
            range_min: scan.range_min_m,
            range_max: scan.range_max_m,
            ranges: scan.ranges_m.clone(),
            intensities: Vec::new(),
        };
        outgoing.push(Outgoing {
            topic: 0,
            stamp: *stamp,
            data: encode(&message)?,
        });
    }
    let odometry = |stamp: Time, pose: &Se2, velocity: f64, turn_rate: f64| {
        let mut message = OdometryMessage {
            header: header(stamp, &params.odom_frame),
            child_frame_id: params.base_frame.clone(),
            ..Default::default()
        };
        message.pose.pose.position = Vector3 {
            x: pose.x_m,
            y: pose.y_m,
            z: 0.0,
        };
        message.pose.pose.orientation = Quaternion::from_yaw(pose.theta_rad);
        message.twist.twist.linear.x = velocity;
        message.twist.twist.angular.z = turn_rate;
        encode(&message)
    };
    let mut odometry_messages = 0;
    if log.scans.iter().all(|r| r.odom_from_robot.is_some()) {
        for (record, stamp) in log.scans.iter().zip(&stamps) {
            if let Some(pose) = &record.odom_from_robot {
                outgoing.push(Outgoing {
                    topic: 1,
                    stamp: *stamp,
                    data: odometry(*stamp, pose, 0.0, 0.0)?,
                });
                odometry_messages += 1;
            }
        }
    } else if !log.odometry.is_empty() {
        if let Some(reason) = &rewritten {
            return Err(format!("the scans carry no poses and their stamps cannot pair them with odometry: {reason}"));
        }
        for reading in &log.odometry {
            let stamp = stamp_of(reading.stamp_secs);
            let data = odometry(
                stamp,
                &reading.odom_from_robot,
                reading.velocity_m_per_s,
                reading.turn_rate_rad_per_s,
            )?;
            outgoing.push(Outgoing {
                topic: 1,
                stamp,
                data,
            });
            odometry_messages += 1;
        }
    }
    outgoing.sort_by_key(|m| m.stamp);
    let report = BagWriteReport {
        storage: Storage::Mcap,
        scans: log.scans.len(),
        odometry_messages,
        stamps_rewritten: rewritten,
        bytes: 0,
    };
    Ok((outgoing, report))
}

/// Writes `log` as a bag at `path`; the extension picks the storage (`.mcap` or `.db3`).
pub fn write_bag(
    path: &Path,
    log: &LaserLog,
    params: &BagWriteParams,
) -> Result<BagWriteReport, IoError> {
    let storage = storage_of(path)?;
    let (messages, mut report) = messages_of(log, params).map_err(unwritable)?;
    let topics = [
        (params.scan_topic.as_str(), LASER_SCAN_TYPE),
        (params.odom_topic.as_str(), ODOMETRY_TYPE),
        ("/tf_static", TF_TYPE),
    ];
    report.storage = storage;
    report.bytes = write_messages(path, storage, &topics, &messages)?;
    Ok(report)
}

/// Writes a 3D session as a bag at `path` (`.mcap` or `.db3`): `/points` (PointCloud2, `x y z`
/// float32, in the robot's frame `params.base_frame`) and `/odom` (the sensor's pose
/// `world_from_sensor` as the robot's), one each per cloud, `params.rewritten_period_s` apart
/// from 0 s.
pub fn write_cloud_bag(
    path: &Path,
    world_from_sensor: &[Se3],
    clouds: &[Vec<nalgebra::Vector3<f64>>],
    params: &BagWriteParams,
) -> Result<BagWriteReport, IoError> {
    let storage = storage_of(path)?;
    if clouds.len() != world_from_sensor.len() || clouds.is_empty() {
        return Err(unwritable(format!(
            "{} clouds and {} poses",
            clouds.len(),
            world_from_sensor.len()
        )));
    }
    let mut messages = Vec::with_capacity(2 * clouds.len());
    for (k, (cloud, pose)) in clouds.iter().zip(world_from_sensor).enumerate() {
        let stamp = stamp_of(k as f64 * params.rewritten_period_s);
        let header = Header {
            stamp,
            frame_id: params.base_frame.clone(),
        };
        let field = |name: &str, offset| PointField {
            name: name.into(),
            offset,
            datatype: 7,
            count: 1,
        };
        let mut data = Vec::with_capacity(12 * cloud.len());
        for point in cloud {
            for v in [point.x, point.y, point.z] {
                data.extend_from_slice(&(v as f32).to_le_bytes());
            }
        }
        let message = PointCloud2Message {
            header: header.clone(),
            height: 1,
            width: cloud.len() as u32,
            fields: vec![field("x", 0), field("y", 4), field("z", 8)],
            is_bigendian: false,
            point_step: 12,
            row_step: 12 * cloud.len() as u32,
            data: serde_bytes::ByteBuf::from(data),
            is_dense: true,
        };
        messages.push(Outgoing {
            topic: 0,
            stamp,
            data: encode(&message).map_err(unwritable)?,
        });
        let mut odometry = OdometryMessage {
            header: Header {
                stamp,
                frame_id: params.odom_frame.clone(),
            },
            child_frame_id: params.base_frame.clone(),
            ..Default::default()
        };
        let (t, q) = (&pose.translation_m, pose.rotation.quaternion());
        odometry.pose.pose.position = Vector3 {
            x: t.x,
            y: t.y,
            z: t.z,
        };
        odometry.pose.pose.orientation = Quaternion {
            x: q.i,
            y: q.j,
            z: q.k,
            w: q.w,
        };
        messages.push(Outgoing {
            topic: 1,
            stamp,
            data: encode(&odometry).map_err(unwritable)?,
        });
    }
    let topics = [
        ("/points", POINT_CLOUD2_TYPE),
        (params.odom_topic.as_str(), ODOMETRY_TYPE),
    ];
    let bytes = write_messages(path, storage, &topics, &messages)?;
    Ok(BagWriteReport {
        storage,
        scans: clouds.len(),
        odometry_messages: clouds.len(),
        stamps_rewritten: None,
        bytes,
    })
}

/// A writing error: the data cannot be written as a bag.
fn unwritable(reason: String) -> IoError {
    IoError::Unwritable {
        format: "rosbag2",
        reason,
    }
}

/// The storage a bag's file name asks for.
fn storage_of(path: &Path) -> Result<Storage, IoError> {
    Storage::of_file(path)
        .ok_or_else(|| unwritable(format!("{}: name the bag .mcap or .db3", path.display())))
}

/// Writes `messages` on `topics` into `path` in `storage`; returns the file's bytes.
fn write_messages(
    path: &Path,
    storage: Storage,
    topics: &[(&str, &str)],
    messages: &[Outgoing],
) -> Result<u64, IoError> {
    let file = path.display().to_string();
    let written = match storage {
        Storage::Mcap => write_mcap(path, topics, messages),
        Storage::Sqlite3 => write_db3(path, topics, messages),
    };
    written.map_err(|reason| IoError::Invalid {
        file: file.clone(),
        reason,
    })?;
    std::fs::metadata(path)
        .map(|m| m.len())
        .map_err(|source| IoError::Io { file, source })
}

fn write_mcap(path: &Path, topics: &[(&str, &str)], messages: &[Outgoing]) -> Result<(), String> {
    let file = std::fs::File::create(path).map_err(|e| format!("cannot create: {e}"))?;
    let mcap_error = |e: mcap::McapError| format!("cannot write MCAP: {e}");
    let options = mcap::WriteOptions::new()
        .profile("ros2")
        .library("mapmerge");
    let mut writer = options
        .create(std::io::BufWriter::new(file))
        .map_err(mcap_error)?;
    let mut channels = Vec::with_capacity(topics.len());
    for (topic, message_type) in topics {
        let schema = writer
            .add_schema(
                message_type,
                "ros2msg",
                crate::msgdefs::definition(message_type).as_bytes(),
            )
            .map_err(mcap_error)?;
        channels.push(
            writer
                .add_channel(schema, topic, "cdr", &BTreeMap::new())
                .map_err(mcap_error)?,
        );
    }
    for (sequence, message) in messages.iter().enumerate() {
        let time = u64::try_from(message.stamp.nanoseconds()).unwrap_or(0);
        let header = mcap::records::MessageHeader {
            channel_id: channels[message.topic],
            sequence: sequence as u32,
            log_time: time,
            publish_time: time,
        };
        writer
            .write_to_known_channel(&header, &message.data)
            .map_err(mcap_error)?;
    }
    writer.finish().map_err(mcap_error)?;
    Ok(())
}

/// rosbag2's SQLite schema (version 4, as Jazzy writes it).
const DB3_SCHEMA: &str = "
CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);
CREATE TABLE metadata(id INTEGER PRIMARY KEY, metadata_version INTEGER NOT NULL, metadata TEXT NOT NULL);
CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL, serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL, type_description_hash TEXT NOT NULL);
CREATE TABLE message_definitions(id INTEGER PRIMARY KEY, topic_type TEXT NOT NULL, encoding TEXT NOT NULL, encoded_message_definition TEXT NOT NULL, type_description_hash TEXT NOT NULL);
CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, timestamp INTEGER NOT NULL, data BLOB NOT NULL);
CREATE INDEX timestamp_idx ON messages (timestamp ASC);
INSERT INTO schema VALUES (4, 'jazzy');
";

fn write_db3(path: &Path, topics: &[(&str, &str)], messages: &[Outgoing]) -> Result<(), String> {
    let sql = |e: rusqlite::Error| format!("cannot write SQLite: {e}");
    if path.exists() {
        std::fs::remove_file(path).map_err(|e| format!("cannot replace the file: {e}"))?;
    }
    let mut connection = rusqlite::Connection::open(path).map_err(sql)?;
    connection.execute_batch(DB3_SCHEMA).map_err(sql)?;
    let transaction = connection.transaction().map_err(sql)?;
    for (id, (topic, message_type)) in topics.iter().enumerate() {
        transaction
            .execute(
                "INSERT INTO topics VALUES (?1, ?2, ?3, 'cdr', '', '')",
                (id as i64 + 1, topic, message_type),
            )
            .map_err(sql)?;
        transaction
            .execute(
                "INSERT INTO message_definitions VALUES (?1, ?2, 'ros2msg', ?3, '')",
                (
                    id as i64 + 1,
                    message_type,
                    crate::msgdefs::definition(message_type),
                ),
            )
            .map_err(sql)?;
    }
    {
        let mut insert = transaction
            .prepare("INSERT INTO messages (topic_id, timestamp, data) VALUES (?1, ?2, ?3)")
            .map_err(sql)?;
        for message in messages {
            insert
                .execute((
                    message.topic as i64 + 1,
                    message.stamp.nanoseconds(),
                    &message.data,
                ))
                .map_err(sql)?;
        }
    }
    transaction.commit().map_err(sql)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn broken_stamps_are_replaced_by_a_clock_and_named() {
        use mapmerge_scan::{LaserScan, ScanRecord};
        let log_with = |stamps: &[f64]| LaserLog {
            scans: stamps
                .iter()
                .map(|&stamp_secs| ScanRecord {
                    stamp_secs,
                    scan: LaserScan::new(-1.0, 1.0, 10.0, vec![1.0; 3]),
                    odom_from_robot: Some(Se2::identity()),
                    source_tag: "FLASER".into(),
                })
                .collect(),
            ..Default::default()
        };
        let params = BagWriteParams::default();
        let stamps = |log: &LaserLog| {
            let (messages, report) = messages_of(log, &params).unwrap();
            let scans: Vec<f64> = messages
                .iter()
                .filter(|m| m.topic == 0)
                .map(|m| m.stamp.seconds())
                .collect();
            (scans, report.stamps_rewritten)
        };
        assert_eq!(stamps(&log_with(&[5.0, 5.5])), (vec![5.0, 5.5], None));
        let (clock, why) = stamps(&log_with(&[3.0, 3.0, 3.0]));
        assert!(
            (clock[2] - 3.2).abs() < 1e-9 && why.unwrap().contains("do not increase at scan 2")
        );
        let (clock, why) = stamps(&log_with(&[-0.4, 0.0]));
        assert!((clock[1] - 0.1).abs() < 1e-9 && why.unwrap().contains("outside a ROS time"));
    }
}
