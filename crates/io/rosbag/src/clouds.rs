//! `sensor_msgs/msg/PointCloud2` → points, for the 3D path.

use std::path::Path;

use mapmerge_io::IoError;
use nalgebra::Vector3;

use crate::messages::{decode, PointCloud2Message, POINT_CLOUD2_TYPE};
use crate::session::choose_topic;
use crate::storage::read_raw_bag;

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
                other => Err(format!("field '{name}' has datatype {other}; FLOAT32 or FLOAT64 is read")),
            })
    };
    let fields = [field("x")?, field("y")?, field("z")?];
    let step = cloud.point_step as usize;
    if fields.iter().any(|(offset, size)| offset + size > step) {
        return Err(format!("a coordinate field lies outside the point step of {step} bytes"));
    }
    let (rows, columns, row_step) = (cloud.height as usize, cloud.width as usize, cloud.row_step as usize);
    let needed = rows
        .checked_mul(row_step)
        .filter(|_| columns.checked_mul(step).is_some_and(|row| row <= row_step || rows == 0));
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
            let point = Vector3::new(read(bytes, fields[0]), read(bytes, fields[1]), read(bytes, fields[2]));
            if point.iter().all(|v| v.is_finite()) {
                points.push(point);
            }
        }
    }
    Ok(points)
}

/// The clouds of the PointCloud2 topic `topic` (or the only one) of the bag at `path`.
pub fn read_point_clouds(path: &Path, topic: Option<&str>) -> Result<Vec<StampedCloud>, IoError> {
    let invalid = |reason: String| IoError::Invalid { file: path.display().to_string(), reason };
    let raw = read_raw_bag(path, &|t| t == POINT_CLOUD2_TYPE)?;
    let index = choose_topic(&raw.topics, POINT_CLOUD2_TYPE, topic, "--cloud-topic")
        .map_err(invalid)?
        .ok_or_else(|| invalid(format!("no {POINT_CLOUD2_TYPE} topic")))?;
    let mut clouds = Vec::new();
    for message in raw.messages.iter().filter(|m| m.topic == index) {
        let context = |reason: String| invalid(format!("topic '{}', message {}: {reason}", raw.topics[index].name, clouds.len() + 1));
        let cloud: PointCloud2Message = decode(&message.data).map_err(context)?;
        let points = cloud_points(&cloud).map_err(context)?;
        clouds.push(StampedCloud {
            stamp_secs: cloud.header.stamp.seconds(),
            frame_id: cloud.header.frame_id,
            points,
        });
    }
    Ok(clouds)
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
        let field = |name: &str, offset| PointField { name: name.into(), offset, datatype: FLOAT32, count: 1 };
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
        let message = cloud(&[[1.0, 2.0, 3.0], [f32::NAN, 0.0, 0.0], [-1.0, 0.5, 0.25]], 4);
        let bytes = crate::messages::encode(&message).unwrap();
        let decoded: PointCloud2Message = decode(&bytes).unwrap();
        let points = cloud_points(&decoded).unwrap();
        assert_eq!(points, vec![Vector3::new(1.0, 2.0, 3.0), Vector3::new(-1.0, 0.5, 0.25)]);
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
