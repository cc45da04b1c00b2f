//! Arbitrary bytes as CDR messages of every type the bag reader and the live nodes decode: an
//! error or a message, never a panic; whatever decodes encodes again and decodes to the same
//! message. What decodes also goes where a live node sends it: a map is read as a grid, and
//! scans, odometry and tf go through a `ScanAssembler`.

#![no_main]

use libfuzzer_sys::fuzz_target;
use std::time::{Duration, Instant};

use mapmerge_rosbag::{
    decode, encode, ros_map_of_message, LaserScanMessage, OccupancyGridMessage, OdometryMessage,
    PointCloud2Message, ScanAssembler, TfMessage,
};

fn round_trip<T>(data: &[u8])
where
    T: serde::de::DeserializeOwned + serde::Serialize + PartialEq + std::fmt::Debug,
{
    let Ok(message) = decode::<T>(data) else {
        return;
    };
    let again: T = decode(&encode(&message).unwrap()).unwrap();
    // NaN != NaN: compare the encodings instead.
    assert_eq!(encode(&again).unwrap(), encode(&message).unwrap());
}

fuzz_target!(|data: &[u8]| {
    round_trip::<LaserScanMessage>(data);
    round_trip::<OdometryMessage>(data);
    round_trip::<TfMessage>(data);
    round_trip::<PointCloud2Message>(data);
    round_trip::<OccupancyGridMessage>(data);
    if let Ok(cloud) = decode::<PointCloud2Message>(data) {
        let _ = mapmerge_rosbag::cloud_points(&cloud);
    }
    if let Ok(map) = decode::<OccupancyGridMessage>(data) {
        if let Ok(read) = ros_map_of_message(&map) {
            let _ = read.to_grid();
        }
    }
    let mut live = ScanAssembler::new();
    let start = Instant::now();
    if let Ok(tf) = decode::<TfMessage>(data) {
        let _ = live.tf(&tf, true);
        let _ = live.tf(&tf, false);
    }
    if let Ok(odometry) = decode::<OdometryMessage>(data) {
        let _ = live.odometry(&odometry);
    }
    if let Ok(scan) = decode::<LaserScanMessage>(data) {
        live.scan(scan.clone(), start);
        live.scan(scan, start);
    }
    let _ = live.next_record(start);
    let _ = live.next_record(start + Duration::from_secs(1));
});
