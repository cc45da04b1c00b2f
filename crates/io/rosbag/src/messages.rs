//! The ROS 2 messages mapmerge reads and writes, declared once as serde structs in the field
//! order of their ROS 2 interface definitions, and the CDR encapsulation around them (OMG
//! XTypes §7.6.3: a 4-byte header, then the payload aligned relative to its own start).

use byteorder::{BigEndian, LittleEndian};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

/// `sensor_msgs/msg/LaserScan`.
pub const LASER_SCAN_TYPE: &str = "sensor_msgs/msg/LaserScan";
/// `nav_msgs/msg/Odometry`.
pub const ODOMETRY_TYPE: &str = "nav_msgs/msg/Odometry";
/// `tf2_msgs/msg/TFMessage`, on `/tf` and `/tf_static`.
pub const TF_TYPE: &str = "tf2_msgs/msg/TFMessage";
/// `sensor_msgs/msg/PointCloud2`.
pub const POINT_CLOUD2_TYPE: &str = "sensor_msgs/msg/PointCloud2";
/// `nav_msgs/msg/OccupancyGrid`, on `/map`.
pub const OCCUPANCY_GRID_TYPE: &str = "nav_msgs/msg/OccupancyGrid";

/// `builtin_interfaces/msg/Time`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Time {
    /// Whole seconds.
    pub sec: i32,
    /// Nanoseconds within the second, `0..1e9`.
    pub nanosec: u32,
}

impl Time {
    /// The stamp in seconds.
    pub fn seconds(&self) -> f64 {
        f64::from(self.sec) + 1e-9 * f64::from(self.nanosec)
    }
    /// The stamp in nanoseconds.
    pub fn nanoseconds(&self) -> i64 {
        i64::from(self.sec) * 1_000_000_000 + i64::from(self.nanosec)
    }
    /// The stamp of `nanoseconds`; `None` outside `Time`'s range (negative, or past 2038).
    pub fn from_nanoseconds(nanoseconds: i64) -> Option<Self> {
        let sec = i32::try_from(nanoseconds.div_euclid(1_000_000_000)).ok()?;
        let nanosec = u32::try_from(nanoseconds.rem_euclid(1_000_000_000)).ok()?;
        (sec >= 0).then_some(Self { sec, nanosec })
    }
}

/// `std_msgs/msg/Header`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// When the data was taken.
    pub stamp: Time,
    /// The frame the data is expressed in.
    pub frame_id: String,
}

/// `sensor_msgs/msg/LaserScan`: beam `i` at `angle_min + i · angle_increment` (rad, sensor frame).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LaserScanMessage {
    /// Stamp of the first beam and the laser's frame.
    pub header: Header,
    /// Angle of the first beam (rad).
    pub angle_min: f32,
    /// Angle of the last beam (rad).
    pub angle_max: f32,
    /// Angle between beams (rad).
    pub angle_increment: f32,
    /// Time between beams (s).
    pub time_increment: f32,
    /// Time between scans (s).
    pub scan_time: f32,
    /// Shortest valid range (m).
    pub range_min: f32,
    /// Longest valid range (m).
    pub range_max: f32,
    /// One range per beam (m).
    pub ranges: Vec<f32>,
    /// Intensities (device units), empty or one per beam.
    pub intensities: Vec<f32>,
}

/// `geometry_msgs/msg/Vector3`, and `geometry_msgs/msg/Point`, which has the same fields.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `geometry_msgs/msg/Quaternion`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

impl Default for Quaternion {
    /// The identity rotation.
    fn default() -> Self {
        Self {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }
    }
}

/// How many float64 steps [`Quaternion::from_yaw`] moves `z` and `w` to find a quaternion whose
/// [`Quaternion::yaw`] is the given yaw exactly.
const YAW_SEARCH_ULPS: i64 = 8;

/// `value` moved by `steps` float64 steps (ulps).
fn ulp_step(value: f64, steps: i64) -> f64 {
    let bits = value.to_bits() as i64;
    let moved = if value >= 0.0 {
        bits + steps
    } else {
        bits - steps
    };
    f64::from_bits(moved as u64)
}

impl Quaternion {
    /// The rotation by `yaw_rad` about z: `(0, 0, sin(yaw/2), cos(yaw/2))`, with `z` and `w`
    /// moved by a few float64 steps where that makes [`Quaternion::yaw`] give back `yaw_rad`
    /// bit for bit (the quaternion is then unit to 1e-15). A pose written and read back is
    /// then the same pose: scan matching is chaotic enough that a one-ulp heading changes
    /// which loops close (up to 14 m on infinite-corridor).
    pub fn from_yaw(yaw_rad: f64) -> Self {
        let (s, c) = (0.5 * yaw_rad).sin_cos();
        let quaternion = |z: f64, w: f64| Self {
            x: 0.0,
            y: 0.0,
            z,
            w,
        };
        let plain = quaternion(s, c);
        if !yaw_rad.is_finite() || plain.yaw() == yaw_rad {
            return plain;
        }
        let steps = (0..=YAW_SEARCH_ULPS).flat_map(|n| [n, -n]);
        steps
            .clone()
            .flat_map(|dz| {
                steps
                    .clone()
                    .map(move |dw| quaternion(ulp_step(s, dz), ulp_step(c, dw)))
            })
            .find(|candidate| candidate.yaw() == yaw_rad)
            .unwrap_or(plain)
    }

    /// The heading (rad) of the rotation: its rotation about z after the roll and pitch
    /// (ZYX Euler), `atan2(2(wz + xy), w² + x² − y² − z²)`; a quaternion's scale cancels.
    pub fn yaw(&self) -> f64 {
        let Self { x, y, z, w } = *self;
        (2.0 * (w * z + x * y)).atan2(w * w + x * x - y * y - z * z)
    }
}

/// `geometry_msgs/msg/Pose`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Position (m).
    pub position: Vector3,
    /// Orientation.
    pub orientation: Quaternion,
}

/// A row-major 6×6 covariance, `float64[36]`: a fixed-size array, written without a length.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Covariance6(pub [f64; 36]);

impl Default for Covariance6 {
    fn default() -> Self {
        Self([0.0; 36])
    }
}

impl Serialize for Covariance6 {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeTuple as _;
        let mut tuple = serializer.serialize_tuple(36)?;
        for value in &self.0 {
            tuple.serialize_element(value)?;
        }
        tuple.end()
    }
}

impl<'de> Deserialize<'de> for Covariance6 {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = Covariance6;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("36 float64")
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> Result<Covariance6, A::Error> {
                let mut values = [0.0; 36];
                for (i, value) in values.iter_mut().enumerate() {
                    *value = seq
                        .next_element()?
                        .ok_or_else(|| serde::de::Error::invalid_length(i, &self))?;
                }
                Ok(Covariance6(values))
            }
        }
        deserializer.deserialize_tuple(36, Visitor)
    }
}

/// `geometry_msgs/msg/PoseWithCovariance`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseWithCovariance {
    /// The pose.
    pub pose: Pose,
    /// Its covariance (x, y, z, rotation about x, y, z).
    pub covariance: Covariance6,
}

/// `geometry_msgs/msg/Twist`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Twist {
    /// Linear velocity (m/s).
    pub linear: Vector3,
    /// Angular velocity (rad/s).
    pub angular: Vector3,
}

/// `geometry_msgs/msg/TwistWithCovariance`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TwistWithCovariance {
    /// The twist.
    pub twist: Twist,
    /// Its covariance.
    pub covariance: Covariance6,
}

/// `nav_msgs/msg/Odometry`: the pose of `child_frame_id` in `header.frame_id`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct OdometryMessage {
    /// Stamp, and the odometry frame.
    pub header: Header,
    /// The robot's frame (`base_link`, `base_footprint`).
    pub child_frame_id: String,
    /// The robot's pose in the odometry frame.
    pub pose: PoseWithCovariance,
    /// The robot's velocity in its own frame.
    pub twist: TwistWithCovariance,
}

/// `geometry_msgs/msg/Transform`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    /// Translation (m).
    pub translation: Vector3,
    /// Rotation.
    pub rotation: Quaternion,
}

/// `geometry_msgs/msg/TransformStamped`: `header.frame_id` from `child_frame_id`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TransformStamped {
    /// Stamp, and the parent frame.
    pub header: Header,
    /// The child frame.
    pub child_frame_id: String,
    /// `parent_from_child`.
    pub transform: Transform,
}

/// `tf2_msgs/msg/TFMessage`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TfMessage {
    /// The transforms.
    pub transforms: Vec<TransformStamped>,
}

/// `sensor_msgs/msg/PointField`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PointField {
    /// Field name (`x`, `y`, `z`, `intensity`, …).
    pub name: String,
    /// Byte offset within a point.
    pub offset: u32,
    /// Element type: 1 INT8, 2 UINT8, 3 INT16, 4 UINT16, 5 INT32, 6 UINT32, 7 FLOAT32, 8 FLOAT64.
    pub datatype: u8,
    /// Elements in the field.
    pub count: u32,
}

/// `sensor_msgs/msg/PointCloud2`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PointCloud2Message {
    /// Stamp and sensor frame.
    pub header: Header,
    /// Rows (1 for an unordered cloud).
    pub height: u32,
    /// Points per row.
    pub width: u32,
    /// The layout of one point.
    pub fields: Vec<PointField>,
    /// Byte order of `data`.
    pub is_bigendian: bool,
    /// Bytes per point.
    pub point_step: u32,
    /// Bytes per row.
    pub row_step: u32,
    /// The points.
    pub data: serde_bytes::ByteBuf,
    /// True when no point is invalid.
    pub is_dense: bool,
}

/// `nav_msgs/msg/MapMetaData`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MapMetaData {
    /// When the map was loaded (or made).
    pub map_load_time: Time,
    /// Cell side (m).
    pub resolution: f32,
    /// Cells per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Pose of cell (0, 0)'s lower-left corner in the map frame.
    pub origin: Pose,
}

/// `nav_msgs/msg/OccupancyGrid`: `info.height` rows of `info.width` cells, row 0 at the
/// origin, each an `int8` occupancy probability in percent or −1 for unknown. The cells are
/// kept as their bytes (−1 is 0xFF; `int8[]` and `uint8[]` share the CDR layout), so a large
/// map encodes as one copy.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct OccupancyGridMessage {
    /// Stamp and map frame.
    pub header: Header,
    /// Resolution, size and origin.
    pub info: MapMetaData,
    /// Row-major cells, each an `int8` as its byte.
    pub data: serde_bytes::ByteBuf,
}

impl OccupancyGridMessage {
    /// Cell (`column`, `row`): −1 unknown, else 0–100; `None` outside the grid or its data.
    pub fn cell(&self, column: u32, row: u32) -> Option<i8> {
        if column >= self.info.width || row >= self.info.height {
            return None;
        }
        let index =
            usize::try_from(u64::from(row) * u64::from(self.info.width) + u64::from(column))
                .ok()?;
        self.data.get(index).map(|b| i8::from_le_bytes([*b]))
    }
}

/// The CDR encapsulation identifiers ROS 2 writes: plain CDR, big- and little-endian.
const CDR_BIG_ENDIAN: [u8; 2] = [0x00, 0x00];
const CDR_LITTLE_ENDIAN: [u8; 2] = [0x00, 0x01];

/// Decodes one serialized message (encapsulation header, then CDR). The reason names what is
/// wrong; the caller adds file and topic.
pub fn decode<T: DeserializeOwned>(data: &[u8]) -> Result<T, String> {
    let (Some(kind), Some(payload)) = (data.get(..2), data.get(4..)) else {
        return Err(format!(
            "message of {} bytes: too short for a CDR header",
            data.len()
        ));
    };
    let decoded = if kind == CDR_LITTLE_ENDIAN {
        cdr_encoding::from_bytes::<T, LittleEndian>(payload)
    } else if kind == CDR_BIG_ENDIAN {
        cdr_encoding::from_bytes::<T, BigEndian>(payload)
    } else {
        return Err(format!(
            "unsupported CDR encapsulation {:#04x}{:02x} (plain CDR 0x0000/0x0001 only)",
            kind[0], kind[1]
        ));
    };
    decoded
        .map(|(message, _)| message)
        .map_err(|e| format!("malformed CDR: {e}"))
}

/// Encodes one message as little-endian CDR with its encapsulation header.
pub fn encode<T: Serialize>(message: &T) -> Result<Vec<u8>, String> {
    let mut data = vec![CDR_LITTLE_ENDIAN[0], CDR_LITTLE_ENDIAN[1], 0, 0];
    cdr_encoding::to_writer::<T, LittleEndian, _>(&mut data, message)
        .map_err(|e| format!("cannot encode as CDR: {e}"))?;
    Ok(data)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A LaserScan serialized by hand from the CDR rules (the bytes rclcpp writes): the
    /// decoder must read exactly these, and the encoder write them.
    #[test]
    fn laser_scan_bytes_match_the_cdr_layout() {
        let mut bytes = vec![0u8, 1, 0, 0];
        bytes.extend(7i32.to_le_bytes()); // stamp.sec
        bytes.extend(500u32.to_le_bytes()); // stamp.nanosec
        bytes.extend(6u32.to_le_bytes()); // frame_id length with its NUL
        bytes.extend(b"laser\0");
        bytes.extend([0, 0]); // pad to 4
        for value in [-1.5f32, 1.5, 1.5, 0.0, 0.1, 0.05, 30.0] {
            bytes.extend(value.to_le_bytes());
        }
        bytes.extend(3u32.to_le_bytes());
        for value in [1.0f32, 2.0, f32::INFINITY] {
            bytes.extend(value.to_le_bytes());
        }
        bytes.extend(0u32.to_le_bytes());
        let scan: LaserScanMessage = decode(&bytes).unwrap();
        assert_eq!(scan.header.frame_id, "laser");
        assert_eq!(
            scan.header.stamp,
            Time {
                sec: 7,
                nanosec: 500
            }
        );
        assert_eq!(scan.ranges, vec![1.0, 2.0, f32::INFINITY]);
        assert_eq!((scan.angle_min, scan.range_max), (-1.5, 30.0));
        assert_eq!(encode(&scan).unwrap(), bytes);
    }

    /// An OccupancyGrid serialized by hand from the CDR rules: the origin's doubles align to
    /// 8 after the four-byte fields, and the cells follow as a length and their bytes.
    #[test]
    fn occupancy_grid_bytes_match_the_cdr_layout() {
        let mut bytes = vec![0u8, 1, 0, 0];
        bytes.extend(3i32.to_le_bytes()); // header.stamp.sec
        bytes.extend(0u32.to_le_bytes()); // header.stamp.nanosec
        bytes.extend(4u32.to_le_bytes()); // frame_id length with its NUL
        bytes.extend(b"map\0"); // payload offset 16
        bytes.extend(3i32.to_le_bytes()); // info.map_load_time
        bytes.extend(0u32.to_le_bytes());
        bytes.extend(0.05f32.to_le_bytes()); // resolution
        bytes.extend(3u32.to_le_bytes()); // width
        bytes.extend(2u32.to_le_bytes()); // height; payload offset 36
        bytes.extend([0, 0, 0, 0]); // pad to 40 for the origin's first f64
        for value in [-1.5f64, 2.0, 0.0, 0.0, 0.0, 0.0, 1.0] {
            bytes.extend(value.to_le_bytes());
        }
        bytes.extend(6u32.to_le_bytes());
        bytes.extend([0xFF, 0, 100, 50, 0xFF, 0]);
        let grid: OccupancyGridMessage = decode(&bytes).unwrap();
        assert_eq!(grid.header.frame_id, "map");
        assert_eq!((grid.info.width, grid.info.height), (3, 2));
        assert_eq!(grid.info.origin.position.x, -1.5);
        assert_eq!(grid.info.origin.orientation.w, 1.0);
        assert_eq!(grid.cell(0, 0), Some(-1));
        assert_eq!(grid.cell(2, 0), Some(100));
        assert_eq!(grid.cell(1, 1), Some(-1));
        assert_eq!(grid.cell(3, 0), None);
        assert_eq!(grid.cell(0, 2), None);
        assert_eq!(encode(&grid).unwrap(), bytes);
    }

    /// Odometry has 8-byte fields after a string: the payload aligns them relative to its own
    /// start, not the buffer's.
    #[test]
    fn odometry_round_trips_with_alignment_after_strings() {
        let mut message = OdometryMessage {
            header: Header {
                stamp: Time { sec: 1, nanosec: 2 },
                frame_id: "odom".into(),
            },
            child_frame_id: "base".into(),
            ..Default::default()
        };
        message.pose.pose.position = Vector3 {
            x: 1.25,
            y: -2.5,
            z: 0.0,
        };
        message.pose.pose.orientation = Quaternion::from_yaw(0.3);
        message.pose.covariance.0[35] = 0.01;
        message.twist.twist.angular.z = 0.5;
        let bytes = encode(&message).unwrap();
        // Payload: stamp 8, "odom\0" (4 + 5) → 17, pad to 20, "base\0" (4 + 5) → 29, pad to
        // 32 for the first f64; the encapsulation header's 4 bytes come before.
        assert_eq!(
            f64::from_le_bytes(bytes[4 + 32..4 + 40].try_into().unwrap()),
            1.25
        );
        assert_eq!(decode::<OdometryMessage>(&bytes).unwrap(), message);
    }

    #[test]
    fn big_endian_payloads_decode() {
        let mut bytes = vec![0u8, 0, 0, 0];
        bytes.extend(3i32.to_be_bytes());
        bytes.extend(4u32.to_be_bytes());
        bytes.extend(1u32.to_be_bytes());
        bytes.push(0);
        let header: Header = decode(&bytes).unwrap();
        assert_eq!(header.stamp, Time { sec: 3, nanosec: 4 });
        assert_eq!(header.frame_id, "");
    }

    #[test]
    fn bad_headers_and_truncation_are_errors() {
        assert!(decode::<Header>(&[0, 1]).unwrap_err().contains("too short"));
        assert!(decode::<Header>(&[0, 7, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8])
            .unwrap_err()
            .contains("unsupported CDR encapsulation"));
        let bytes = encode(&LaserScanMessage {
            ranges: vec![1.0; 10],
            ..Default::default()
        })
        .unwrap();
        for cut in 4..bytes.len() {
            assert!(
                decode::<LaserScanMessage>(&bytes[..cut]).is_err(),
                "cut at {cut}"
            );
        }
    }

    #[test]
    #[allow(clippy::approx_constant)] // headings from just inside −π, on purpose
    fn yaw_survives_the_quaternion_bit_for_bit() {
        let mut exact = 0;
        for k in 0..20_000 {
            let yaw = -3.14159 + k as f64 * 3.14159e-4 + 1e-9 * (k % 7) as f64;
            let q = Quaternion::from_yaw(yaw);
            let norm = (q.z * q.z + q.w * q.w).sqrt();
            assert!((norm - 1.0).abs() < 1e-14, "{yaw}: {norm}");
            assert!((q.yaw() - yaw).abs() < 1e-15, "{yaw}");
            exact += usize::from(q.yaw() == yaw);
        }
        assert!(exact > 19_900, "{exact} of 20000 exact");
        let turned = Quaternion {
            x: 0.0,
            y: 0.0,
            z: 2.0,
            w: 0.0,
        };
        assert!(
            (turned.yaw() - std::f64::consts::PI).abs() < 1e-15,
            "scale cancels"
        );
    }

    #[test]
    fn time_conversions() {
        let time = Time::from_nanoseconds(1_500_000_001).unwrap();
        assert_eq!(
            time,
            Time {
                sec: 1,
                nanosec: 500_000_001
            }
        );
        assert_eq!(time.nanoseconds(), 1_500_000_001);
        assert!((time.seconds() - 1.500_000_001).abs() < 1e-12);
        assert_eq!(Time::from_nanoseconds(-1), None);
    }
}
