//! The message definitions written with a bag (MCAP schemas, encoding `ros2msg`; the db3
//! `message_definitions` table): the main type's fields, then each type it uses under a
//! `MSG: pkg/Type` line, separated by a line of 80 `=`, as rosbag2 writes them. Readers
//! that decode by schema (Foxglove, `mcap-ros2-support`, `rosbags`) need them.

use crate::messages::{
    LASER_SCAN_TYPE, OCCUPANCY_GRID_TYPE, ODOMETRY_TYPE, POINT_CLOUD2_TYPE, TF_TYPE,
};

const TIME: (&str, &str) = ("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n");
const HEADER: (&str, &str) = (
    "std_msgs/Header",
    "builtin_interfaces/Time stamp\nstring frame_id\n",
);
const VECTOR3: (&str, &str) = ("geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z\n");
const POINT: (&str, &str) = ("geometry_msgs/Point", "float64 x\nfloat64 y\nfloat64 z\n");
const QUATERNION: (&str, &str) = (
    "geometry_msgs/Quaternion",
    "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
);
const POSE: (&str, &str) = (
    "geometry_msgs/Pose",
    "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
);
const POSE_WITH_COVARIANCE: (&str, &str) = (
    "geometry_msgs/PoseWithCovariance",
    "geometry_msgs/Pose pose\nfloat64[36] covariance\n",
);
const TWIST: (&str, &str) = (
    "geometry_msgs/Twist",
    "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n",
);
const TWIST_WITH_COVARIANCE: (&str, &str) = (
    "geometry_msgs/TwistWithCovariance",
    "geometry_msgs/Twist twist\nfloat64[36] covariance\n",
);
const TRANSFORM: (&str, &str) = (
    "geometry_msgs/Transform",
    "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n",
);
const TRANSFORM_STAMPED: (&str, &str) = (
    "geometry_msgs/TransformStamped",
    "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n",
);
const POINT_FIELD: (&str, &str) = (
    "sensor_msgs/PointField",
    "uint8 INT8=1\nuint8 UINT8=2\nuint8 INT16=3\nuint8 UINT16=4\nuint8 INT32=5\nuint8 UINT32=6\nuint8 FLOAT32=7\nuint8 FLOAT64=8\nstring name\nuint32 offset\nuint8 datatype\nuint32 count\n",
);

const MAP_META_DATA: (&str, &str) = (
    "nav_msgs/MapMetaData",
    "builtin_interfaces/Time map_load_time\nfloat32 resolution\nuint32 width\nuint32 height\ngeometry_msgs/Pose origin\n",
);

fn with_dependencies(main: &str, dependencies: &[(&str, &str)]) -> String {
    let mut text = main.to_owned();
    for (name, fields) in dependencies {
        text.push_str(&"=".repeat(80));
        text.push_str(&format!("\nMSG: {name}\n{fields}"));
    }
    text
}

/// The definition of `message_type` (one of the types of [`crate::messages`]), empty for
/// others.
pub fn definition(message_type: &str) -> String {
    match message_type {
        LASER_SCAN_TYPE => with_dependencies(
            "std_msgs/Header header\nfloat32 angle_min\nfloat32 angle_max\nfloat32 angle_increment\nfloat32 time_increment\nfloat32 scan_time\nfloat32 range_min\nfloat32 range_max\nfloat32[] ranges\nfloat32[] intensities\n",
            &[HEADER, TIME],
        ),
        ODOMETRY_TYPE => with_dependencies(
            "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n",
            &[HEADER, TIME, POSE_WITH_COVARIANCE, POSE, POINT, QUATERNION, TWIST_WITH_COVARIANCE, TWIST, VECTOR3],
        ),
        TF_TYPE => with_dependencies(
            "geometry_msgs/TransformStamped[] transforms\n",
            &[TRANSFORM_STAMPED, HEADER, TIME, TRANSFORM, VECTOR3, QUATERNION],
        ),
        POINT_CLOUD2_TYPE => with_dependencies(
            "std_msgs/Header header\nuint32 height\nuint32 width\nsensor_msgs/PointField[] fields\nbool is_bigendian\nuint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n",
            &[HEADER, TIME, POINT_FIELD],
        ),
        OCCUPANCY_GRID_TYPE => with_dependencies(
            "std_msgs/Header header\nnav_msgs/MapMetaData info\nint8[] data\n",
            &[HEADER, TIME, MAP_META_DATA, POSE, POINT, QUATERNION],
        ),
        _ => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every type a definition's fields name (`pkg/Type`, arrays too) has its own `MSG:`
    /// section, as schema-driven readers need, and none is listed twice.
    #[test]
    fn every_used_type_is_defined_once() {
        let types = [
            LASER_SCAN_TYPE,
            ODOMETRY_TYPE,
            TF_TYPE,
            POINT_CLOUD2_TYPE,
            OCCUPANCY_GRID_TYPE,
        ];
        for message_type in types {
            let text = definition(message_type);
            assert!(!text.is_empty(), "{message_type}");
            let defined: Vec<&str> = text
                .lines()
                .filter_map(|l| l.strip_prefix("MSG: "))
                .collect();
            let mut unique = defined.clone();
            unique.sort_unstable();
            unique.dedup();
            assert_eq!(unique.len(), defined.len(), "{message_type}: {defined:?}");
            for line in text
                .lines()
                .filter(|l| !l.starts_with("MSG: ") && !l.starts_with('='))
            {
                let Some(field_type) = line.split_whitespace().next() else {
                    continue;
                };
                let base = field_type.split('[').next().unwrap_or(field_type);
                if base.contains('/') {
                    assert!(
                        defined.contains(&base),
                        "{message_type}: {base} is not defined"
                    );
                }
            }
        }
        assert!(definition("std_msgs/msg/String").is_empty());
    }
}
