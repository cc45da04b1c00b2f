//! `sensor_msgs/msg/PointCloud2` → points, for the 3D path.

use std::path::Path;

use mapmerge_geometry::{LieGroup as _, Se3};
use mapmerge_io::IoError;
use nalgebra::Vector3;

use crate::messages::{
    decode, OdometryMessage, PointCloud2Message, ODOMETRY_TYPE, POINT_CLOUD2_TYPE, TF_TYPE,
};
use crate::session::{check_monotonic, choose_topic, pose_at, rotation_of, Tf, ODOMETRY_HOLD_S};
use crate::storage::{read_raw_bag, RawBag};

/// One cloud: its stamp, frame and finite points (m, in `frame_id`).
#[derive(Clone, Debug, PartialEq)]
pub struct StampedCloud {
    /// Header stamp (s).
    pub stamp_secs: f64,
    /// The sensor's frame.
    pub frame_id: String,
    /// The points with finite x, y and z.
    pub points: Vec<Vector3<f64>>,
}

/// PointField datatypes that can hold a coordinate.
const FLOAT32: u8 = 7;
const FLOAT64: u8 = 8;

/// The finite points of `cloud`; its `x`, `y`, `z` fields must be FLOAT32 or FLOAT64.
pub fn cloud_points(cloud: &PointCloud2Message) -> Result<Vec<Vector3<f64>>, String> {
    let field = |name: &str| {
        cloud
            .fields
            .iter()
            .find(|f| f.name == name)
            .ok_or_else(|| format!("the cloud has no '{name}' field"))
            .and_then(|f| match f.datatype {
                FLOAT32 => Ok((f.offset as usize, 4usize)),
                FLOAT64 => Ok((f.offset as usize, 8usize)),
                other => Err(format!(
                    "field '{name}' has datatype {other}; FLOAT32 or FLOAT64 is read"
                )),
            })
    };
    let fields = [field("x")?, field("y")?, field("z")?];
    let step = cloud.point_step as usize;
    if fields.iter().any(|(offset, size)| offset + size > step) {
        return Err(format!(
            "a coordinate field lies outside the point step of {step} bytes"
        ));
    }
    let (rows, columns, row_step) = (
        cloud.height as usize,
        cloud.width as usize,
        cloud.row_step as usize,
    );
    let needed = rows.checked_mul(row_step).filter(|_| {
        columns
            .checked_mul(step)
            .is_some_and(|row| row <= row_step || rows == 0)
    });
    match needed {
        Some(needed) if needed <= cloud.data.len() => {}
        _ => {
            return Err(format!(
                "{rows}×{columns} points of {step} bytes in rows of {row_step} bytes do not fit {} bytes of data",
                cloud.data.len()
            ))
        }
    }
    let read = |bytes: &[u8], (offset, size): (usize, usize)| -> f64 {
        let raw = &bytes[offset..offset + size];
        match (size, cloud.is_bigendian) {
            (4, false) => f64::from(f32::from_le_bytes([raw[0], raw[1], raw[2], raw[3]])),
            (4, true) => f64::from(f32::from_be_bytes([raw[0], raw[1], raw[2], raw[3]])),
            (_, false) => f64::from_le_bytes(raw.try_into().unwrap_or([0; 8])),
            (_, true) => f64::from_be_bytes(raw.try_into().unwrap_or([0; 8])),
        }
    };
    let mut points = Vec::with_capacity(rows * columns);
    for row in 0..rows {
        for column in 0..columns {
            let start = row * row_step + column * step;
            let bytes = &cloud.data[start..start + step];
            let point = Vector3::new(
                read(bytes, fields[0]),
                read(bytes, fields[1]),
                read(bytes, fields[2]),
            );
            if point.iter().all(|v| v.is_finite()) {
                points.push(point);
            }
        }
    }
    Ok(points)
}

/// The clouds of topic `index` of `raw`, decoded.
fn decode_clouds(raw: &RawBag, index: usize) -> Result<Vec<StampedCloud>, String> {
    let mut clouds = Vec::new();
    for message in raw.messages.iter().filter(|m| m.topic == index) {
        let context = |reason: String| {
            format!(
                "topic '{}', message {}: {reason}",
                raw.topics[index].name,
                clouds.len() + 1
            )
        };
        let cloud: PointCloud2Message = decode(&message.data).map_err(context)?;
        let points = cloud_points(&cloud).map_err(context)?;
        clouds.push(StampedCloud {
            stamp_secs: cloud.header.stamp.seconds(),
            frame_id: cloud.header.frame_id.trim_start_matches('/').to_owned(),
            points,
        });
    }
    Ok(clouds)
}

fn cloud_topic(raw: &RawBag, topic: Option<&str>) -> Result<usize, String> {
    choose_topic(&raw.topics, POINT_CLOUD2_TYPE, topic, "--cloud-topic")?
        .ok_or_else(|| format!("no {POINT_CLOUD2_TYPE} topic"))
}

/// The clouds of the PointCloud2 topic `topic` (or the only one) of the bag at `path`.
pub fn read_point_clouds(path: &Path, topic: Option<&str>) -> Result<Vec<StampedCloud>, IoError> {
    let invalid = |reason: String| IoError::Invalid {
        file: path.display().to_string(),
        reason,
    };
    let raw = read_raw_bag(path, &|t| t == POINT_CLOUD2_TYPE)?;
    let index = cloud_topic(&raw, topic).map_err(invalid)?;
    decode_clouds(&raw, index).map_err(invalid)
}

/// A bag's clouds, each with the sensor's pose in the odometry frame at its stamp.
#[derive(Clone, Debug)]
pub struct CloudSession {
    /// `odom_from_sensor` of each cloud: the odometry interpolated on SE(3) at the cloud's
    /// stamp, composed with the sensor's mount from tf.
    pub odom_from_sensor: Vec<Se3>,
    /// The clouds, in the sensor's frame.
    pub clouds: Vec<StampedCloud>,
    /// Clouds left out: no odometry within [`ODOMETRY_HOLD_S`] of their stamp.
    pub clouds_without_odometry: usize,
}

/// Reads a 3D session from the bag at `path`: the PointCloud2 topic `cloud_topic` (or the
/// only one) and the odometry topic `odom_topic` (or the only one), which it needs.
pub fn read_cloud_session(
    path: &Path,
    cloud_topic_name: Option<&str>,
    odom_topic_name: Option<&str>,
) -> Result<CloudSession, IoError> {
    let invalid = |reason: String| IoError::Invalid {
        file: path.display().to_string(),
        reason,
    };
    let wanted = |t: &str| t == POINT_CLOUD2_TYPE || t == ODOMETRY_TYPE || t == TF_TYPE;
    let raw = read_raw_bag(path, &wanted)?;
    cloud_session_of(&raw, cloud_topic_name, odom_topic_name).map_err(invalid)
}

fn cloud_session_of(
    raw: &RawBag,
    cloud_name: Option<&str>,
    odom_name: Option<&str>,
) -> Result<CloudSession, String> {
    let cloud_index = cloud_topic(raw, cloud_name)?;
    let odom_index = choose_topic(&raw.topics, ODOMETRY_TYPE, odom_name, "--odom-topic")?
        .ok_or_else(|| {
            format!("no {ODOMETRY_TYPE} topic: a 3D session takes its clouds' poses from odometry")
        })?;
    let clouds = decode_clouds(raw, cloud_index)?;
    let first = clouds
        .first()
        .ok_or_else(|| format!("topic '{}' has no messages", raw.topics[cloud_index].name))?;
    let (mut stamps, mut odom_from_base, mut base_frame) = (Vec::new(), Vec::new(), None);
    let mut tf = Tf::default();
    for message in &raw.messages {
        let topic = &raw.topics[message.topic];
        let context = |reason: String| format!("topic '{}': {reason}", topic.name);
        if message.topic == odom_index {
            let odometry: OdometryMessage = decode(&message.data).map_err(context)?;
            let position = &odometry.pose.pose.position;
            let rotation = rotation_of(&odometry.pose.pose.orientation).ok_or_else(|| {
                context("an odometry quaternion is zero or not finite".to_owned())
            })?;
            stamps.push(odometry.header.stamp.seconds());
            odom_from_base.push(Se3::new(
                rotation,
                Vector3::new(position.x, position.y, position.z),
            ));
            base_frame.get_or_insert(odometry.child_frame_id);
        } else if topic.message_type == TF_TYPE && topic.encoding == "cdr" {
            tf.take(topic, &message.data).map_err(context)?;
        }
    }
    check_monotonic(&stamps, &raw.topics[odom_index].name)?;
    let cloud_stamps: Vec<f64> = clouds.iter().map(|c| c.stamp_secs).collect();
    check_monotonic(&cloud_stamps, &raw.topics[cloud_index].name)?;
    let base_frame = base_frame
        .map(|f| f.trim_start_matches('/').to_owned())
        .filter(|f| !f.is_empty())
        .unwrap_or_else(|| "base_link".to_owned());
    let sensor_frame = &first.frame_id;
    let (base_from_sensor, _) = tf.mount(&base_frame, sensor_frame)?;
    let mut session = CloudSession {
        odom_from_sensor: Vec::new(),
        clouds: Vec::new(),
        clouds_without_odometry: 0,
    };
    for cloud in clouds {
        match pose_at(&stamps, &odom_from_base, cloud.stamp_secs) {
            Some(pose) => {
                session
                    .odom_from_sensor
                    .push(pose.compose(&base_from_sensor));
                session.clouds.push(cloud);
            }
            None => session.clouds_without_odometry += 1,
        }
    }
    if session.clouds.is_empty() {
        return Err(format!(
            "none of the clouds has odometry within {ODOMETRY_HOLD_S} s of its stamp"
        ));
    }
    Ok(session)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::messages::PointField;

    fn cloud(points: &[[f32; 3]], extra: usize) -> PointCloud2Message {
        let step = 12 + extra;
        let mut data = Vec::new();
        for p in points {
            for v in p {
                data.extend(v.to_le_bytes());
            }
            data.extend(vec![0u8; extra]);
        }
        let field = |name: &str, offset| PointField {
            name: name.into(),
            offset,
            datatype: FLOAT32,
            count: 1,
        };
        PointCloud2Message {
            height: 1,
            width: points.len() as u32,
            fields: vec![field("x", 0), field("y", 4), field("z", 8)],
            point_step: step as u32,
            row_step: (step * points.len()) as u32,
            data: serde_bytes::ByteBuf::from(data),
            ..Default::default()
        }
    }

    #[test]
    fn points_are_read_and_non_finite_ones_dropped() {
        let message = cloud(
            &[[1.0, 2.0, 3.0], [f32::NAN, 0.0, 0.0], [-1.0, 0.5, 0.25]],
            4,
        );
        let bytes = crate::messages::encode(&message).unwrap();
        let decoded: PointCloud2Message = decode(&bytes).unwrap();
        let points = cloud_points(&decoded).unwrap();
        assert_eq!(
            points,
            vec![Vector3::new(1.0, 2.0, 3.0), Vector3::new(-1.0, 0.5, 0.25)]
        );
    }

    #[test]
    fn layouts_that_do_not_fit_are_errors() {
        let mut short = cloud(&[[1.0, 2.0, 3.0]], 0);
        short.width = 2;
        assert!(cloud_points(&short).unwrap_err().contains("do not fit"));
        let mut no_z = cloud(&[[1.0, 2.0, 3.0]], 0);
        no_z.fields.pop();
        assert!(cloud_points(&no_z).unwrap_err().contains("no 'z'"));
        let mut huge = cloud(&[[1.0, 2.0, 3.0]], 0);
        (huge.height, huge.row_step) = (u32::MAX, u32::MAX);
        assert!(cloud_points(&huge).is_err());
    }
}
