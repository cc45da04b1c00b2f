//! Opening stores: created, reopened, upgraded; refused without being modified.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_store::{Store, StoreError, VersionInfo, SCHEMA_VERSION};

fn counts(session: &str, nodes: i64) -> VersionInfo {
    VersionInfo {
        version: 0,
        parent: None,
        session: session.into(),
        created: 0,
        nodes,
        edges: 2 * nodes,
        keyframes: nodes / 2,
        local_maps: nodes / 4,
        mapped_area_m2: 120.5,
        bytes: 0,
    }
}

#[test]
fn a_new_store_keeps_its_versions_across_reopening_and_rolls_back() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("site.mapmerge");
    {
        let mut store = Store::open(&path).unwrap();
        assert_eq!(store.versions().unwrap(), vec![]);
        assert_eq!(store.commit_version(&counts("monday", 100)).unwrap(), 1);
        assert_eq!(store.commit_version(&counts("tuesday", 120)).unwrap(), 2);
        store.check().unwrap();
    }
    let mut store = Store::open_existing(&path).unwrap();
    let versions = store.versions().unwrap();
    assert_eq!(versions.len(), 2);
    assert_eq!(versions[1].parent, Some(1));
    assert_eq!(versions[1].session, "tuesday");
    assert_eq!(versions[1].edges, 240);
    let info = store.info().unwrap();
    assert_eq!(info.schema_version, SCHEMA_VERSION);
    assert_eq!(info.versions, 2);
    assert!(info.bytes > 0);
    assert!(matches!(
        store.rollback_to(7),
        Err(StoreError::NoSuchVersion { version: 7, .. })
    ));
    assert_eq!(store.rollback_to(1).unwrap(), 1);
    assert_eq!(store.versions().unwrap().len(), 1);
    assert_eq!(store.commit_version(&counts("wednesday", 90)).unwrap(), 2);
    store.check().unwrap();
}

#[test]
fn a_store_held_by_another_connection_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("site.mapmerge");
    let _held = Store::open(&path).unwrap();
    let error = Store::open(&path).unwrap_err();
    assert!(matches!(error, StoreError::Locked { .. }), "{error}");
    assert!(error.to_string().contains("in use"), "{error}");
}

#[test]
fn a_missing_store_is_an_error_unless_created() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("none.mapmerge");
    assert!(Store::open_existing(&path).is_err());
    assert!(!path.exists());
}

/// The file's bytes, to show that a refused store was not modified.
fn bytes(path: &std::path::Path) -> Vec<u8> {
    std::fs::read(path).unwrap()
}

/// The error of opening a store whose schema version was set to `version`; the file is
/// checked to be byte for byte what it was.
fn refused_with_schema_version(version: i64) -> StoreError {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("site.mapmerge");
    drop(Store::open(&path).unwrap());
    rusqlite_connection(&path)
        .pragma_update(None, "user_version", version)
        .unwrap();
    let before = bytes(&path);
    let error = Store::open(&path).unwrap_err();
    assert_eq!(bytes(&path), before);
    error
}

#[test]
fn a_newer_schema_is_refused_and_left_untouched() {
    let error = refused_with_schema_version(SCHEMA_VERSION + 1);
    assert!(
        matches!(error, StoreError::NewerSchema { found, .. } if found == SCHEMA_VERSION + 1),
        "{error}"
    );
}

#[test]
fn a_negative_schema_version_is_corruption_and_left_untouched() {
    let error = refused_with_schema_version(-3);
    assert!(matches!(error, StoreError::Corrupt { .. }), "{error}");
}

#[test]
fn files_that_are_not_stores_are_refused_and_left_untouched() {
    let dir = tempfile::tempdir().unwrap();
    // Text.
    let text = dir.path().join("notes.mapmerge");
    std::fs::write(
        &text,
        "not a database at all, but long enough to have a header .....",
    )
    .unwrap();
    let before = bytes(&text);
    let error = Store::open(&text).unwrap_err();
    assert!(matches!(error, StoreError::NotAStore { .. }), "{error}");
    assert_eq!(bytes(&text), before);
    // Another application's SQLite database.
    let other = dir.path().join("other.sqlite");
    {
        let raw = rusqlite_connection(&other);
        raw.execute_batch("CREATE TABLE t (x INTEGER); INSERT INTO t VALUES (1);")
            .unwrap();
    }
    let before = bytes(&other);
    let error = Store::open(&other).unwrap_err();
    assert!(matches!(error, StoreError::NotAStore { .. }), "{error}");
    assert_eq!(bytes(&other), before);
}

#[test]
fn a_damaged_store_is_an_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("site.mapmerge");
    {
        let mut store = Store::open(&path).unwrap();
        for k in 0..50 {
            store
                .commit_version(&counts(&format!("session {k}"), k))
                .unwrap();
        }
    }
    // Overwrite the middle of the file (the tables' pages) with garbage.
    let mut data = bytes(&path);
    assert!(data.len() > 4096, "{}", data.len());
    for b in data.iter_mut().skip(4096 + 100).take(2000) {
        *b = 0xA5;
    }
    std::fs::write(&path, &data).unwrap();
    let opened = Store::open_existing(&path);
    match opened {
        Err(e) => assert!(
            matches!(e, StoreError::Corrupt { .. } | StoreError::NotAStore { .. }),
            "{e}"
        ),
        Ok(store) => assert!(store.check().is_err() || store.versions().is_err()),
    }
}

fn rusqlite_connection(path: &std::path::Path) -> rusqlite::Connection {
    rusqlite::Connection::open(path).unwrap()
}
