//! Arbitrary bytes into `parse_kitti_cloud` and (lossy UTF-8) into `parse_kitti_poses`. A cloud
//! parses exactly when its length is a multiple of 16, to its finite points; a pose file either
//! names a data line or gives one finite rotation per data line, each line's rotation block
//! orthonormal within the documented 1e-3 and its translation as written.

#![no_main]

use libfuzzer_sys::fuzz_target;
use mapmerge_io::{parse_kitti_cloud, parse_kitti_poses, IoError};

/// `‖MᵀM − I‖` (Frobenius) of a 3×3 matrix given by its entry at (row, column).
fn defect(m: impl Fn(usize, usize) -> f64) -> f64 {
    let mut sum = 0.0;
    for i in 0..3 {
        for j in 0..3 {
            let dot: f64 = (0..3).map(|k| m(k, i) * m(k, j)).sum();
            let d = dot - if i == j { 1.0 } else { 0.0 };
            sum += d * d;
        }
    }
    sum.sqrt()
}

fuzz_target!(|data: &[u8]| {
    // Clouds: every 16 bytes a point, non-finite ones dropped.
    match parse_kitti_cloud(data, "fuzz.bin") {
        Ok(cloud) => {
            assert_eq!(data.len() % 16, 0);
            let finite = data
                .chunks_exact(16)
                .filter(|p| {
                    p[..12]
                        .chunks_exact(4)
                        .all(|w| f32::from_le_bytes([w[0], w[1], w[2], w[3]]).is_finite())
                })
                .count();
            assert_eq!(cloud.len(), finite);
            assert!(cloud.iter().all(|p| p.iter().all(|v| v.is_finite())));
        }
        Err(IoError::Invalid { file, .. }) => {
            assert_eq!(file, "fuzz.bin");
            assert_ne!(data.len() % 16, 0);
        }
        Err(err) => panic!("unexpected cloud error: {err}"),
    }

    // Poses: the data lines, read independently (ASCII whitespace, `#` comments).
    let text = String::from_utf8_lossy(data);
    let lines: Vec<(usize, Vec<&str>)> = text
        .split('\n')
        .enumerate()
        .filter_map(|(index, line)| {
            let tokens: Vec<&str> = line.split_ascii_whitespace().collect();
            match tokens.first() {
                Some(first) if !first.starts_with('#') => Some((index + 1, tokens)),
                _ => None,
            }
        })
        .collect();
    match parse_kitti_poses(&text, "fuzz.txt") {
        Ok(poses) => {
            assert_eq!(poses.len(), lines.len());
            for (pose, (number, tokens)) in poses.iter().zip(&lines) {
                assert_eq!(tokens.len(), 12, "line {number}");
                let values: Vec<f64> = tokens
                    .iter()
                    .map(|t| t.parse().unwrap_or(f64::NAN))
                    .collect();
                assert!(
                    values.iter().all(|v| v.is_finite()),
                    "line {number}: {tokens:?}"
                );
                let written = defect(|row, column| values[4 * row + column]);
                assert!(
                    written <= 1e-3,
                    "line {number} accepted with defect {written}"
                );
                let m = pose.to_matrix();
                assert!(m.iter().all(|v| v.is_finite()), "line {number}: {pose:?}");
                assert!(defect(|row, column| m[(row, column)]) < 1e-9, "{pose:?}");
                assert!(pose.rotation_matrix().determinant() > 0.0, "{pose:?}");
                for row in 0..3 {
                    assert_eq!(m[(row, 3)], values[4 * row + 3], "line {number}");
                }
            }
        }
        Err(IoError::Parse { file, line, .. }) => {
            assert_eq!(file, "fuzz.txt");
            assert!(
                lines.iter().any(|(number, _)| *number == line),
                "line {line} is not a data line"
            );
        }
        Err(err) => panic!("unexpected pose error: {err}"),
    }
});
