//! A bag → the session type the CARMEN reader produces ([`LaserLog`]): each scan with the
//! odometry pose at its stamp (interpolated on SE(2)) and the laser's mount from tf.

use std::collections::HashMap;
use std::path::Path;

use mapmerge_geometry::{LieGroup, Se2, Se3};
use mapmerge_io::IoError;
use mapmerge_scan::{LaserLog, LaserScan, OdometryReading, ScanRecord};
use nalgebra::{UnitQuaternion, Vector3};

use crate::messages::{
    decode, LaserScanMessage, OdometryMessage, Quaternion, TfMessage, Transform, LASER_SCAN_TYPE,
    ODOMETRY_TYPE, TF_TYPE,
};
use crate::storage::{read_raw_bag, RawBag, Storage, Topic};

/// Which topics to read; `None` finds the one topic of the right type.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct TopicChoice {
    /// The `sensor_msgs/msg/LaserScan` topic.
    pub scan_topic: Option<String>,
    /// The `nav_msgs/msg/Odometry` topic.
    pub odom_topic: Option<String>,
}

/// A scan this far (s) before the first or after the last odometry message takes that
/// message's pose; farther out it has no odometry and is left out.
pub const ODOMETRY_HOLD_S: f64 = 0.05;

/// Largest angle (deg) between the laser's axis of rotation and the robot's vertical: a
/// planar scanner mounted within it is projected onto the plane, upright or upside down.
pub const MAX_LASER_TILT_DEG: f64 = 10.0;

/// Where the laser's mount came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MountSource {
    /// `/tf_static`.
    TfStatic,
    /// The first transform on `/tf` (no static one).
    Tf,
    /// The scans are in the robot's own frame.
    SameFrame,
    /// The bag has no tf at all: the laser is taken to sit at the robot's origin.
    NoTf,
}

impl MountSource {
    /// Where the mount came from, in words.
    pub fn describe(self) -> &'static str {
        match self {
            Self::TfStatic => "from /tf_static",
            Self::Tf => "from /tf",
            Self::SameFrame => "(the scans are in the robot's frame)",
            Self::NoTf => "(no tf in the bag: taken at the robot's origin)",
        }
    }
}

/// What was read, and how the session was put together.
#[derive(Clone, Debug, serde::Serialize)]
pub struct BagInfo {
    /// MCAP or SQLite.
    pub storage: Storage,
    /// Bytes read from disk.
    pub bytes: u64,
    /// Every topic of the bag.
    pub topics: Vec<Topic>,
    /// The scans' topic.
    pub scan_topic: String,
    /// The odometry's topic, if there is one.
    pub odom_topic: Option<String>,
    /// The scans' frame.
    pub laser_frame: String,
    /// The robot's frame (odometry's `child_frame_id`, else `base_link`).
    pub base_frame: String,
    /// The laser's mount on the robot, projected onto the plane.
    pub robot_from_sensor: Se2,
    /// True when the laser is mounted upside down (its beams are mirrored).
    pub laser_upside_down: bool,
    /// Where the mount came from.
    pub mount_from: MountSource,
    /// Scans left out: no odometry within [`ODOMETRY_HOLD_S`] of their stamp.
    pub scans_without_odometry: usize,
}

/// A bag read as a laser session.
#[derive(Clone, Debug)]
pub struct BagSession {
    /// The session, as the CARMEN reader gives it.
    pub log: LaserLog,
    /// How it was read.
    pub info: BagInfo,
}

fn invalid(file: &Path, reason: impl Into<String>) -> IoError {
    IoError::Invalid {
        file: file.display().to_string(),
        reason: reason.into(),
    }
}

/// The topic named `given`, or the only one of `message_type`; `None` when the bag has none
/// of that type and none was named.
pub(crate) fn choose_topic(
    topics: &[Topic],
    message_type: &str,
    given: Option<&str>,
    flag: &str,
) -> Result<Option<usize>, String> {
    let list = |pick: &dyn Fn(&Topic) -> bool| {
        let names: Vec<String> = topics
            .iter()
            .filter(|t| pick(t))
            .map(|t| format!("{} ({})", t.name, t.message_type))
            .collect();
        if names.is_empty() {
            "none".to_owned()
        } else {
            names.join(", ")
        }
    };
    let index = match given {
        Some(name) => {
            let index = topics
                .iter()
                .position(|t| t.name == name)
                .ok_or_else(|| format!("no topic '{name}' (topics: {})", list(&|_| true)))?;
            if topics[index].message_type != message_type {
                return Err(format!(
                    "topic '{name}' carries {}, not {message_type}",
                    topics[index].message_type
                ));
            }
            index
        }
        None => {
            let of_type: Vec<usize> = (0..topics.len())
                .filter(|&i| topics[i].message_type == message_type)
                .collect();
            match of_type.as_slice() {
                [] => return Ok(None),
                [only] => *only,
                _ => {
                    return Err(format!(
                        "several {message_type} topics: {}; choose one with {flag}",
                        list(&|t| t.message_type == message_type)
                    ))
                }
            }
        }
    };
    let topic = &topics[index];
    if topic.encoding != "cdr" {
        return Err(format!(
            "topic '{}' is serialised as '{}'; only CDR (ROS 2) is read",
            topic.name, topic.encoding
        ));
    }
    Ok(Some(index))
}

pub(crate) fn rotation_of(quaternion: &Quaternion) -> Option<UnitQuaternion<f64>> {
    let q = nalgebra::Quaternion::new(quaternion.w, quaternion.x, quaternion.y, quaternion.z);
    let norm = q.norm();
    (norm.is_finite() && norm > 1e-9).then(|| UnitQuaternion::from_quaternion(q))
}

fn se3_of(transform: &Transform) -> Option<Se3> {
    let t = &transform.translation;
    let translation = Vector3::new(t.x, t.y, t.z);
    translation
        .iter()
        .all(|v| v.is_finite())
        .then_some(())
        .and(rotation_of(&transform.rotation))
        .map(|rotation| Se3::new(rotation, translation))
}

/// Heading (rad) of a rotation about z, from its quaternion.
fn yaw_of(rotation: &UnitQuaternion<f64>) -> f64 {
    let matrix = rotation.to_rotation_matrix();
    matrix[(1, 0)].atan2(matrix[(0, 0)])
}

/// Transforms by child frame: `(parent, parent_from_child)`.
#[derive(Default)]
pub(crate) struct TfTree {
    edges: HashMap<String, (String, Se3)>,
}

impl TfTree {
    pub(crate) fn insert_first(&mut self, tf: &TfMessage) -> Result<(), String> {
        for stamped in &tf.transforms {
            let child = stamped.child_frame_id.trim_start_matches('/').to_owned();
            let parent = stamped.header.frame_id.trim_start_matches('/').to_owned();
            if self.edges.contains_key(&child) {
                continue;
            }
            let transform = se3_of(&stamped.transform).ok_or_else(|| {
                format!("the transform {parent} → {child} is not finite or has a zero quaternion")
            })?;
            self.edges.insert(child, (parent, transform));
        }
        Ok(())
    }

    /// `(frame, frame_from_start)` from `start` up to its root.
    fn chain(&self, start: &str) -> Vec<(String, Se3)> {
        let mut chain = vec![(start.to_owned(), Se3::identity())];
        while let Some((frame, from_start)) = chain.last() {
            let Some((parent, parent_from_frame)) = self.edges.get(frame) else {
                break;
            };
            if chain.len() > self.edges.len() || chain.iter().any(|(f, _)| f == parent) {
                break; // a cycle
            }
            let next = (parent.clone(), parent_from_frame.compose(from_start));
            chain.push(next);
        }
        chain
    }

    /// `base_from_laser` through the frames' first common ancestor.
    pub(crate) fn lookup(&self, base: &str, laser: &str) -> Option<Se3> {
        let base_chain = self.chain(base);
        self.chain(laser)
            .into_iter()
            .find_map(|(frame, frame_from_laser)| {
                base_chain
                    .iter()
                    .find(|(f, _)| *f == frame)
                    .map(|(_, frame_from_base)| {
                        frame_from_base.inverse().compose(&frame_from_laser)
                    })
            })
    }
}

/// Everything a bag's tf says: `/tf_static`, and the first transform of each edge on `/tf`.
#[derive(Default)]
pub(crate) struct Tf {
    static_tree: TfTree,
    dynamic_tree: TfTree,
    any: bool,
}

impl Tf {
    /// Takes one message of `topic` (a TFMessage topic; `…tf_static` is static).
    pub(crate) fn take(&mut self, topic: &Topic, data: &[u8]) -> Result<(), String> {
        let tf: TfMessage = decode(data)?;
        self.insert(&tf, topic.name.ends_with("tf_static"))
    }

    /// Takes one decoded message, from `/tf_static` when `is_static`.
    pub(crate) fn insert(&mut self, tf: &TfMessage, is_static: bool) -> Result<(), String> {
        self.any = true;
        if is_static {
            self.static_tree.insert_first(tf)
        } else {
            self.dynamic_tree.insert_first(tf)
        }
    }

    /// `base_from_sensor` and where it came from: identity for the same frame or a bag
    /// without tf, else through `/tf_static`, else `/tf`; an error when neither links them.
    pub(crate) fn mount(&self, base: &str, sensor: &str) -> Result<(Se3, MountSource), String> {
        if sensor == base || sensor.is_empty() {
            return Ok((Se3::identity(), MountSource::SameFrame));
        }
        if !self.any {
            return Ok((Se3::identity(), MountSource::NoTf));
        }
        if let Some(found) = self.static_tree.lookup(base, sensor) {
            return Ok((found, MountSource::TfStatic));
        }
        self.dynamic_tree
            .lookup(base, sensor)
            .map(|found| (found, MountSource::Tf))
            .ok_or_else(|| {
                format!("tf has no transform between the robot's frame '{base}' and the sensor's frame '{sensor}'")
            })
    }
}

/// `base_from_laser` on the plane, and whether the laser is upside down.
pub(crate) fn planar_mount(base_from_laser: &Se3) -> Result<(Se2, bool), String> {
    let rotation = base_from_laser.rotation.to_rotation_matrix();
    let up = rotation[(2, 2)];
    let tilt_deg = up.abs().clamp(-1.0, 1.0).acos().to_degrees();
    if tilt_deg > MAX_LASER_TILT_DEG {
        return Err(format!(
            "the laser is tilted {tilt_deg:.1}° from the robot's plane; a planar scanner within {MAX_LASER_TILT_DEG}° is needed"
        ));
    }
    let t = &base_from_laser.translation_m;
    Ok((
        Se2::new(t.x, t.y, yaw_of(&base_from_laser.rotation)),
        up < 0.0,
    ))
}

/// The pose at `stamp_secs` among stamped poses in non-decreasing stamp order: interpolated on
/// SE(2) between the two around it, held for [`ODOMETRY_HOLD_S`] past either end.
pub(crate) fn pose_at<const D: usize, G: LieGroup<D>>(
    stamps_secs: &[f64],
    poses: &[G],
    stamp_secs: f64,
) -> Option<G> {
    let after = stamps_secs.partition_point(|&t| t <= stamp_secs);
    let (first, last) = (stamps_secs.first()?, stamps_secs.last()?);
    if after == 0 {
        return (first - stamp_secs <= ODOMETRY_HOLD_S).then(|| poses[0]);
    }
    let before = after - 1;
    if stamps_secs[before] == stamp_secs {
        return Some(poses[before]);
    }
    if after == stamps_secs.len() {
        return (stamp_secs - last <= ODOMETRY_HOLD_S).then(|| poses[before]);
    }
    let fraction = (stamp_secs - stamps_secs[before]) / (stamps_secs[after] - stamps_secs[before]);
    Some(poses[before].interpolate(&poses[after], fraction))
}

/// The robot's pose in an odometry message's frame, on the plane (NaN yaw for a zero
/// quaternion).
pub(crate) fn odom_pose(odometry: &OdometryMessage) -> Se2 {
    let p = &odometry.pose.pose;
    let yaw = rotation_of(&p.orientation).map_or(f64::NAN, |_| p.orientation.yaw());
    Se2::new(p.position.x, p.position.y, yaw)
}

/// A laser's angles as recovered by [`angle_rad_of`], each distinct stored value once (the
/// scans of one laser share them).
#[derive(Default)]
pub(crate) struct Angles {
    recovered: HashMap<u32, f64>,
}

impl Angles {
    fn angle(&mut self, stored: f32) -> f64 {
        *self
            .recovered
            .entry(stored.to_bits())
            .or_insert_with(|| angle_rad_of(stored))
    }

    /// The scan record of `message` at `stamp_secs`, with its odometry pose and the laser's
    /// planar mount (its beams mirrored when it is upside down).
    pub(crate) fn record(
        &mut self,
        message: LaserScanMessage,
        stamp_secs: f64,
        odom_from_robot: Option<Se2>,
        robot_from_sensor: Se2,
        upside_down: bool,
    ) -> ScanRecord {
        let mirror = if upside_down { -1.0 } else { 1.0 };
        ScanRecord {
            stamp_secs,
            scan: LaserScan {
                angle_min_rad: mirror * self.angle(message.angle_min),
                angle_increment_rad: mirror * self.angle(message.angle_increment),
                range_min_m: message.range_min,
                range_max_m: message.range_max,
                ranges_m: message.ranges,
                robot_from_sensor,
            },
            odom_from_robot,
            source_tag: "LaserScan".to_owned(),
        }
    }
}

/// Largest denominator tried by [`angle_rad_of`]: π/2880 is 1/16 of a degree.
const MAX_ANGLE_DENOMINATOR: i64 = 2880;

/// Significant digits up to which a float32's shortest decimal is taken as the value it was
/// written from (laser logs print angles with six).
const DECIMAL_ANGLE_DIGITS: usize = 6;

/// The angle (rad) a LaserScan's float32 field most likely held before it was rounded to
/// float32: its shortest decimal when that has at most six significant digits (the angle was
/// printed, as in CARMEN's ROBOTLASER1), else the simplest multiple `p·π/q` (q ≤ 2880; scanners
/// step in fractions of a degree, drivers compute them in double) that rounds to the same
/// float32, else its shortest decimal. Whatever is chosen rounds back to `stored`, so nothing a
/// bag says is changed; scan matching is spared the float32 error (up to 6e-8 rad at ±π),
/// which is enough to flip a loop decision and move a trajectory by centimetres.
pub(crate) fn angle_rad_of(stored: f32) -> f64 {
    let decimal_text = format!("{stored:e}");
    let decimal: f64 = decimal_text.parse().unwrap_or(f64::from(stored));
    let digits = decimal_text.split('e').next().map_or(0, |mantissa| {
        mantissa.chars().filter(char::is_ascii_digit).count()
    });
    if !stored.is_finite() || digits <= DECIMAL_ANGLE_DIGITS {
        return decimal;
    }
    let turns = f64::from(stored) / std::f64::consts::PI;
    (1..=MAX_ANGLE_DENOMINATOR)
        .find_map(|q| {
            let p = (turns * q as f64).round();
            let candidate = p * std::f64::consts::PI / q as f64;
            (candidate as f32 == stored).then_some(candidate)
        })
        .unwrap_or(decimal)
}

/// Checks that `stamps` never decrease.
pub(crate) fn check_monotonic(stamps_secs: &[f64], topic: &str) -> Result<(), String> {
    // NaN counts as going back: `partial_cmp` gives no order.
    let goes_back = |w: &[f64]| {
        !matches!(
            w[1].partial_cmp(&w[0]),
            Some(std::cmp::Ordering::Greater | std::cmp::Ordering::Equal)
        )
    };
    match stamps_secs.windows(2).position(goes_back) {
        Some(i) => Err(format!(
            "{topic}: header stamps are not monotonic: message {} is stamped {} s, after {} s",
            i + 2,
            stamps_secs[i + 1],
            stamps_secs[i]
        )),
        None => Ok(()),
    }
}

/// Reads the bag at `path` (a `.mcap` or `.db3` file, or a bag directory) as a laser session.
pub fn read_bag(path: &Path, choice: &TopicChoice) -> Result<BagSession, IoError> {
    let wanted = |t: &str| t == LASER_SCAN_TYPE || t == ODOMETRY_TYPE || t == TF_TYPE;
    let raw = read_raw_bag(path, &wanted)?;
    session_of(raw, choice).map_err(|reason| invalid(path, reason))
}

pub(crate) fn session_of(raw: RawBag, choice: &TopicChoice) -> Result<BagSession, String> {
    let topics = &raw.topics;
    let scan_topic = choose_topic(
        topics,
        LASER_SCAN_TYPE,
        choice.scan_topic.as_deref(),
        "--scan-topic",
    )?
    .ok_or_else(|| {
        let names: Vec<&str> = topics.iter().map(|t| t.name.as_str()).collect();
        format!("no {LASER_SCAN_TYPE} topic (topics: {})", names.join(", "))
    })?;
    let odom_topic = choose_topic(
        topics,
        ODOMETRY_TYPE,
        choice.odom_topic.as_deref(),
        "--odom-topic",
    )?;
    let mut scans: Vec<LaserScanMessage> = Vec::new();
    let mut odometry: Vec<OdometryMessage> = Vec::new();
    let mut tf = Tf::default();
    let mut counts = vec![0usize; topics.len()];
    for message in &raw.messages {
        let topic = &topics[message.topic];
        counts[message.topic] += 1;
        let context = |reason: String| {
            format!(
                "topic '{}', message {}: {reason}",
                topic.name, counts[message.topic]
            )
        };
        if message.topic == scan_topic {
            scans.push(decode(&message.data).map_err(context)?);
        } else if Some(message.topic) == odom_topic {
            odometry.push(decode(&message.data).map_err(context)?);
        } else if topic.message_type == TF_TYPE && topic.encoding == "cdr" {
            tf.take(topic, &message.data).map_err(context)?;
        }
    }
    let scan_name = &topics[scan_topic].name;
    let first_scan = scans
        .first()
        .ok_or_else(|| format!("topic '{scan_name}' has no messages"))?;
    let laser_frame = first_scan
        .header
        .frame_id
        .trim_start_matches('/')
        .to_owned();
    let base_frame = odometry
        .first()
        .map(|o| o.child_frame_id.trim_start_matches('/'))
        .filter(|f| !f.is_empty())
        .unwrap_or("base_link")
        .to_owned();
    let (base_from_laser, mount_from) = tf.mount(&base_frame, &laser_frame)?;
    let (robot_from_sensor, upside_down) = planar_mount(&base_from_laser)?;

    let scan_stamps: Vec<f64> = scans.iter().map(|s| s.header.stamp.seconds()).collect();
    check_monotonic(&scan_stamps, scan_name)?;
    let odom_stamps: Vec<f64> = odometry.iter().map(|o| o.header.stamp.seconds()).collect();
    if let Some(odom) = odom_topic {
        check_monotonic(&odom_stamps, &topics[odom].name)?;
    }
    let odom_poses: Vec<Se2> = odometry.iter().map(odom_pose).collect();
    if let Some(bad) = odom_poses.iter().position(|p| !p.is_finite()) {
        return Err(format!(
            "odometry message {}: the pose is not finite or its quaternion is zero",
            bad + 1
        ));
    }

    let mut log = LaserLog {
        odometry: odometry
            .iter()
            .zip(&odom_poses)
            .map(|(o, pose)| OdometryReading {
                stamp_secs: o.header.stamp.seconds(),
                odom_from_robot: *pose,
                velocity_m_per_s: o.twist.twist.linear.x,
                turn_rate_rad_per_s: o.twist.twist.angular.z,
            })
            .collect(),
        ..Default::default()
    };
    let mut scans_without_odometry = 0;
    let mut angles = Angles::default();
    for (message, stamp_secs) in scans.into_iter().zip(scan_stamps) {
        let odom_from_robot = match odom_topic {
            Some(_) => match pose_at(&odom_stamps, &odom_poses, stamp_secs) {
                Some(pose) => Some(pose),
                None => {
                    scans_without_odometry += 1;
                    continue;
                }
            },
            None => None,
        };
        log.scans.push(angles.record(
            message,
            stamp_secs,
            odom_from_robot,
            robot_from_sensor,
            upside_down,
        ));
    }
    if log.scans.is_empty() {
        return Err(format!(
            "none of the {scans_without_odometry} scans on '{scan_name}' has odometry within {ODOMETRY_HOLD_S} s of its stamp"
        ));
    }
    let info = BagInfo {
        storage: raw.storage.unwrap_or(Storage::Mcap),
        bytes: raw.bytes,
        topics: raw.topics.clone(),
        scan_topic: scan_name.clone(),
        odom_topic: odom_topic.map(|i| raw.topics[i].name.clone()),
        laser_frame,
        base_frame,
        robot_from_sensor,
        laser_upside_down: upside_down,
        mount_from,
        scans_without_odometry,
    };
    Ok(BagSession { log, info })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_interpolate_between_stamps_and_hold_briefly_at_the_ends() {
        let stamps = [1.0, 2.0];
        let poses = [Se2::new(0.0, 0.0, 0.0), Se2::new(2.0, 0.0, 0.2)];
        let mid = pose_at(&stamps, &poses, 1.5).unwrap();
        assert!(
            (mid.x_m - 1.0).abs() < 0.02 && (mid.theta_rad - 0.1).abs() < 1e-12,
            "{mid:?}"
        );
        assert_eq!(pose_at(&stamps, &poses, 2.0), Some(poses[1]));
        assert_eq!(pose_at(&stamps, &poses, 0.97), Some(poses[0]));
        assert_eq!(pose_at(&stamps, &poses, 2.04), Some(poses[1]));
        assert_eq!(pose_at(&stamps, &poses, 0.9), None);
        assert_eq!(pose_at(&stamps, &poses, 2.1), None);
        assert_eq!(pose_at::<3, Se2>(&[], &[], 2.1), None);
    }

    #[test]
    fn tf_chains_meet_at_a_common_ancestor() {
        let edge =
            |parent: &str, child: &str, x: f64, yaw: f64| crate::messages::TransformStamped {
                header: crate::messages::Header {
                    frame_id: parent.into(),
                    ..Default::default()
                },
                child_frame_id: child.into(),
                transform: Transform {
                    translation: crate::messages::Vector3 { x, y: 0.0, z: 0.3 },
                    rotation: Quaternion::from_yaw(yaw),
                },
            };
        let mut tree = TfTree::default();
        tree.insert_first(&TfMessage {
            transforms: vec![
                edge("base_footprint", "base_link", 0.1, 0.0),
                edge("base_link", "laser_mount", 0.2, 0.5),
                edge("laser_mount", "laser", 0.0, 0.25),
            ],
        })
        .unwrap();
        let (mount, upside_down) =
            planar_mount(&tree.lookup("base_link", "laser").unwrap()).unwrap();
        assert!(!upside_down);
        assert!((mount.x_m - 0.2).abs() < 1e-12 && (mount.theta_rad - 0.75).abs() < 1e-12);
        // Seen from a sibling's child: through base_footprint.
        let back = tree.lookup("laser", "base_footprint").unwrap();
        let (planar, _) = planar_mount(&back).unwrap();
        let expected = Se2::new(0.3, 0.0, 0.75).inverse();
        assert!(
            (planar.x_m - expected.x_m).abs() < 1e-12 && (planar.y_m - expected.y_m).abs() < 1e-12
        );
        assert!(tree.lookup("base_link", "camera").is_none());
    }

    #[test]
    fn upside_down_and_tilted_lasers() {
        let flipped = Se3::new(
            UnitQuaternion::from_euler_angles(std::f64::consts::PI, 0.0, 0.4),
            Vector3::new(0.1, 0.0, 0.0),
        );
        let (mount, upside_down) = planar_mount(&flipped).unwrap();
        assert!(
            upside_down && (mount.theta_rad - 0.4).abs() < 1e-9,
            "{mount:?}"
        );
        let tilted = Se3::new(
            UnitQuaternion::from_euler_angles(0.0, 0.3, 0.0),
            Vector3::zeros(),
        );
        assert!(planar_mount(&tilted).unwrap_err().contains("tilted 17.2°"));
    }

    #[test]
    fn topics_are_found_by_type_or_named() {
        let topic = |name: &str, message_type: &str| Topic {
            name: name.into(),
            message_type: message_type.into(),
            encoding: "cdr".into(),
            messages: 1,
        };
        let topics = vec![
            topic("/scan", LASER_SCAN_TYPE),
            topic("/scan_rear", LASER_SCAN_TYPE),
            topic("/odom", ODOMETRY_TYPE),
        ];
        assert_eq!(
            choose_topic(&topics, ODOMETRY_TYPE, None, "--odom-topic"),
            Ok(Some(2))
        );
        let err = choose_topic(&topics, LASER_SCAN_TYPE, None, "--scan-topic").unwrap_err();
        assert!(
            err.contains("several") && err.contains("/scan_rear") && err.contains("--scan-topic"),
            "{err}"
        );
        assert_eq!(
            choose_topic(&topics, LASER_SCAN_TYPE, Some("/scan_rear"), "--scan-topic"),
            Ok(Some(1))
        );
        assert!(choose_topic(&topics, LASER_SCAN_TYPE, Some("/odom"), "x")
            .unwrap_err()
            .contains("carries nav_msgs/msg/Odometry"));
        assert!(choose_topic(&topics, LASER_SCAN_TYPE, Some("/nope"), "x")
            .unwrap_err()
            .contains("no topic '/nope'"));
        assert_eq!(choose_topic(&topics, TF_TYPE, None, "x"), Ok(None));
        let json = vec![Topic {
            encoding: "json".into(),
            ..topic("/odom", ODOMETRY_TYPE)
        }];
        assert!(choose_topic(&json, ODOMETRY_TYPE, None, "x")
            .unwrap_err()
            .contains("only CDR"));
    }

    /// A bag in memory: scans at `scan_stamps`, odometry at `odom_stamps` (s).
    fn raw_bag(scan_stamps: &[i32], odom_stamps: &[i32], scan_encoding: &str) -> RawBag {
        let topic = |name: &str, message_type: &str, encoding: &str| Topic {
            name: name.into(),
            message_type: message_type.into(),
            encoding: encoding.into(),
            messages: 0,
        };
        let mut bag = RawBag {
            topics: vec![
                topic("/scan", LASER_SCAN_TYPE, scan_encoding),
                topic("/odom", ODOMETRY_TYPE, "cdr"),
            ],
            ..Default::default()
        };
        let stamp = |sec| crate::messages::Header {
            stamp: crate::messages::Time { sec, nanosec: 0 },
            frame_id: String::new(),
        };
        for &sec in scan_stamps {
            let scan = LaserScanMessage {
                header: stamp(sec),
                ranges: vec![1.0; 4],
                ..Default::default()
            };
            let data = crate::messages::encode(&scan).unwrap();
            bag.messages.push(crate::storage::RawMessage {
                topic: 0,
                log_time_ns: 0,
                data,
            });
        }
        for &sec in odom_stamps {
            let odometry = OdometryMessage {
                header: stamp(sec),
                ..Default::default()
            };
            let data = crate::messages::encode(&odometry).unwrap();
            bag.messages.push(crate::storage::RawMessage {
                topic: 1,
                log_time_ns: 0,
                data,
            });
        }
        bag
    }

    #[test]
    fn sessions_refuse_backward_stamps_and_other_encodings() {
        let ok = session_of(
            raw_bag(&[1, 2, 3], &[1, 2, 3], "cdr"),
            &TopicChoice::default(),
        )
        .unwrap();
        assert_eq!(
            (ok.log.scans.len(), ok.info.mount_from),
            (3, MountSource::SameFrame)
        );
        let err = session_of(
            raw_bag(&[1, 3, 2], &[1, 2, 3], "cdr"),
            &TopicChoice::default(),
        )
        .unwrap_err();
        assert!(
            err.contains("/scan: header stamps are not monotonic: message 3"),
            "{err}"
        );
        let err =
            session_of(raw_bag(&[1, 2], &[2, 1], "cdr"), &TopicChoice::default()).unwrap_err();
        assert!(
            err.contains("/odom: header stamps are not monotonic"),
            "{err}"
        );
        let err =
            session_of(raw_bag(&[1, 2], &[1, 2], "ros1"), &TopicChoice::default()).unwrap_err();
        assert!(err.contains("serialised as 'ros1'"), "{err}");
        let err =
            session_of(raw_bag(&[5, 6], &[1, 2], "cdr"), &TopicChoice::default()).unwrap_err();
        assert!(err.contains("none of the 2 scans"), "{err}");
        let mut corrupt = raw_bag(&[1, 2], &[1, 2], "cdr");
        corrupt.messages[1].data.truncate(20);
        let err = session_of(corrupt, &TopicChoice::default()).unwrap_err();
        assert!(
            err.contains("topic '/scan', message 2: malformed CDR"),
            "{err}"
        );
    }

    #[test]
    #[allow(clippy::approx_constant)] // printed angles such as −1.5708 are the point
    fn float32_angles_recover_the_value_they_were_rounded_from() {
        use std::f64::consts::PI;
        // Multiples of π, as drivers and CARMEN's FLASER compute them.
        for angle in [
            -PI / 2.0,
            PI / 180.0,
            PI / 179.0,
            PI / 720.0,
            -3.0 * PI / 4.0,
            2.0 * PI / 1440.0,
            PI / 360.0,
        ] {
            assert_eq!(angle_rad_of(angle as f32), angle, "{angle}");
        }
        // Printed decimals, as in ROBOTLASER1.
        for angle in [-1.5708, 0.0174533, 0.00436332, 0.5, 0.0] {
            assert_eq!(angle_rad_of(angle as f32), angle, "{angle}");
        }
        // Anything else stays the float32 value, and the choice always rounds back to it.
        for stored in [0.123_456_78f32, -2.987_654_3, 1e-7, f32::MAX] {
            let recovered = angle_rad_of(stored);
            assert_eq!(recovered as f32, stored);
        }
        assert!(angle_rad_of(f32::NAN).is_nan());
    }

    #[test]
    fn stamps_must_not_go_back() {
        assert!(check_monotonic(&[1.0, 1.0, 2.0], "/scan").is_ok());
        let err = check_monotonic(&[1.0, 3.0, 2.0], "/scan").unwrap_err();
        assert!(err.contains("message 3 is stamped 2 s, after 3 s"), "{err}");
        assert!(check_monotonic(&[1.0, f64::NAN], "/scan").is_err());
    }
}
