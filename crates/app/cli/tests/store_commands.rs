//! Integration tests of `mapmerge store`: info, versions, check and rollback on a store, and
//! refused files (exit code 2, left untouched).

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::{ok_json, p, run, scratch};
use mapmerge_store::{Store, VersionInfo};

fn session(name: &str, nodes: i64) -> VersionInfo {
    VersionInfo {
        version: 0,
        parent: None,
        session: name.into(),
        created: 0,
        nodes,
        edges: nodes + 5,
        keyframes: nodes / 2,
        local_maps: nodes / 3,
        mapped_area_m2: 42.0,
        bytes: 0,
    }
}

#[test]
fn store_commands_read_check_and_roll_back_a_store() {
    let dir = scratch("store-commands");
    let site = dir.join("site.mapmerge");
    {
        let mut store = Store::open(&site).unwrap();
        for (name, nodes) in [("monday", 30), ("tuesday", 36), ("wednesday", 40)] {
            store.commit_version(&session(name, nodes)).unwrap();
        }
    }
    let info = ok_json(&["store", "info", p(&site), "--json"]);
    assert_eq!(info["versions"], 3);
    assert_eq!(info["session"], "wednesday");
    assert_eq!(info["nodes"], 40);
    assert_eq!(info["edges"], 45);
    assert!(info["bytes"].as_u64().unwrap() > 0);
    assert_eq!(info["schema_version"], mapmerge_store::SCHEMA_VERSION);
    let versions = ok_json(&["store", "versions", p(&site), "--json"]);
    let list = versions["versions"].as_array().unwrap();
    assert_eq!(list.len(), 3);
    assert_eq!(list[1]["parent"], 1);
    assert_eq!(list[1]["nodes"], 36);
    assert!(list[1]["bytes"].as_i64().unwrap() > 0);
    assert!(list[1]["created"].as_i64().unwrap() > 1_700_000_000);
    assert_eq!(
        ok_json(&["store", "check", p(&site), "--json"])["intact"],
        true
    );
    let rolled = ok_json(&["store", "rollback", p(&site), "--to", "1", "--json"]);
    assert_eq!(rolled["deleted_versions"], 2);
    let versions = ok_json(&["store", "versions", p(&site), "--json"]);
    assert_eq!(versions["versions"].as_array().unwrap().len(), 1);
    // A version that is not there is an error, and changes nothing.
    let out = run(&["store", "rollback", p(&site), "--to", "9"]);
    assert_eq!(out.status.code(), Some(2));
    assert_eq!(
        ok_json(&["store", "info", p(&site), "--json"])["versions"],
        1
    );
}

#[test]
fn store_commands_refuse_what_is_not_a_store() {
    let dir = scratch("store-refused");
    let missing = dir.join("missing.mapmerge");
    let out = run(&["store", "info", p(&missing)]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no such store"));
    assert!(!missing.exists());
    let text = dir.join("notes.mapmerge");
    std::fs::write(
        &text,
        "these are notes, not a map store; long enough for a header",
    )
    .unwrap();
    let before = std::fs::read(&text).unwrap();
    for command in ["info", "versions", "check"] {
        let out = run(&["store", command, p(&text)]);
        assert_eq!(out.status.code(), Some(2), "{command}");
        assert!(
            String::from_utf8_lossy(&out.stderr).contains("not a mapmerge store"),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    assert_eq!(std::fs::read(&text).unwrap(), before);
}
