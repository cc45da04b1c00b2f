//! Arbitrary bytes as an MCAP bag into `parse_mcap_session`: an error or a session, never a
//! panic; a session's scans have non-decreasing stamps and, with odometry, finite poses.

#![no_main]

use libfuzzer_sys::fuzz_target;
use mapmerge_geometry::LieGroup as _;
use mapmerge_rosbag::{parse_mcap_session, TopicChoice};

fuzz_target!(|data: &[u8]| {
    let Ok(log) = parse_mcap_session(data, &TopicChoice::default()) else {
        return;
    };
    assert!(!log.scans.is_empty());
    for pair in log.scans.windows(2) {
        assert!(pair[1].stamp_secs >= pair[0].stamp_secs);
    }
    for record in &log.scans {
        if let Some(pose) = &record.odom_from_robot {
            assert!(pose.is_finite());
        }
    }
});
