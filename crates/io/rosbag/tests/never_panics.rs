//! The stable-Rust companion of the fuzz targets `parse_bag` and `decode_cdr`: mutated and
//! truncated bags and messages give errors or sessions, never a panic.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_geometry::Se2;
use mapmerge_rosbag::{
    decode, encode, parse_mcap_session, write_bag, BagWriteParams, LaserScanMessage,
    OdometryMessage, TfMessage, TopicChoice,
};
use mapmerge_scan::{LaserLog, LaserScan, ScanRecord};

/// xorshift64*: a repeatable stream of mutations without a dependency.
struct Mutations(u64);

impl Mutations {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
    /// `bytes` with 1–4 bytes overwritten, or cut short.
    fn mutate(&mut self, bytes: &[u8]) -> Vec<u8> {
        let mut out = bytes.to_vec();
        if self.below(4) == 0 {
            out.truncate(self.below(bytes.len()));
            return out;
        }
        for _ in 0..1 + self.below(4) {
            let at = self.below(out.len());
            out[at] = self.next() as u8;
        }
        out
    }
}

fn small_bag() -> Vec<u8> {
    let mut log = LaserLog::default();
    for k in 0..6 {
        let mut scan = LaserScan::new(-1.0, 1.0, 20.0, vec![2.0, 3.0, 4.0, 5.0]);
        scan.robot_from_sensor = Se2::new(0.1, 0.0, 0.2);
        log.scans.push(ScanRecord {
            stamp_secs: 1.0 + 0.1 * k as f64,
            scan,
            odom_from_robot: Some(Se2::new(0.1 * k as f64, 0.0, 0.0)),
            source_tag: "FLASER".into(),
        });
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("small.mcap");
    write_bag(&path, &log, &BagWriteParams::default()).unwrap();
    std::fs::read(path).unwrap()
}

#[test]
fn mutated_mcap_bags_never_panic() {
    let bag = small_bag();
    assert_eq!(
        parse_mcap_session(&bag, &TopicChoice::default())
            .unwrap()
            .scans
            .len(),
        6
    );
    let mut mutations = Mutations(0x9E37_79B9_7F4A_7C15);
    let mut sessions = 0;
    for _ in 0..3000 {
        if let Ok(log) = parse_mcap_session(&mutations.mutate(&bag), &TopicChoice::default()) {
            sessions += 1;
            assert!(log
                .scans
                .windows(2)
                .all(|w| w[1].stamp_secs >= w[0].stamp_secs));
        }
    }
    // Most single-byte changes land in ranges or padding and still read.
    assert!(sessions > 100, "{sessions}");
}

#[test]
fn mutated_cdr_messages_never_panic() {
    let mut scan = LaserScanMessage {
        ranges: vec![1.0; 16],
        ..Default::default()
    };
    scan.header.frame_id = "laser".into();
    let originals = [
        encode(&scan).unwrap(),
        encode(&OdometryMessage::default()).unwrap(),
        encode(&TfMessage::default()).unwrap(),
    ];
    let mut mutations = Mutations(42);
    for original in &originals {
        for _ in 0..3000 {
            let bytes = mutations.mutate(original);
            let _ = decode::<LaserScanMessage>(&bytes);
            let _ = decode::<OdometryMessage>(&bytes);
            let _ = decode::<TfMessage>(&bytes);
        }
    }
}

/// Found by the fuzz target `parse_bag`: an uncompressed chunk whose record is longer than the
/// chunk made the `mcap` crate's chunk reader subtract past zero (a panic with overflow checks).
/// Chunks are now opened by `storage::chunk_records`; the bag is an error.
#[test]
fn a_record_longer_than_its_chunk_is_an_error() {
    let bytes = include_bytes!("data/chunk_record_longer_than_chunk.mcap");
    assert!(parse_mcap_session(bytes, &TopicChoice::default()).is_err());
}

/// Found by the fuzz target `parse_bag`: an attachment record shorter than its own fields made
/// `mcap::parse_record` slice out of bounds. Records the reader does not need are skipped.
#[test]
fn a_short_attachment_is_skipped() {
    let bytes = include_bytes!("data/short_attachment.mcap");
    let _ = parse_mcap_session(bytes, &TopicChoice::default());
}

/// Issue 67: a bag directory whose metadata.yaml nests flow lists deeply is refused at once,
/// naming the file and line (the YAML parser once took minutes on 300 KB of it).
#[test]
fn deeply_nested_bag_metadata_is_refused_before_parsing() {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("bag");
    std::fs::create_dir(&bag).unwrap();
    let nested = format!(
        "rosbag2_bagfile_information:\n  relative_file_paths: {}\n",
        "[".repeat(100_000)
    );
    std::fs::write(bag.join("metadata.yaml"), nested).unwrap();
    let error = mapmerge_rosbag::read_log(&bag, &TopicChoice::default()).unwrap_err();
    let text = error.to_string();
    assert!(
        text.contains("metadata.yaml:2: nested deeper than"),
        "{text}"
    );
}
