//! Arbitrary bytes (lossy UTF-8) into `parse_carmen`; whatever parses must write (unless a
//! number overflows to infinity on the way) and read back with the same odometry, parameters,
//! ranges, max ranges and robot poses.

#![no_main]

use libfuzzer_sys::fuzz_target;
use mapmerge_io::{format_carmen, parse_carmen, IoError};

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let Ok(log) = parse_carmen(&text, "fuzz") else {
        return;
    };
    let written = match format_carmen(&log) {
        Ok(written) => written,
        Err(IoError::Unwritable { reason, .. }) if reason.contains("non-finite") => return,
        Err(err) => panic!("a parsed log must be writable: {err}"),
    };
    let again = match parse_carmen(&written, "fuzz-again") {
        Ok(again) => again,
        Err(err) => panic!("re-parse failed: {err}\n--- written:\n{written}"),
    };
    assert_eq!(again.odometry, log.odometry);
    assert_eq!(again.params, log.params);
    assert_eq!(again.scans.len(), log.scans.len());
    for (a, b) in again.scans.iter().zip(&log.scans) {
        assert_eq!(a.stamp_secs, b.stamp_secs);
        assert_eq!(a.scan.ranges_m, b.scan.ranges_m);
        assert_eq!(a.scan.range_max_m, b.scan.range_max_m);
        assert_eq!(a.scan.angle_min_rad, b.scan.angle_min_rad);
        assert_eq!(a.scan.angle_increment_rad, b.scan.angle_increment_rad);
        assert_eq!(a.odom_from_robot, b.odom_from_robot);
    }
});
