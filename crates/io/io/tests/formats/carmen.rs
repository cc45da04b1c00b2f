//! CARMEN logs: every public log loads with the counts of the data README, the max-range rule
//! gives the documented value per log, and every log (and random logs) survive write → read.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;
use std::f64::consts::{FRAC_PI_2, PI};

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_io::{
    format_carmen, parse_carmen, read_carmen, write_carmen, IoError, FRONT_LASER_MAX_PARAM,
};
use mapmerge_scan::{LaserLog, LaserScan, OdometryReading, ScanRecord};
use proptest::prelude::*;

/// One public log and what it must read as.
struct Expected {
    /// Path under the data folder.
    path: &'static str,
    /// Scan message tag.
    tag: &'static str,
    scans: usize,
    odometry: usize,
    beams: usize,
    /// `range_max_m` of every scan.
    max_range_m: f32,
    /// True when the log has a `PARAM robot_front_laser_max` (the max range is that value
    /// unless the readings contradict it).
    has_param: bool,
    /// Skipped `NEFF` lines.
    neff: usize,
}

const fn log(
    path: &'static str,
    scans: usize,
    odometry: usize,
    beams: usize,
    max_range_m: f32,
    has_param: bool,
) -> Expected {
    Expected {
        path,
        tag: "FLASER",
        scans,
        odometry,
        beams,
        max_range_m,
        has_param,
        neff: scans,
    }
}

/// The 14 logs of `carmen/`: FLASER counts from the data README, ODOM counts from the files,
/// max ranges from `old_laser_max_range_m` (see docs/formats.md).
#[rustfmt::skip]
const LOGS: &[Expected] = &[
    log("carmen/acapulco-corrected.log.xz", 861, 12142, 181, 51.09, false),
    log("carmen/aces-corrected.log.xz", 440, 7814, 180, 50.0, false),
    log("carmen/belgioioso-corrected.log.xz", 395, 4442, 361, 80.99, true),
    log("carmen/csail-corrected.log.xz", 406, 2394, 361, 50.0, true),
    // PARAM robot_front_laser_max 10 is overruled: 30 % of the readings lie beyond it.
    log("carmen/edmonton-corrected.log.xz", 340, 6351, 180, 51.09, true),
    log("carmen/fhw-corrected.log.xz", 488, 13935, 180, 51.05, false),
    log("carmen/freiburg-079-corrected.log.xz", 4791, 9725, 360, 80.99, true),
    log("carmen/freiburg-101-corrected.log.xz", 292, 4569, 360, 80.99, true),
    log("carmen/freiburg-campus-corrected.log.xz", 2008, 17691, 360, 80.99, true),
    log("carmen/infinite-corridor-corrected.log.xz", 1941, 18191, 180, 51.01, false),
    log("carmen/intel-corrected.log.xz", 910, 14541, 180, 81.83, false),
    log("carmen/orebro-corrected.log.xz", 237, 255, 181, 32.759, false),
    log("carmen/seattle-corrected.log.xz", 241, 19311, 361, 81.87, false),
    Expected {
        path: "carmen/robot-mapping-course/csail.log.xz",
        tag: "ROBOTLASER1",
        scans: 686,
        odometry: 0,
        beams: 361,
        max_range_m: 80.0,
        has_param: false,
        neff: 0,
    },
];

#[test]
fn every_log_on_disk_is_listed() {
    let Some(dir) = mapmerge_testkit::shared_data_dir() else {
        return;
    };
    let mut found = Vec::new();
    for sub in ["carmen", "carmen/robot-mapping-course"] {
        for entry in std::fs::read_dir(dir.join(sub)).unwrap().flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            if name.ends_with(".log.xz") || name.ends_with(".log") {
                found.push(format!("{sub}/{name}"));
            }
        }
    }
    found.sort();
    let mut listed: Vec<String> = LOGS.iter().map(|l| l.path.to_owned()).collect();
    listed.sort();
    assert_eq!(found, listed);
}

#[test]
fn every_log_loads_with_expected_counts_and_max_range() {
    for expected in LOGS {
        let Some(path) = mapmerge_testkit::shared_data(expected.path) else {
            return;
        };
        let log = read_carmen(&path).unwrap_or_else(|e| panic!("{e}"));
        let name = expected.path;
        assert_eq!(log.scans.len(), expected.scans, "{name}: scans");
        assert_eq!(log.odometry.len(), expected.odometry, "{name}: odometry");
        let neff = log.skipped_messages.get("NEFF").copied().unwrap_or(0);
        assert_eq!(neff, expected.neff, "{name}: NEFF");
        assert_eq!(
            log.skipped_messages.len(),
            usize::from(expected.neff > 0),
            "{name}: {:?}",
            log.skipped_messages
        );
        assert_eq!(
            log.params.contains_key(FRONT_LASER_MAX_PARAM),
            expected.has_param,
            "{name}"
        );
        for (k, record) in log.scans.iter().enumerate() {
            let scan = &record.scan;
            assert_eq!(record.source_tag, expected.tag, "{name}: scan {k}");
            assert_eq!(scan.len(), expected.beams, "{name}: scan {k}");
            assert_eq!(scan.range_max_m, expected.max_range_m, "{name}: scan {k}");
            assert_eq!(scan.range_min_m, 0.0);
            // The corrected logs store the same pose twice: the offset is exactly zero.
            assert_eq!(scan.robot_from_sensor, Se2::identity(), "{name}: scan {k}");
            assert!(record.odom_from_robot.is_some(), "{name}: scan {k}");
            // 180° (181/361 beams) or one step short of it (180/360 beams), from −90°.
            let last = scan.beam_angle_rad(scan.len() - 1);
            assert!((scan.angle_min_rad + FRAC_PI_2).abs() < 1e-6, "{name}");
            let span = if expected.beams % 2 == 1 {
                PI
            } else {
                PI - PI / expected.beams as f64
            };
            assert!(
                (last - scan.angle_min_rad - span).abs() < 2e-3,
                "{name}: {last}"
            );
            assert!(scan.ranges_m.iter().all(|r| r.is_finite() && *r >= 0.0));
        }
        // The limit leaves most beams as returns and catches the saturated ones.
        let beams: Vec<f32> = log
            .scans
            .iter()
            .flat_map(|r| r.scan.ranges_m.iter().copied())
            .collect();
        let returns = beams
            .iter()
            .filter(|&&r| log.scans[0].scan.is_return(r))
            .count();
        let fraction = returns as f64 / beams.len() as f64;
        assert!(
            fraction > 0.7,
            "{name}: only {fraction} of beams are returns"
        );
        let top = beams.iter().copied().fold(0.0, f32::max);
        assert!(
            !log.scans[0].scan.is_return(top),
            "{name}: {top} is a return"
        );
    }
}

#[test]
fn intel_first_scan_matches_the_file() {
    let Some(path) = mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz") else {
        return;
    };
    let log = read_carmen(&path).unwrap();
    // FLASER 180 … 1.22 1.23 0.600266 -0.0320327 -0.354665 0.600266 -0.0320327 -0.354665
    // 32.9068 pippo 32.9068
    let first = &log.scans[0];
    assert_eq!(first.stamp_secs, 32.9068);
    assert_eq!(
        first.odom_from_robot,
        Some(Se2::new(0.600266, -0.0320327, -0.354665))
    );
    assert_eq!(first.scan.ranges_m[178..], [1.22, 1.23]);
    assert_eq!(first.scan.angle_increment_rad, 1f64.to_radians());
    assert_eq!(first.scan.angle_min_rad, -FRAC_PI_2);
    assert_eq!(
        log.odometry[0],
        OdometryReading {
            stamp_secs: 0.000246,
            odom_from_robot: Se2::identity(),
            velocity_m_per_s: 0.0,
            turn_rate_rad_per_s: 0.0,
        }
    );
    assert_eq!(
        log.params
            .get("robot_frontlaser_offset")
            .map(String::as_str),
        Some("0.0")
    );
}

#[test]
fn csail_robotlaser_fields() {
    let Some(path) = mapmerge_testkit::shared_data("carmen/robot-mapping-course/csail.log.xz")
    else {
        return;
    };
    let log = read_carmen(&path).unwrap();
    let second = &log.scans[1];
    assert_eq!(second.stamp_secs, 1134864643.764189);
    // The file's `-1.570796` (π/2 to 6 digits), kept as written.
    assert_eq!(
        second.scan.angle_min_rad,
        "-1.570796".parse::<f64>().unwrap()
    );
    assert_eq!(second.scan.angle_increment_rad, 0.008727);
    assert_eq!(
        second.odom_from_robot,
        Some(Se2::new(0.319678, 0.110037, 0.994330))
    );
}

/// What a log must read back as after write → read: scans get the written tags, nothing is
/// skipped.
fn as_written(log: &LaserLog) -> LaserLog {
    let mut expected = log.clone();
    expected.skipped_messages.clear();
    for record in &mut expected.scans {
        record.source_tag = if record.odom_from_robot.is_some() {
            "ROBOTLASER1"
        } else {
            "RAWLASER1"
        }
        .to_owned();
    }
    expected
}

#[test]
fn every_log_round_trips() {
    let dir = std::env::temp_dir().join(format!("mapmerge-io-carmen-{}", std::process::id()));
    for expected in LOGS {
        let Some(path) = mapmerge_testkit::shared_data(expected.path) else {
            return;
        };
        let log = read_carmen(&path).unwrap();
        let text = format_carmen(&log).unwrap();
        let again = parse_carmen(&text, expected.path).unwrap();
        assert!(
            again == as_written(&log),
            "{}: round trip differs",
            expected.path
        );
        // The merged order is by stamp (for the logs whose stamps increase) and the file is
        // parseable by line-oriented CARMEN readers: one message per line.
        assert_eq!(
            text.lines().count(),
            log.params.len() + log.odometry.len() + log.scans.len()
        );
    }
    // Through a file, xz-compressed.
    let Some(path) = mapmerge_testkit::shared_data("carmen/orebro-corrected.log.xz") else {
        return;
    };
    let log = read_carmen(&path).unwrap();
    let out = dir.join("orebro.log.xz");
    write_carmen(&out, &log).unwrap();
    assert!(read_carmen(&out).unwrap() == as_written(&log));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn flaser_geometry_offsets_and_rear_laser() {
    let text = "\
# comment
PARAM robot_rear_laser_max 30 nohost 0
FLASER 3 1 2 3 1 2 0.5 1 2 0.5 10 h 10
FLASER 4 1 2 3 4 1.5 2 0 1 2 0 11 h 11
RLASER 2 5 30 0 0 3.141592653589793 0 0 0 12 h 12
";
    let log = parse_carmen(text, "t.log").unwrap();
    let [a, b, rear] = &log.scans[..] else {
        panic!("three scans")
    };
    assert_eq!(a.scan.angle_increment_rad, FRAC_PI_2);
    assert_eq!(b.scan.angle_increment_rad, PI / 4.0);
    assert_eq!(a.scan.robot_from_sensor, Se2::identity());
    let offset = b.scan.robot_from_sensor;
    // Laser 0.5 m ahead of the robot along its heading.
    assert!((offset.x_m - 0.5).abs() < 1e-15 && offset.y_m.abs() < 1e-15);
    assert_eq!(offset.theta_rad, 0.0);
    assert_eq!(rear.source_tag, "RLASER");
    assert_eq!(rear.scan.range_max_m, 30.0);
    assert_eq!(rear.scan.robot_from_sensor.theta_rad, PI);
    assert_eq!(rear.stamp_secs, 12.0);
    // No front max PARAM and only 7 front readings: no saturation cluster → 80 m.
    assert_eq!(a.scan.range_max_m, 80.0);
}

#[test]
fn front_max_param_wins_and_last_param_wins() {
    let text = "PARAM robot_front_laser_max 20 0 h 0\nFLASER 1 25 0 0 0 0 0 0 1 h 1\n\
                PARAM robot_front_laser_max 40 0 h 0\n";
    let log = parse_carmen(text, "t.log").unwrap();
    assert_eq!(log.scans[0].scan.range_max_m, 40.0);
    assert_eq!(log.params[FRONT_LASER_MAX_PARAM], "40");
}

#[test]
fn rawlaser_robotlaser_and_unknown_tags() {
    let text = "\
RAWLASER3 0 -1 2 0.5 30 0.01 0 5 1 2 3 4 5 2 7 8 100.5 host 0.5
ROBOTLASER2 0 -1.5 3 1 50 0.01 0 4 1 2 3 50 0 1 2 0.1 1 2 0.1 0.3 0.1 0 0 0 101 host 1
NEFF 30
TRUEPOS 1 2 3 1 2 3 0 h 0
NEFF 20
";
    let log = parse_carmen(text, "t.log").unwrap();
    let [raw, robot] = &log.scans[..] else {
        panic!("two scans")
    };
    assert_eq!(raw.source_tag, "RAWLASER3");
    assert_eq!(raw.odom_from_robot, None);
    assert_eq!(
        (raw.scan.angle_min_rad, raw.scan.angle_increment_rad),
        (-1.0, 0.5)
    );
    assert_eq!(raw.scan.range_max_m, 30.0);
    assert_eq!(raw.scan.ranges_m, [1.0, 2.0, 3.0, 4.0, 5.0]);
    assert_eq!(raw.stamp_secs, 100.5);
    assert_eq!(robot.odom_from_robot, Some(Se2::new(1.0, 2.0, 0.1)));
    assert_eq!(robot.scan.robot_from_sensor, Se2::identity());
    assert_eq!(robot.scan.range_max_m, 50.0);
    assert!(!robot.scan.is_return(50.0));
    let skipped: BTreeMap<String, usize> =
        [("NEFF".to_owned(), 2), ("TRUEPOS".to_owned(), 1)].into();
    assert_eq!(log.skipped_messages, skipped);
    // An empty text is an empty log.
    assert_eq!(parse_carmen("", "e.log").unwrap(), LaserLog::default());
}

#[test]
fn writer_merges_by_stamp_and_writes_the_documented_lines() {
    let odom = |t: f64| OdometryReading {
        stamp_secs: t,
        odom_from_robot: Se2::new(t, 0.0, 0.0),
        velocity_m_per_s: 0.5,
        turn_rate_rad_per_s: -0.25,
    };
    let scan = |t: f64, pose: Option<Se2>| ScanRecord {
        stamp_secs: t,
        scan: LaserScan::new(-FRAC_PI_2, FRAC_PI_2, 80.0, vec![1.0, 2.5, 80.0]),
        odom_from_robot: pose,
        source_tag: "FLASER".to_owned(),
    };
    let mut log = LaserLog {
        odometry: vec![odom(1.0), odom(2.0), odom(0.5)],
        scans: vec![scan(2.0, Some(Se2::new(1.0, 2.0, 0.5))), scan(1.5, None)],
        ..LaserLog::default()
    };
    log.params
        .insert("robot_front_laser_max".into(), "80".into());
    let text = format_carmen(&log).unwrap();
    let tags: Vec<&str> = text.lines().map(|l| l.split(' ').next().unwrap()).collect();
    // Odometry 1.0, then scan 2.0 waits for odometry 2.0 (odometry first on ties) and 0.5.
    assert_eq!(
        tags,
        ["PARAM", "ODOM", "ODOM", "ODOM", "ROBOTLASER1", "RAWLASER1"]
    );
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], "PARAM robot_front_laser_max 80 0 mapmerge 0");
    assert_eq!(lines[1], "ODOM 1 0 0 0.5 -0.25 0 1 mapmerge 1");
    assert_eq!(
        lines[4],
        "ROBOTLASER1 0 -1.5707963267948966 3.141592653589793 1.5707963267948966 80 0 0 3 \
         1 2.5 80 0 1 2 0.5 1 2 0.5 0 0 0 0 0 2 mapmerge 2"
    );
    assert_eq!(
        lines[5],
        "RAWLASER1 0 -1.5707963267948966 3.141592653589793 1.5707963267948966 80 0 0 3 \
         1 2.5 80 0 1.5 mapmerge 1.5"
    );
    assert!(parse_carmen(&text, "w.log").unwrap() == as_written(&log));
}

#[test]
fn unwritable_logs() {
    let record = ScanRecord {
        stamp_secs: 0.0,
        scan: LaserScan::new(-1.0, 1.0, 10.0, vec![1.0, f32::NAN]),
        odom_from_robot: Some(Se2::identity()),
        source_tag: "FLASER".to_owned(),
    };
    let mut log = LaserLog {
        scans: vec![record],
        ..LaserLog::default()
    };
    let err = format_carmen(&log).unwrap_err();
    assert_eq!(
        err.to_string(),
        "cannot write the data as CARMEN: scan 0 has a non-finite number"
    );
    log.scans[0].scan.ranges_m[1] = 2.0;
    log.scans[0].odom_from_robot = None;
    log.scans[0].scan.robot_from_sensor = Se2::new(0.1, 0.0, 0.0);
    let err = format_carmen(&log).unwrap_err();
    assert!(err.to_string().contains("no robot pose"), "{err}");
    log.scans.clear();
    log.params.insert("a b".into(), "1".into());
    assert!(matches!(
        format_carmen(&log),
        Err(IoError::Unwritable { .. })
    ));
}

/// Parses `text` expecting exactly `message` (`file:line: reason`).
#[track_caller]
fn expect_error(text: &str, message: &str) {
    match parse_carmen(text, "bad.log") {
        Err(err @ IoError::Parse { .. }) => assert_eq!(err.to_string(), message),
        other => panic!("expected {message:?}, got {other:?}"),
    }
}

#[test]
fn malformed_lines_give_file_line_reason() {
    expect_error(
        "ODOM 0 0 0 0 0 0 1 h\n",
        "bad.log:1: truncated ODOM line: expected 9 fields after the tag, found 8",
    );
    expect_error(
        "# c\nODOM 0 0 0 0 0 0 1 h 1 9\n",
        "bad.log:2: too many fields on ODOM line: expected 9 after the tag, found 10",
    );
    expect_error(
        "ODOM 0 x 0 0 0 0 1 h 1\n",
        "bad.log:1: field 2 `x` is not a number",
    );
    expect_error(
        "ODOM 0 0 0 0 0 0 nan h 1\n",
        "bad.log:1: field 7 `nan` is not a finite number",
    );
    expect_error(
        "ODOM 0 0 0 0 0 0 1 h inf\n",
        "bad.log:1: field 9 `inf` is not a finite number",
    );
    expect_error(
        "FLASER\n",
        "bad.log:1: truncated FLASER line: expected the beam count after the tag",
    );
    expect_error(
        "FLASER 3 1 2 0 0 0 0 0 0 1 h 1\n",
        "bad.log:1: truncated FLASER line: expected 13 fields after the tag (n = 3), found 12",
    );
    expect_error(
        "FLASER 1 1 2 0 0 0 0 0 0 1 h 1\n",
        "bad.log:1: too many fields on FLASER line: expected 11 after the tag (n = 1), found 12",
    );
    expect_error(
        "FLASER -2 1 2 0 0 0 0 0 0 1 h 1\n",
        "bad.log:1: field 1: negative beam count `-2`",
    );
    expect_error(
        "FLASER 1.5 1 0 0 0 0 0 0 1 h 1\n",
        "bad.log:1: field 1 `1.5` is not a beam count (non-negative integer)",
    );
    expect_error(
        "FLASER 99999999999999999999999 1 0 0 0 0 0 0 1 h 1\n",
        "bad.log:1: field 1: beam count `99999999999999999999999` is too large",
    );
    // A huge count that fits in usize is only compared with the line, never allocated.
    expect_error(
        "FLASER 18446744073709551000 1 0 0 0 0 0 0 1 h 1\n",
        "bad.log:1: truncated FLASER line: expected 18446744073709551010 fields after the tag \
         (n = 18446744073709551000), found 11",
    );
    expect_error(
        "FLASER 18446744073709551610 1 0 0 0 0 0 0 1 h 1\n",
        "bad.log:1: field 1: beam count `18446744073709551610` is too large",
    );
    expect_error(
        "RLASER 2 1 1e39 0 0 0 0 0 0 1 h 1\n",
        "bad.log:1: field 3 `1e39` is not a finite number",
    );
    expect_error(
        "FLASER 2 1 1 0 0 0 0 0 zero 1 h 1\n",
        "bad.log:1: field 9 `zero` is not a number",
    );
    expect_error(
        "ROBOTLASER1 0 -1.5 3 1 50 0.01 0\n",
        "bad.log:1: truncated ROBOTLASER1 line: expected at least 23 fields after the tag, \
         found 7",
    );
    expect_error(
        "ROBOTLASER1 0 -1.5 3 1 50 0.01 0 4 1 2 3 4\n",
        "bad.log:1: truncated ROBOTLASER1 line: expected at least 27 fields after the tag \
         (n = 4), found 12",
    );
    expect_error(
        "ROBOTLASER1 0 -1.5 3 1 50 0.01 0 1 1 2 7 0 0 0 0 0 0 0 0 0 0 0 1 h 1\n",
        "bad.log:1: truncated ROBOTLASER1 line: expected 26 fields after the tag \
         (n = 1, n_remissions = 2), found 25",
    );
    expect_error(
        "ROBOTLASER1 0 -1.5 3 1 50 0.01 0 1 1 x 0 0 0 0 0 0 0 0 0 0 0 1 h 1\n",
        "bad.log:1: field 10 `x` is not a remission count (non-negative integer)",
    );
    expect_error(
        "RAWLASER1 0 -1.5 3 1 50 0.01 0 1 1 1 nan 1 h 1\n",
        "bad.log:1: field 11 `nan` is not a finite number",
    );
    expect_error(
        "RAWLASER2 0 -1.5 3 1 50 0.01 0 1 1 0 1 h 1 2\n",
        "bad.log:1: too many fields on RAWLASER2 line: expected 13 after the tag \
         (n = 1, n_remissions = 0), found 14",
    );
    expect_error(
        "PARAM lonely\n",
        "bad.log:1: truncated PARAM line: expected a name and a value after the tag, found 1 \
         field(s)",
    );
    expect_error(
        "PARAM robot_front_laser_max big nohost 0\nFLASER 1 1 0 0 0 0 0 0 1 h 1\n",
        "bad.log:1: PARAM robot_front_laser_max `big` is not a positive number of metres",
    );
    // Errors name the right line in a longer file.
    expect_error(
        "PARAM a 1 nohost 0\n\n# x\nODOM 0 0 0 0 0 0 1 h 1\nODOM 0 0 0 0 0 0 1 h\n",
        "bad.log:5: truncated ODOM line: expected 9 fields after the tag, found 8",
    );
}

#[test]
fn invalid_utf8_is_reported_with_its_line() {
    let dir = std::env::temp_dir().join(format!("mapmerge-io-carmen-utf8-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bad.log");
    std::fs::write(&path, b"ODOM 0 0 0 0 0 0 1 h 1\nODOM \xff\n").unwrap();
    let err = read_carmen(&path).unwrap_err();
    assert_eq!(
        err.to_string(),
        format!("{}:2: invalid UTF-8", path.display())
    );
    let _ = std::fs::remove_dir_all(&dir);
}

fn coordinate() -> impl Strategy<Value = f64> {
    prop_oneof![
        6 => -1e3..1e3_f64,
        1 => -1e-7..1e-7_f64,
        1 => Just(0.0),
        1 => Just(-0.0),
    ]
}

fn pose() -> impl Strategy<Value = Se2> {
    (coordinate(), coordinate(), -4.0..4.0_f64).prop_map(|(x, y, t)| Se2::new(x, y, t))
}

fn range() -> impl Strategy<Value = f32> {
    prop_oneof![4 => 0.0..90.0_f32, 1 => Just(81.91_f32), 1 => Just(0.0_f32)]
}

fn stamp() -> impl Strategy<Value = f64> {
    prop_oneof![4 => 0.0..3000.0_f64, 1 => Just(1.13486e9), 1 => 1.1e9..1.2e9_f64]
}

fn odometry() -> impl Strategy<Value = OdometryReading> {
    (stamp(), pose(), -2.0..2.0_f64, -2.0..2.0_f64).prop_map(|(t, p, v, w)| OdometryReading {
        stamp_secs: t,
        odom_from_robot: p,
        velocity_m_per_s: v,
        turn_rate_rad_per_s: w,
    })
}

fn scan_record() -> impl Strategy<Value = ScanRecord> {
    let offset = prop_oneof![3 => Just(Se2::identity()), 1 => pose()];
    (
        stamp(),
        prop::option::of(pose()),
        offset,
        prop::collection::vec(range(), 0..40),
        -3.2..0.0_f64,
        0.001..0.1_f64,
        1.0..100.0_f32,
    )
        .prop_map(|(t, robot, offset, ranges, start, step, max)| ScanRecord {
            stamp_secs: t,
            scan: LaserScan {
                angle_min_rad: start,
                angle_increment_rad: step,
                range_min_m: 0.0,
                range_max_m: max,
                ranges_m: ranges,
                // RAWLASER1 cannot carry an offset.
                robot_from_sensor: if robot.is_some() {
                    offset
                } else {
                    Se2::identity()
                },
            },
            odom_from_robot: robot,
            source_tag: "FLASER".to_owned(),
        })
}

fn laser_log() -> impl Strategy<Value = LaserLog> {
    let params = prop::collection::btree_map("[a-z_]{1,12}", "[!-~]{1,8}", 0..5);
    (
        prop::collection::vec(odometry(), 0..20),
        prop::collection::vec(scan_record(), 0..12),
        params,
    )
        .prop_map(|(odometry, scans, params)| LaserLog {
            odometry,
            scans,
            params: params
                .into_iter()
                .filter(|(name, _)| !name.starts_with('#'))
                .collect(),
            skipped_messages: BTreeMap::new(),
        })
}

/// Equal except the non-identity sensor offsets, which are recomputed from two poses.
fn assert_round_trip(log: &LaserLog, again: &LaserLog) {
    let expected = as_written(log);
    let mut again = again.clone();
    for (got, want) in again.scans.iter_mut().zip(&expected.scans) {
        let (a, b) = (got.scan.robot_from_sensor, want.scan.robot_from_sensor);
        if b != Se2::identity() {
            let scale = 1.0
                + want
                    .odom_from_robot
                    .map_or(0.0, |p| p.x_m.abs() + p.y_m.abs());
            let d = a.between(&b).log().norm();
            assert!(d < 1e-12 * scale, "offset {a:?} vs {b:?}");
            got.scan.robot_from_sensor = b;
        }
    }
    assert_eq!(again, expected);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn random_logs_round_trip(log in laser_log()) {
        let text = format_carmen(&log).unwrap();
        let again = parse_carmen(&text, "random.log").unwrap();
        assert_round_trip(&log, &again);
        // Writing what was read gives the same text (offsets other than the identity are
        // recomputed, so only without them).
        if log.scans.iter().all(|r| r.scan.robot_from_sensor == Se2::identity()) {
            prop_assert_eq!(format_carmen(&again).ok(), Some(text));
        }
    }
}
