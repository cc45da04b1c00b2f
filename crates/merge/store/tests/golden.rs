//! Golden stores: a file written by every released schema version (testdata/stores/) opens,
//! is upgraded to the current schema, keeps its versions and goes on taking sessions. A
//! user's map is never stranded by an upgrade.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;
use std::path::PathBuf;

use mapmerge_atlas::{Atlas, AtlasParams, EpochEndReason};
use mapmerge_store::{SessionCommit, Store, StoreError, SCHEMA_VERSION};

fn golden(schema: i64) -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../testdata/stores"
    ))
    .join(format!("schema-{schema}.mapmerge"))
}

/// A copy of the golden store of `schema`, opened (and so upgraded), with its versions as
/// they were listed before.
fn upgraded(schema: i64, dir: &std::path::Path) -> (Store, Vec<(i64, String)>) {
    let path = dir.join(format!("schema-{schema}.mapmerge"));
    std::fs::copy(golden(schema), &path).unwrap();
    let listed = {
        let raw = rusqlite::Connection::open(&path).unwrap();
        let version: i64 = raw
            .pragma_query_value(None, "user_version", |row| row.get(0))
            .unwrap();
        assert_eq!(version, schema, "the golden file is of schema {schema}");
        let mut statement = raw
            .prepare("SELECT version, session FROM versions ORDER BY version")
            .unwrap();
        let rows = statement
            .query_map([], |row| Ok((row.get(0)?, row.get(1)?)))
            .unwrap();
        rows.collect::<Result<Vec<_>, _>>().unwrap()
    };
    let store = Store::open(&path).unwrap();
    assert_eq!(store.info().unwrap().schema_version, SCHEMA_VERSION);
    store.check().unwrap();
    let now: Vec<(i64, String)> = store
        .versions()
        .unwrap()
        .into_iter()
        .map(|v| (v.version, v.session))
        .collect();
    assert_eq!(now, listed, "an upgrade keeps every version");
    (store, listed)
}

#[test]
fn every_schema_version_has_a_golden_store() {
    for schema in 1..=SCHEMA_VERSION {
        assert!(
            golden(schema).is_file(),
            "testdata/stores/schema-{schema}.mapmerge is missing: add the golden store of every schema"
        );
    }
}

#[test]
fn a_schema_1_store_is_upgraded_and_its_atlas_starts_with_the_next_session() {
    let dir = tempfile::tempdir().unwrap();
    let (mut store, listed) = upgraded(1, dir.path());
    assert_eq!(listed.len(), 3);
    // Schema 1 stored version summaries only: there is no atlas to continue.
    assert!(matches!(
        store.load(None),
        Err(StoreError::NoAtlas { version: 3, .. })
    ));
    let atlas = Atlas::new(AtlasParams::default())
        .unwrap()
        .snapshot()
        .unwrap();
    let version = store
        .commit_session(&SessionCommit {
            session: "thursday",
            atlas: &atlas,
            events: &[],
            reference_poses: &BTreeMap::new(),
        })
        .unwrap();
    assert_eq!(version, 4);
    assert_eq!(store.versions().unwrap()[3].parent, Some(3));
    assert_eq!(store.load(None).unwrap().unwrap().atlas, atlas);
    store.check().unwrap();
}

#[test]
fn stores_of_schema_2_on_are_continued() {
    for schema in 2..=SCHEMA_VERSION {
        continued(schema);
    }
}

/// The golden store of `schema`, upgraded, restored into an atlas and given one more session.
fn continued(schema: i64) {
    let dir = tempfile::tempdir().unwrap();
    let (mut store, listed) = upgraded(schema, dir.path());
    let stored = store.load(None).unwrap().unwrap();
    assert_eq!(stored.version, listed.last().unwrap().0);
    assert!(stored.atlas.num_vertices() > 0);
    assert!(!stored.reference_poses.is_empty());
    let mut atlas: Atlas =
        Atlas::restore(AtlasParams::default(), Default::default(), stored.atlas).unwrap();
    atlas.end_epoch(EpochEndReason::Restart);
    let snapshot = atlas.snapshot().unwrap();
    let version = store
        .commit_session(&SessionCommit {
            session: "next",
            atlas: &snapshot,
            events: &[],
            reference_poses: &BTreeMap::new(),
        })
        .unwrap();
    assert_eq!(version, stored.version + 1);
    assert_eq!(store.load(None).unwrap().unwrap().atlas, snapshot);
    store.check().unwrap();
}

#[test]
fn a_schema_4_store_keeps_its_areas_through_an_atlas_session() {
    let dir = tempfile::tempdir().unwrap();
    let (mut store, listed) = upgraded(4, dir.path());
    let areas = store.load_areas(None).unwrap().unwrap();
    assert_eq!(areas.version, listed.last().unwrap().0);
    assert!(!areas.sessions.is_empty());
    assert!(areas.map.hybrid.areas.len() >= 2);
    let stored = store.load(None).unwrap().unwrap();
    let mut atlas: Atlas =
        Atlas::restore(AtlasParams::default(), Default::default(), stored.atlas).unwrap();
    atlas.end_epoch(EpochEndReason::Restart);
    store
        .commit_session(&SessionCommit {
            session: "next",
            atlas: &atlas.snapshot().unwrap(),
            events: &[],
            reference_poses: &BTreeMap::new(),
        })
        .unwrap();
    let kept = store.load_areas(None).unwrap().unwrap();
    assert_eq!((kept.sessions, kept.map), (areas.sessions, areas.map));
    store.check().unwrap();
}

/// Issue 67: a read-only command does not upgrade an older store; it says what will.
#[test]
fn an_older_store_is_not_upgraded_by_a_reader() {
    let dir = tempfile::tempdir().unwrap();
    for schema in 1..SCHEMA_VERSION {
        let path = dir.path().join(format!("schema-{schema}.mapmerge"));
        std::fs::copy(golden(schema), &path).unwrap();
        let before = std::fs::read(&path).unwrap();
        let error = Store::open_read_only(&path).unwrap_err();
        assert!(
            matches!(error, StoreError::OlderSchema { found, .. } if found == schema),
            "{error}"
        );
        assert!(error.to_string().contains("upgrades it"), "{error}");
        assert_eq!(std::fs::read(&path).unwrap(), before);
    }
}
