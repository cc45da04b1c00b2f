//! KITTI odometry data: ground-truth / odometry pose files and Velodyne point clouds.
//!
//! - Poses (`poses/NN.txt`): one line per frame, 12 numbers, the row-major 3×4 matrix `[R | t]`
//!   of `world_from_camera` (the left camera of frame 0 is the world; camera axes: x right,
//!   y down, z forward). For clouds in the Velodyne frame compose with the calibration:
//!   `world_from_velodyne = world_from_camera · camera_from_velodyne` (`Tr` in `calib.txt`).
//! - Clouds (`velodyne/NNNNNN.bin`): little-endian `f32` quadruples `x y z reflectance` in the
//!   Velodyne frame (x forward, y left, z up, metres).
//!
//! Both are read plain or xz-compressed; nothing panics on input.

use std::path::Path;

use mapmerge_geometry::Se3;
use nalgebra::{Matrix3, Vector3};

use crate::input::{read_bytes, read_text};
use crate::reader::{data_lines, parse_error, parse_f64};
use crate::IoError;

/// Largest accepted `‖RᵀR − I‖` (Frobenius) of a pose's rotation block; KITTI's files keep
/// about 1e-6, so anything beyond is a broken line rather than rounding.
const ROTATION_TOLERANCE: f64 = 1e-3;

/// Reads a KITTI pose file; see [`parse_kitti_poses`].
pub fn read_kitti_poses(path: &Path) -> Result<Vec<Se3>, IoError> {
    let text = read_text(path)?;
    parse_kitti_poses(&text, &path.display().to_string())
}

/// Parses a KITTI pose file: one pose per data line (12 finite numbers, row-major `[R | t]`),
/// in file order; blank lines and `#` comments are skipped. The rotation block is projected
/// onto the nearest rotation; one further than [`ROTATION_TOLERANCE`] from orthonormal, or a
/// line without exactly 12 numbers, is an [`IoError::Parse`] naming `source` and the line.
pub fn parse_kitti_poses(text: &str, source: &str) -> Result<Vec<Se3>, IoError> {
    let mut poses = Vec::new();
    for line in data_lines(text) {
        let mut values = [0.0f64; 12];
        let mut count = 0;
        for token in std::iter::once(line.tag).chain(line.fields.rest()) {
            if let Some(slot) = values.get_mut(count) {
                *slot = parse_f64(token, count + 1)
                    .map_err(|reason| parse_error(source, line.number, reason))?;
            }
            count += 1;
        }
        if count != 12 {
            return Err(parse_error(
                source,
                line.number,
                format!("expected 12 numbers (a 3x4 [R|t] matrix), found {count}"),
            ));
        }
        let [r00, r01, r02, tx, r10, r11, r12, ty, r20, r21, r22, tz] = values;
        let rotation = Matrix3::new(r00, r01, r02, r10, r11, r12, r20, r21, r22);
        let defect = (rotation.transpose() * rotation - Matrix3::identity()).norm();
        // Huge entries overflow RᵀR into NaN: only a defect known to be small passes.
        if !(defect <= ROTATION_TOLERANCE && rotation.determinant() > 0.0) {
            return Err(parse_error(
                source,
                line.number,
                format!("rotation block is not a rotation (‖RᵀR − I‖ = {defect:.3e})"),
            ));
        }
        let pose = Se3::try_from_rotation_matrix(&rotation, Vector3::new(tx, ty, tz))
            .ok_or_else(|| parse_error(source, line.number, "non-finite pose".to_owned()))?;
        poses.push(pose);
    }
    Ok(poses)
}

/// Reads a KITTI Velodyne scan; see [`parse_kitti_cloud`].
pub fn read_kitti_cloud(path: &Path) -> Result<Vec<Vector3<f64>>, IoError> {
    let bytes = read_bytes(path)?;
    parse_kitti_cloud(&bytes, &path.display().to_string())
}

/// The points of a KITTI Velodyne scan (`x y z reflectance` as little-endian `f32`, 16 bytes a
/// point), reflectance dropped, in file order; points with a non-finite coordinate are
/// skipped. A length that is not a multiple of 16 is an [`IoError::Invalid`].
pub fn parse_kitti_cloud(bytes: &[u8], source: &str) -> Result<Vec<Vector3<f64>>, IoError> {
    const POINT_BYTES: usize = 16;
    if bytes.len() % POINT_BYTES != 0 {
        return Err(IoError::Invalid {
            file: source.to_owned(),
            reason: format!(
                "{} bytes is not a whole number of 16-byte points (x y z reflectance as f32)",
                bytes.len()
            ),
        });
    }
    let coordinate = |b: &[u8]| -> f64 {
        let mut word = [0u8; 4];
        word.copy_from_slice(b);
        f64::from(f32::from_le_bytes(word))
    };
    Ok(bytes
        .chunks_exact(POINT_BYTES)
        .map(|point| {
            Vector3::new(
                coordinate(&point[0..4]),
                coordinate(&point[4..8]),
                coordinate(&point[8..12]),
            )
        })
        .filter(|p| p.iter().all(|v| v.is_finite()))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapmerge_geometry::LieGroup;

    #[test]
    fn poses_parse_and_broken_lines_name_their_line() {
        let text = "1 0 0 0 0 1 0 0 0 0 1 0\n\n# comment\n0 -1 0 1.5 1 0 0 2 0 0 1 -3\n";
        let poses = parse_kitti_poses(text, "00.txt").unwrap();
        assert_eq!(poses.len(), 2);
        assert!(poses[0].log().norm() < 1e-12);
        let p = poses[1].transform_point(&Vector3::new(1.0, 0.0, 0.0));
        assert!((p - Vector3::new(1.5, 3.0, -3.0)).norm() < 1e-12);
        let err = parse_kitti_poses("1 0 0 0 0 1 0 0 0 0 1\n", "x.txt").unwrap_err();
        assert!(err.to_string().starts_with("x.txt:1:"), "{err}");
        let err = parse_kitti_poses("1 0 0 0 0 1 0 0 0 0 1 0\n2 0 0 0 0 1 0 0 0 0 1 0\n", "x")
            .unwrap_err();
        assert!(err.to_string().starts_with("x:2:"), "{err}");
        assert!(parse_kitti_poses("1 0 0 0 0 1 0 0 0 0 1 nan\n", "x").is_err());
        assert!(parse_kitti_poses("-1 0 0 0 0 1 0 0 0 0 1 0\n", "x").is_err());
    }

    #[test]
    fn clouds_parse_little_endian_quadruples() {
        let mut bytes = Vec::new();
        for v in [
            1.0f32,
            -2.0,
            0.5,
            0.3,
            f32::NAN,
            0.0,
            0.0,
            0.0,
            3.0,
            4.0,
            5.0,
            1.0,
        ] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        let cloud = parse_kitti_cloud(&bytes, "000000.bin").unwrap();
        assert_eq!(
            cloud,
            vec![Vector3::new(1.0, -2.0, 0.5), Vector3::new(3.0, 4.0, 5.0)]
        );
        assert!(parse_kitti_cloud(&bytes[..15], "x.bin").is_err());
        assert!(parse_kitti_cloud(&[], "x.bin").unwrap().is_empty());
    }

    #[test]
    fn public_pose_file_reads() {
        let Some(path) = mapmerge_testkit::shared_data("kitti/poses/00.txt") else {
            return;
        };
        let poses = read_kitti_poses(&path).unwrap();
        assert_eq!(poses.len(), 4541);
        assert!(poses[0].log().norm() < 1e-6);
    }
}
