//! Bags written by tools nobody on mapmerge wrote (`rosbags`, `mcap-ros2-support`, from
//! PyPI; `scripts/bag_interop.py`) read back as the CARMEN original, scan for scan, for every
//! public log. `MAPMERGE_BAG_PYTHON` names a Python with those packages (`.ci/run` makes
//! one); without it the test skips, except under `CI=true`.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use std::path::PathBuf;
use std::process::Command;

use common::{assert_same_session, LOGS};
use mapmerge_rosbag::{read_bag, write_bag, BagWriteParams, Storage, TopicChoice};

#[test]
fn bags_written_by_rosbags_and_mcap_ros2_read_back_as_the_carmen_logs() {
    let what = "a Python with rosbags, mcap and mcap-ros2-support";
    let Some(python) = mapmerge_testkit::tool_from_env("MAPMERGE_BAG_PYTHON", what) else {
        return;
    };
    let Some(data) = mapmerge_testkit::shared_data_dir() else {
        return;
    };
    let script = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../scripts/bag_interop.py"
    ));
    let out = tempfile::tempdir().unwrap();
    for name in LOGS {
        let original =
            mapmerge_io::read_carmen(&data.join(format!("carmen/{name}-corrected.log.xz")))
                .unwrap();
        let ours = out.path().join(format!("{name}.mcap"));
        let written = write_bag(&ours, &original, &BagWriteParams::default()).unwrap();
        let rewritten = out.path().join(name);
        let status = Command::new(&python)
            .arg(&script)
            .arg(&ours)
            .arg(&rewritten)
            .output()
            .unwrap();
        assert!(
            status.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&status.stderr)
        );
        for (bag, storage) in [
            (rewritten.join("rosbags-mcap"), Storage::Mcap),
            (rewritten.join("rosbags-db3"), Storage::Sqlite3),
            (rewritten.join("mcap-ros2.mcap"), Storage::Mcap),
            (rewritten.join("mcap-ros2-lz4.mcap"), Storage::Mcap),
        ] {
            let session = read_bag(&bag, &TopicChoice::default()).unwrap();
            assert_eq!(session.info.storage, storage, "{}", bag.display());
            let label = format!("{name} via {}", bag.display());
            assert_same_session(
                &original,
                &session.log,
                written.stamps_rewritten.is_none(),
                &label,
            );
        }
    }
}
