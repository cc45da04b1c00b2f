//! Integration tests of the lifelong store from the command line: `atlas --store` session by
//! session; `store` info, versions, check, export and rollback; refused files (exit code 2,
//! left untouched).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common::{ok_json, p, run, scratch, testdata};
use mapmerge_store::Store;

/// One simulated session of the office, continued from and committed to `site`.
fn live_session(
    site: &std::path::Path,
    index: usize,
    output: &std::path::Path,
) -> serde_json::Value {
    let index = index.to_string();
    ok_json(&[
        "atlas",
        "--sim",
        "office",
        "--session-index",
        &index,
        "--duration",
        "40",
        "--no-pictures",
        "--store",
        p(site),
        "-o",
        p(output),
        "--json",
    ])
}

#[test]
fn the_atlas_lives_on_in_a_store_that_the_store_commands_read_export_and_roll_back() {
    let dir = scratch("store-commands");
    let site = dir.join("site.mapmerge");
    let monday = live_session(&site, 0, &dir.join("monday"));
    assert_eq!(monday["store"]["resumed_from"], serde_json::Value::Null);
    assert_eq!(monday["store"]["committed"][0]["version"], 1);
    let tuesday = live_session(&site, 1, &dir.join("tuesday"));
    assert_eq!(tuesday["store"]["resumed_from"], 1);
    let committed = &tuesday["store"]["committed"][0];
    assert_eq!(committed["version"], 2);
    assert!(
        committed["session_ate_m"].as_f64().unwrap() < 0.2,
        "{committed}"
    );
    // Tuesday's map holds Monday's vertices too.
    let monday_nodes = monday["store"]["committed"][0]["nodes"].as_i64().unwrap();
    assert!(committed["nodes"].as_i64().unwrap() > monday_nodes);

    let info = ok_json(&["store", "info", p(&site), "--json"]);
    assert_eq!(info["versions"], 2);
    assert_eq!(info["session"], "office session 1");
    assert_eq!(info["nodes"], committed["nodes"]);
    assert!(info["mapped_area_m2"].as_f64().unwrap() > 50.0);
    assert!(info["bytes"].as_u64().unwrap() > 0);
    assert_eq!(info["schema_version"], mapmerge_store::SCHEMA_VERSION);
    let versions = ok_json(&["store", "versions", p(&site), "--json"]);
    let list = versions["versions"].as_array().unwrap();
    assert_eq!(list.len(), 2);
    for key in [
        "version",
        "session",
        "created",
        "nodes",
        "edges",
        "keyframes",
        "local_maps",
        "bytes",
    ] {
        assert!(list[1].get(key).is_some(), "{key}");
    }
    assert_eq!(list[1]["parent"], 1);
    assert!(list[1]["created"].as_i64().unwrap() > 1_700_000_000);
    assert_eq!(
        ok_json(&["store", "check", p(&site), "--json"])["intact"],
        true
    );

    // Export: every map as g2o, map_server map, picture and trajectories.
    let exported = ok_json(&[
        "store",
        "export",
        p(&site),
        "-o",
        p(&dir.join("export")),
        "--json",
    ]);
    assert_eq!(exported["version"], 2);
    let maps = exported["maps"].as_array().unwrap();
    assert!(!maps.is_empty());
    for map in maps {
        for key in ["g2o", "map_yaml", "png"] {
            assert!(
                std::path::Path::new(map[key].as_str().unwrap()).is_file(),
                "{key}"
            );
        }
        assert!(!map["trajectories"].as_array().unwrap().is_empty());
    }
    let g2o = std::fs::read_to_string(maps[0]["g2o"].as_str().unwrap()).unwrap();
    assert!(g2o.lines().any(|l| l.starts_with("VERTEX_SE2")));
    let old = ok_json(&[
        "store",
        "export",
        p(&site),
        "--version",
        "1",
        "-o",
        p(&dir.join("export-1")),
        "--json",
    ]);
    assert_eq!(old["version"], 1);

    // Protrusions: Tuesday against Monday, region by region.
    let checked = ok_json(&["store", "protrusions", p(&site), "--json"]);
    assert_eq!(checked["version"], 2);
    assert_eq!(checked["parent"], 1);
    for region in checked["regions"].as_array().unwrap() {
        assert!(region["features"]["area_m2"].as_f64().unwrap() >= 0.25);
        assert!(region["protrusion"].is_boolean());
    }
    assert_eq!(checked["rolled_back"], false);
    let first = run(&["store", "protrusions", p(&site), "--version", "1"]);
    assert_eq!(first.status.code(), Some(2), "version 1 has no parent");

    // Roll back Tuesday and live it again: version 2 once more, continuing version 1.
    let rolled = ok_json(&["store", "rollback", p(&site), "--to", "1", "--json"]);
    assert_eq!(rolled["deleted_versions"], 1);
    let again = live_session(&site, 1, &dir.join("tuesday-again"));
    assert_eq!(again["store"]["resumed_from"], 1);
    assert_eq!(again["store"]["committed"][0]["version"], 2);
    assert_eq!(again["store"]["committed"][0]["nodes"], committed["nodes"]);
    // A version that is not there is an error, and changes nothing.
    let out = run(&["store", "rollback", p(&site), "--to", "9"]);
    assert_eq!(out.status.code(), Some(2));
    assert_eq!(
        ok_json(&["store", "info", p(&site), "--json"])["versions"],
        2
    );

    // A store in use by another process is refused (exit 2) and left as it was. (The file is
    // read before it is held: closing any handle of a file drops the process's POSIX locks.)
    let before = std::fs::read(&site).unwrap();
    let held = Store::open(&site).unwrap();
    let out = run(&[
        "atlas",
        "--sim",
        "office",
        "--session-index",
        "2",
        "--duration",
        "10",
        "--no-pictures",
        "--store",
        p(&site),
        "-o",
        p(&dir.join("refused")),
    ]);
    assert_eq!(
        out.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stderr).contains("in use"));
    drop(held);
    assert_eq!(std::fs::read(&site).unwrap(), before);
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

/// Issue 67: what a store command cannot use exits 2, says why, and writes nothing: an empty
/// file, a damaged store (checked before `rollback` writes), no version to keep, a session
/// without scans (no store is left behind).
#[test]
fn store_writers_refuse_what_they_cannot_use_and_write_nothing() {
    let dir = scratch("store-hostile");
    let refused = |args: &[&str], says: &str| {
        let out = run(args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(says), "{args:?}: {stderr}");
    };
    let empty = dir.join("empty.mapmerge");
    std::fs::write(&empty, b"").unwrap();
    refused(&["store", "info", p(&empty)], "an empty file");
    refused(
        &["store", "rollback", p(&empty), "--to", "1"],
        "an empty file",
    );
    assert_eq!(std::fs::metadata(&empty).unwrap().len(), 0);

    let site = dir.join("site.mapmerge");
    let golden = testdata(&format!(
        "stores/schema-{}.mapmerge",
        mapmerge_store::SCHEMA_VERSION
    ));
    std::fs::copy(golden, &site).unwrap();
    rusqlite::Connection::open(&site)
        .unwrap()
        .execute_batch("DROP TABLE events")
        .unwrap();
    let damaged = std::fs::read(&site).unwrap();
    refused(&["store", "check", p(&site)], "table events is missing");
    refused(
        &["store", "rollback", p(&site), "--to", "1"],
        "table events is missing",
    );
    assert_eq!(std::fs::read(&site).unwrap(), damaged);

    let fresh = dir.join("fresh.mapmerge");
    let session = [
        "atlas",
        "--sim",
        "office",
        "--duration",
        "10",
        "--no-pictures",
    ];
    let out = dir.join("out");
    refused(
        &[
            &session[..],
            &["--store", p(&fresh), "--keep-versions", "0", "-o", p(&out)],
        ]
        .concat(),
        "--keep-versions must be at least 1",
    );
    let log = dir.join("empty.log");
    std::fs::write(&log, b"").unwrap();
    refused(
        &["atlas", p(&log), "--store", p(&fresh), "-o", p(&out)],
        "no scans",
    );
    assert!(!fresh.exists(), "a store was left behind");
}
