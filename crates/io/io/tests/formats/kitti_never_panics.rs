//! KITTI readers on arbitrary input: `parse_kitti_poses` and `parse_kitti_cloud` never panic,
//! a pose-file error names the source and the first bad data line, and what parses is what
//! the text says (checked against an independent reading of the same text).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_io::{parse_kitti_cloud, parse_kitti_poses, IoError};
use nalgebra::{Matrix3, Rotation3, Vector3};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;

/// Source name given to the parsers.
const SOURCE: &str = "kitti-prop.txt";

/// The documented tolerance of the rotation block, `‖RᵀR − I‖` (Frobenius).
const ROTATION_TOLERANCE: f64 = 1e-3;

/// Seeded and without regression files: every run tries the same cases.
fn config(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_seed: RngSeed::Fixed(0x6b17_7150),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

/// The tokens of every data line (1-based line number), read independently of the crate:
/// lines end at `\n`, tokens split at ASCII whitespace, blank and `#` lines skipped.
fn data_lines(text: &str) -> Vec<(usize, Vec<&str>)> {
    text.split('\n')
        .enumerate()
        .filter_map(|(index, line)| {
            let tokens: Vec<&str> = line.split_ascii_whitespace().collect();
            match tokens.first() {
                Some(first) if !first.starts_with('#') => Some((index + 1, tokens)),
                _ => None,
            }
        })
        .collect()
}

/// `‖RᵀR − I‖` of a row-major 3×4 line's rotation block, or `None` unless the line is 12
/// finite numbers (as `str::parse` reads them).
fn rotation_defect(tokens: &[&str]) -> Option<f64> {
    if tokens.len() != 12 {
        return None;
    }
    let values: Vec<f64> = tokens
        .iter()
        .map(|t| t.parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect::<Option<_>>()?;
    let r = Matrix3::new(
        values[0], values[1], values[2], values[4], values[5], values[6], values[8], values[9],
        values[10],
    );
    Some((r.transpose() * r - Matrix3::identity()).norm())
}

/// Asserts the contract of `parse_kitti_poses` on any text: an error is a [`IoError::Parse`]
/// naming `SOURCE` and a data line, every data line before it parses on its own and that line
/// does not; a success holds one orthonormal, finite pose per data line, each line's rotation
/// block within the tolerance and its translation as written.
fn check_pose_contract(text: &str) -> Result<(), TestCaseError> {
    let lines = data_lines(text);
    match parse_kitti_poses(text, SOURCE) {
        Err(IoError::Parse { file, line, reason }) => {
            prop_assert_eq!(&file, SOURCE);
            let message = IoError::Parse {
                file,
                line,
                reason: reason.clone(),
            }
            .to_string();
            prop_assert!(
                message.starts_with(&format!("{SOURCE}:{line}: ")),
                "{}",
                message
            );
            prop_assert!(!reason.is_empty());
            let position = lines.iter().position(|(number, _)| *number == line);
            prop_assert!(
                position.is_some(),
                "line {} is not a data line: {}",
                line,
                message
            );
            let position = position.unwrap_or_default();
            for (number, tokens) in &lines[..position] {
                let alone = tokens.join(" ");
                prop_assert!(
                    parse_kitti_poses(&alone, SOURCE).is_ok(),
                    "line {} parses alone yet the error names line {}",
                    number,
                    line
                );
            }
            let named = lines[position].1.join(" ");
            prop_assert!(parse_kitti_poses(&named, SOURCE).is_err(), "{}", named);
        }
        Err(other) => prop_assert!(false, "not a line error: {other:?}"),
        Ok(poses) => {
            prop_assert_eq!(poses.len(), lines.len());
            for (pose, (number, tokens)) in poses.iter().zip(&lines) {
                let defect = rotation_defect(tokens);
                prop_assert!(
                    defect.is_some_and(|d| d <= ROTATION_TOLERANCE),
                    "line {} accepted with rotation defect {:?}: {:?}",
                    number,
                    defect,
                    tokens
                );
                let m = pose.to_matrix();
                prop_assert!(m.iter().all(|v| v.is_finite()), "line {}", number);
                let r = pose.rotation_matrix();
                prop_assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-9);
                prop_assert!(r.determinant() > 0.0);
                for (row, column) in [(0, 3), (1, 7), (2, 11)] {
                    prop_assert_eq!(m[(row, 3)], tokens[column].parse::<f64>().unwrap());
                }
            }
        }
    }
    Ok(())
}

/// Asserts the contract of `parse_kitti_cloud` on any bytes: a whole number of 16-byte points
/// gives every point whose `x y z` are finite, in order; anything else an error naming the
/// source and the length.
fn check_cloud_contract(bytes: &[u8]) -> Result<(), TestCaseError> {
    let result = parse_kitti_cloud(bytes, "prop.bin");
    if bytes.len() % 16 != 0 {
        let err = result.err();
        prop_assert!(
            matches!(&err, Some(IoError::Invalid { file, .. }) if file == "prop.bin"),
            "{:?}",
            err
        );
        let message = err.map(|e| e.to_string()).unwrap_or_default();
        prop_assert!(message.starts_with("prop.bin: "), "{}", message);
        prop_assert!(message.contains(&bytes.len().to_string()), "{}", message);
        return Ok(());
    }
    let expected: Vec<Vector3<f64>> = bytes
        .chunks_exact(16)
        .map(|point| {
            let f = |k: usize| {
                f64::from(f32::from_le_bytes([
                    point[4 * k],
                    point[4 * k + 1],
                    point[4 * k + 2],
                    point[4 * k + 3],
                ]))
            };
            Vector3::new(f(0), f(1), f(2))
        })
        .filter(|p| p.iter().all(|v| v.is_finite()))
        .collect();
    match result {
        Ok(cloud) => prop_assert_eq!(cloud, expected),
        Err(err) => prop_assert!(false, "{} bytes refused: {}", bytes.len(), err),
    }
    Ok(())
}

/// One line of a generated pose file and what the parser must make of it.
#[derive(Clone, Debug)]
enum Line {
    /// A pose, written with shortest round-trip digits (or in exponent form).
    Pose {
        rotation: Rotation3<f64>,
        translation_m: Vector3<f64>,
        exponent: bool,
    },
    /// Whitespace only.
    Blank(String),
    /// A comment, maybe indented.
    Comment(String),
    /// A line the parser must refuse.
    Bad(String),
}

impl Line {
    fn text(&self, separator: &str) -> String {
        match self {
            Line::Pose {
                rotation,
                translation_m,
                exponent,
            } => pose_tokens(rotation.matrix(), translation_m, *exponent).join(separator),
            Line::Blank(text) | Line::Comment(text) | Line::Bad(text) => text.clone(),
        }
    }
}

/// The 12 tokens of `[R | t]`, row-major.
fn pose_tokens(r: &Matrix3<f64>, t: &Vector3<f64>, exponent: bool) -> Vec<String> {
    let mut tokens = Vec::with_capacity(12);
    for row in 0..3 {
        for value in [r[(row, 0)], r[(row, 1)], r[(row, 2)], t[row]] {
            tokens.push(if exponent {
                format!("{value:e}")
            } else {
                format!("{value}")
            });
        }
    }
    tokens
}

fn rotation() -> impl Strategy<Value = Rotation3<f64>> {
    (-3.2..3.2f64, -1.5..1.5f64, -3.2..3.2f64)
        .prop_map(|(roll, pitch, yaw)| Rotation3::from_euler_angles(roll, pitch, yaw))
}

fn translation() -> impl Strategy<Value = Vector3<f64>> {
    (-1e4..1e4f64, -1e4..1e4f64, -1e4..1e4f64).prop_map(|(x, y, z)| Vector3::new(x, y, z))
}

/// A line that breaks the format in one way.
fn bad_line() -> impl Strategy<Value = String> {
    let wrong_count = (rotation(), translation(), 1..30usize)
        .prop_filter("not 12 numbers", |(_, _, n)| *n != 12)
        .prop_map(|(r, t, n)| {
            let tokens = pose_tokens(r.matrix(), &t, false);
            tokens
                .iter()
                .cycle()
                .take(n)
                .cloned()
                .collect::<Vec<_>>()
                .join(" ")
        });
    let bad_token = (
        rotation(),
        translation(),
        0..12usize,
        prop::sample::select(vec![
            "nan", "NaN", "inf", "-inf", "1e999", "-1e400x", "x", "1.0.0", "0x10", "1,5", "--1",
            "½", "1e", ".", "+",
        ]),
    )
        .prop_map(|(r, t, k, token)| {
            let mut tokens = pose_tokens(r.matrix(), &t, false);
            tokens[k] = token.to_owned();
            tokens.join(" ")
        });
    // Scaled rotation blocks: RᵀR = s²·I is at least 0.03 from the identity.
    let scaled = (
        rotation(),
        translation(),
        prop_oneof![0.1..0.99f64, 1.01..5.0f64],
    )
        .prop_map(|(r, t, s)| pose_tokens(&(r.matrix() * s), &t, false).join(" "));
    // One row negated: orthonormal but a reflection (determinant −1).
    let reflected = (rotation(), translation(), 0..3usize).prop_map(|(r, t, row)| {
        let mut m = *r.matrix();
        m.row_mut(row).neg_mut();
        pose_tokens(&m, &t, false).join(" ")
    });
    // Non-finite (overflowing) translations and text that is no number at all.
    let words = "[a-zA-Z_][a-zA-Z0-9_ ]{0,30}";
    prop_oneof![wrong_count, bad_token, scaled, reflected, words]
}

fn line() -> impl Strategy<Value = Line> {
    prop_oneof![
        6 => (rotation(), translation(), any::<bool>()).prop_map(
            |(rotation, translation_m, exponent)| Line::Pose { rotation, translation_m, exponent }
        ),
        1 => prop::sample::select(vec!["", " ", "\t", "\r", " \t \r"])
            .prop_map(|s| Line::Blank(s.to_owned())),
        1 => ("[ \t]{0,2}", "#[^\n]{0,20}")
            .prop_map(|(indent, comment)| Line::Comment(indent + &comment)),
        1 => bad_line().prop_map(Line::Bad),
    ]
}

/// Text of the token vocabulary: numbers, non-numbers, comment marks; up to 14 a line, so
/// that some lines have exactly 12 (huge magnitudes are left to the test below).
fn token_text() -> impl Strategy<Value = String> {
    let token = prop::sample::select(vec![
        "0", "1", "-1", "0.5", "+1", ".5", "1e-3", "-0", "2", "1e-400", "nan", "inf", "#", "#1",
        "x", "1e3",
    ]);
    let line = (
        prop::collection::vec(token, 0..14),
        prop::sample::select(vec![" ", "\t", "  ", "\x0c"]),
        any::<bool>(),
    )
        .prop_map(|(tokens, separator, crlf)| {
            tokens.join(separator) + if crlf { "\r" } else { "" }
        });
    prop::collection::vec(line, 0..8).prop_map(|lines| lines.join("\n"))
}

proptest! {
    #![proptest_config(config(512))]

    #[test]
    fn pose_parser_keeps_its_contract_on_arbitrary_bytes(
        bytes in prop::collection::vec(any::<u8>(), 0..400)
    ) {
        check_pose_contract(&String::from_utf8_lossy(&bytes))?;
    }

    #[test]
    fn pose_parser_keeps_its_contract_on_arbitrary_text(text in "(?s).{0,300}") {
        check_pose_contract(&text)?;
    }

    #[test]
    fn pose_parser_keeps_its_contract_on_number_like_lines(text in token_text()) {
        check_pose_contract(&text)?;
    }

    #[test]
    fn cloud_parser_keeps_its_contract_on_arbitrary_bytes(
        bytes in prop::collection::vec(any::<u8>(), 0..400)
    ) {
        check_cloud_contract(&bytes)?;
    }

    #[test]
    fn cloud_parser_keeps_its_contract_on_arbitrary_floats(
        values in prop::collection::vec(any::<f32>(), 0..64),
        cut in 0..16usize,
    ) {
        let mut bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        check_cloud_contract(&bytes)?;
        bytes.truncate(bytes.len().saturating_sub(cut));
        check_cloud_contract(&bytes)?;
    }
}

proptest! {
    #![proptest_config(config(256))]

    /// Generated files whose outcome is known line by line: the first bad line is the one
    /// named, otherwise every pose comes back (translation exactly, rotation to rounding).
    #[test]
    fn generated_pose_files_parse_or_name_their_first_bad_line(
        lines in prop::collection::vec(line(), 0..12),
        separator in prop::sample::select(vec![" ", "\t", "   ", " \t"]),
        crlf in any::<bool>(),
    ) {
        let ending = if crlf { "\r\n" } else { "\n" };
        let text: String = lines
            .iter()
            .map(|l| l.text(separator))
            .collect::<Vec<_>>()
            .join(ending);
        check_pose_contract(&text)?;
        let first_bad = lines.iter().position(|l| matches!(l, Line::Bad(_)));
        match (parse_kitti_poses(&text, SOURCE), first_bad) {
            (Err(IoError::Parse { line, .. }), Some(bad)) => {
                prop_assert_eq!(line, bad + 1, "{}", text);
            }
            (Ok(poses), None) => {
                let expected: Vec<_> = lines
                    .iter()
                    .filter_map(|l| match l {
                        Line::Pose { rotation, translation_m, .. } => {
                            Some((rotation, translation_m))
                        }
                        _ => None,
                    })
                    .collect();
                prop_assert_eq!(poses.len(), expected.len());
                for (pose, (rotation, translation_m)) in poses.iter().zip(expected) {
                    let m = pose.to_matrix();
                    prop_assert_eq!(
                        Vector3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]),
                        *translation_m
                    );
                    let error = (pose.rotation_matrix() - rotation.matrix()).norm();
                    prop_assert!(error < 1e-12, "rotation off by {}", error);
                }
            }
            (result, bad) => {
                prop_assert!(false, "first bad line {:?}, got {:?}\n{}", bad, result, text);
            }
        }
    }
}

/// A rotation block scaled by 1e155 or more is no rotation, but `RᵀR` overflows and two
/// overflowing products of opposite sign give a NaN defect, which a `defect > tolerance` test
/// would let through as a pose with a NaN quaternion (found by this test; fixed).
#[test]
fn overflowing_rotation_blocks_are_refused() {
    let r = Rotation3::from_euler_angles(0.3, -0.2, 1.1);
    for scale in [1e155, 1e200, 1e300] {
        let line =
            pose_tokens(&(r.matrix() * scale), &Vector3::new(1.0, 2.0, 3.0), false).join(" ");
        let result = parse_kitti_poses(&line, "huge.txt");
        assert!(
            matches!(&result, Err(IoError::Parse { line: 1, .. })),
            "scale {scale}: {result:?}"
        );
    }
}
