//! Arbitrary bytes as CDR messages of every type the bag reader decodes: an error or a
//! message, never a panic; whatever decodes encodes again and decodes to the same message.

#![no_main]

use libfuzzer_sys::fuzz_target;
use mapmerge_rosbag::{
    decode, encode, LaserScanMessage, OdometryMessage, PointCloud2Message, TfMessage,
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
    if let Ok(cloud) = decode::<PointCloud2Message>(data) {
        let _ = mapmerge_rosbag::cloud_points(&cloud);
    }
});
