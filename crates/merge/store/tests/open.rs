//! Opening stores: created, reopened, upgraded; refused without being modified.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;
use std::sync::Arc;

use mapmerge_atlas::{Atlas, AtlasParams, AtlasSnapshot, EpochEndReason};
use mapmerge_geometry::Se2;
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, Vertex};
use mapmerge_store::{SessionCommit, Store, StoreError, SCHEMA_VERSION};
use nalgebra::{Matrix3, Vector2};

/// An atlas that lives through sessions: each adds an epoch of `nodes` vertices along x
/// (with a few points each) and ends it, and prunes the oldest vertices beyond `keep_nodes`.
struct Robot {
    atlas: Atlas,
    sessions: usize,
}

impl Robot {
    fn new() -> Self {
        Self {
            atlas: Atlas::new(AtlasParams::default()).unwrap(),
            sessions: 0,
        }
    }

    /// One session; returns its snapshot and the reference pose of each new keyframe.
    fn session(
        &mut self,
        nodes: usize,
        keep_nodes: usize,
    ) -> (AtlasSnapshot, BTreeMap<NodeId, Se2>) {
        if self.sessions > 0 {
            self.atlas.end_epoch(EpochEndReason::Restart);
        }
        self.sessions += 1;
        let mut reference = BTreeMap::new();
        let mut previous = None;
        for k in 0..nodes {
            let pose = Se2::new(k as f64, 0.1 * self.sessions as f64, 0.0);
            let points: Arc<[Vector2<f64>]> = (0..5)
                .map(|j| Vector2::new(1.0 + j as f64 * 0.3, -1.0 + 0.5 * j as f64))
                .collect();
            let node = self.atlas.add_vertex(Vertex::new(pose), points);
            reference.insert(node, Se2::new(k as f64, 0.0, 0.01 * k as f64));
            if let Some(previous) = previous {
                self.atlas
                    .add_edge(Edge {
                        from: previous,
                        to: node,
                        measurement: Se2::new(1.0, 0.0, 0.0),
                        information: Matrix3::identity() * 50.0,
                        kind: EdgeKind::Odometry,
                    })
                    .unwrap();
            }
            previous = Some(node);
        }
        // Bounded: the oldest inactive vertices go.
        let mut inactive: Vec<NodeId> = self
            .atlas
            .inactive_maps()
            .flat_map(|(_, g)| g.vertices().map(|(n, _)| n).collect::<Vec<_>>())
            .collect();
        inactive.sort();
        let total = inactive.len() + self.atlas.active().num_vertices();
        for node in inactive.iter().take(total.saturating_sub(keep_nodes)) {
            self.atlas.prune_vertex(*node).unwrap();
        }
        (self.atlas.snapshot().unwrap(), reference)
    }
}

fn commit(
    store: &mut Store,
    name: &str,
    atlas: &AtlasSnapshot,
    reference: &BTreeMap<NodeId, Se2>,
) -> i64 {
    let events = vec![format!("{{\"session\":\"{name}\"}}")];
    store
        .commit_session(&SessionCommit {
            session: name,
            atlas,
            events: &events,
            reference_poses: reference,
        })
        .unwrap()
}

#[test]
fn a_new_store_keeps_its_versions_across_reopening_and_rolls_back() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("site.mapmerge");
    let mut robot = Robot::new();
    let (monday, monday_reference) = robot.session(6, 100);
    let (tuesday, tuesday_reference) = robot.session(4, 100);
    {
        let mut store = Store::open(&path).unwrap();
        assert_eq!(store.versions().unwrap(), vec![]);
        assert_eq!(store.load(None).unwrap(), None);
        assert_eq!(commit(&mut store, "monday", &monday, &monday_reference), 1);
        assert_eq!(
            commit(&mut store, "tuesday", &tuesday, &tuesday_reference),
            2
        );
        store.check().unwrap();
    }
    let mut store = Store::open_existing(&path).unwrap();
    let versions = store.versions().unwrap();
    assert_eq!(versions.len(), 2);
    assert_eq!(versions[1].parent, Some(1));
    assert_eq!(versions[1].session, "tuesday");
    assert_eq!(versions[1].nodes, 10);
    assert_eq!(versions[1].edges, 8);
    assert_eq!(versions[1].keyframes, 10);
    assert!(versions[1].mapped_area_m2 > versions[0].mapped_area_m2);
    // Each version's atlas comes back exactly, with the reference poses of its keyframes.
    let newest = store.load(None).unwrap().unwrap();
    assert_eq!(newest.version, 2);
    assert_eq!(newest.atlas, tuesday);
    let mut both = monday_reference.clone();
    both.extend(tuesday_reference);
    assert_eq!(newest.reference_poses, both);
    assert_eq!(store.load(Some(1)).unwrap().unwrap().atlas, monday);
    assert_eq!(store.events(None).unwrap().len(), 2);
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
    assert_eq!(store.load(None).unwrap().unwrap().atlas, monday);
    assert_eq!(store.events(None).unwrap().len(), 1);
    store.check().unwrap();
    // The robot continues from Monday's map.
    let mut robot = Robot {
        atlas: Atlas::restore(AtlasParams::default(), Default::default(), monday).unwrap(),
        sessions: 1,
    };
    let (wednesday, reference) = robot.session(3, 100);
    assert_eq!(commit(&mut store, "wednesday", &wednesday, &reference), 2);
    assert_eq!(store.load(None).unwrap().unwrap().atlas, wednesday);
    store.check().unwrap();
}

#[test]
fn old_versions_forget_their_atlas_and_the_store_stays_bounded() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("site.mapmerge");
    let mut store = Store::open(&path).unwrap();
    store.keep_versions(std::num::NonZeroUsize::new(3).unwrap());
    let mut robot = Robot::new();
    let mut snapshots = Vec::new();
    let mut sizes = Vec::new();
    for k in 0..30 {
        let (atlas, reference) = robot.session(8, 20);
        commit(&mut store, &format!("session {k}"), &atlas, &reference);
        snapshots.push(atlas);
        sizes.push(store.info().unwrap().bytes);
    }
    let versions = store.versions().unwrap();
    assert_eq!(versions.len(), 30);
    assert_eq!(versions.iter().filter(|v| v.retained).count(), 3);
    assert!(matches!(
        store.load(Some(5)),
        Err(StoreError::NotRetained { version: 5, .. })
    ));
    assert!(matches!(
        store.rollback_to(5),
        Err(StoreError::NotRetained { version: 5, .. })
    ));
    for version in 28..=30 {
        let stored = store.load(Some(version)).unwrap().unwrap();
        assert_eq!(stored.atlas, snapshots[version as usize - 1]);
    }
    assert_eq!(store.events(None).unwrap().len(), 3);
    store.check().unwrap();
    // The map is bounded (20 vertices), so is the file: the last ten sessions add nothing.
    assert_eq!(sizes[29], sizes[19], "{sizes:?}");
}

/// Issue 66: a store whose map shrinks (a large atlas, then small ones, each keeping one
/// version) gives the freed pages back: the file ends near the size of a store that only
/// ever held the small atlas, and every version it keeps still loads.
#[test]
fn pages_freed_by_forgotten_versions_are_reclaimed() {
    let dir = tempfile::tempdir().unwrap();
    let size_after = |sessions: &[(usize, usize)], name: &str| {
        let path = dir.path().join(name);
        let mut store = Store::open(&path).unwrap();
        store.keep_versions(std::num::NonZeroUsize::new(1).unwrap());
        let mut robot = Robot::new();
        let mut last = None;
        for (k, (nodes, keep)) in sessions.iter().enumerate() {
            let (atlas, reference) = robot.session(*nodes, *keep);
            commit(&mut store, &format!("session {k}"), &atlas, &reference);
            last = Some(atlas);
        }
        store.check().unwrap();
        let stored = store.load(None).unwrap().unwrap();
        assert_eq!(Some(stored.atlas), last);
        let recorded = store.versions().unwrap().last().unwrap().bytes;
        (store.info().unwrap().bytes, recorded)
    };
    let (shrunk, recorded) = size_after(&[(3000, 3000), (10, 10), (10, 10)], "shrunk.mapmerge");
    let (small, _) = size_after(&[(10, 10), (10, 10)], "small.mapmerge");
    assert!(shrunk < 2 * small, "{shrunk} bytes against {small}");
    assert_eq!(recorded, shrunk as i64);
}

#[test]
fn an_inconsistent_atlas_is_refused_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("site.mapmerge");
    let mut store = Store::open(&path).unwrap();
    let (mut atlas, reference) = Robot::new().session(3, 10);
    atlas.counters.next_node = 1; // below ids in use
    let error = store
        .commit_session(&SessionCommit {
            session: "bad",
            atlas: &atlas,
            events: &[],
            reference_poses: &reference,
        })
        .unwrap_err();
    assert!(matches!(error, StoreError::BadAtlas { .. }), "{error}");
    assert!(store.versions().unwrap().is_empty());
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

/// A store of 20 sessions, its file's bytes.
fn stored_sessions(path: &std::path::Path) -> Vec<u8> {
    {
        let mut store = Store::open(path).unwrap();
        let mut robot = Robot::new();
        for k in 0..20 {
            let (atlas, reference) = robot.session(10, 1000);
            commit(&mut store, &format!("session {k}"), &atlas, &reference);
        }
    }
    bytes(path)
}

/// Opening and checking a damaged store fails with an error, never a panic.
fn refused_as_damaged(path: &std::path::Path) {
    match Store::open_existing(path) {
        Err(e) => assert!(
            matches!(e, StoreError::Corrupt { .. } | StoreError::NotAStore { .. }),
            "{e}"
        ),
        Ok(store) => {
            let error = store.check().unwrap_err();
            assert!(matches!(error, StoreError::Corrupt { .. }), "{error}");
        }
    }
}

#[test]
fn a_damaged_store_is_an_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("site.mapmerge");
    let mut data = stored_sessions(&path);
    // Garbage over every page but the header's.
    assert!(data.len() > 3 * 4096, "{}", data.len());
    let end = data.len() - 100;
    for b in data.iter_mut().take(end).skip(4096 + 100) {
        *b = 0xA5;
    }
    std::fs::write(&path, &data).unwrap();
    refused_as_damaged(&path);
}

#[test]
fn one_flipped_bit_in_a_keyframe_is_found_by_the_check() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("site.mapmerge");
    let mut data = stored_sessions(&path);
    // Every stored x = 1.6 (1.0 + 2 × 0.3, a keyframe point) as little-endian f64, live or
    // in a freed page, gets its lowest bit flipped.
    let needle = 1.6f64.to_le_bytes();
    let at: Vec<usize> = data
        .windows(needle.len())
        .enumerate()
        .filter(|(_, w)| *w == needle)
        .map(|(i, _)| i)
        .collect();
    assert!(!at.is_empty());
    for i in at {
        data[i] ^= 1;
    }
    std::fs::write(&path, &data).unwrap();
    refused_as_damaged(&path);
}

fn rusqlite_connection(path: &std::path::Path) -> rusqlite::Connection {
    rusqlite::Connection::open(path).unwrap()
}

/// Issue 67: an empty file is no store to read or to add to; only `open` makes one of it.
#[test]
fn an_empty_file_is_a_store_only_when_created() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("empty.mapmerge");
    std::fs::write(&path, b"").unwrap();
    for opened in [Store::open_read_only(&path), Store::open_existing(&path)] {
        let error = opened.unwrap_err();
        assert!(matches!(error, StoreError::NotAStore { .. }), "{error}");
        assert!(error.to_string().contains("empty"), "{error}");
    }
    assert_eq!(std::fs::metadata(&path).unwrap().len(), 0);
    Store::open(&path).unwrap().check().unwrap();
}

/// Issue 67: a store missing a table fails its check by name, and no command may write to
/// it; a read-only store reads but takes no write, and is left as it was.
#[test]
fn a_store_is_checked_before_a_write_and_read_only_takes_none() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("site.mapmerge");
    let mut robot = Robot::new();
    {
        let mut store = Store::open(&path).unwrap();
        let (atlas, reference) = robot.session(5, 100);
        commit(&mut store, "session 0", &atlas, &reference);
    }
    let before = std::fs::read(&path).unwrap();
    {
        let mut store = Store::open_read_only(&path).unwrap();
        assert_eq!(store.versions().unwrap().len(), 1);
        store.check().unwrap();
        let (atlas, reference) = robot.session(5, 100);
        let refused = store.commit_session(&SessionCommit {
            session: "session 1",
            atlas: &atlas,
            events: &[],
            reference_poses: &reference,
        });
        assert!(refused.is_err(), "a read-only store took a commit");
        assert!(store.rollback_to(0).is_err());
    }
    assert_eq!(std::fs::read(&path).unwrap(), before);
    rusqlite::Connection::open(&path)
        .unwrap()
        .execute_batch("DROP TABLE events")
        .unwrap();
    let dropped = std::fs::read(&path).unwrap();
    let store = Store::open_read_only(&path).unwrap();
    let error = store.check().unwrap_err();
    assert!(
        error.to_string().contains("table events is missing"),
        "{error}"
    );
    drop(store);
    for opened in [Store::open(&path), Store::open_existing(&path)] {
        let error = opened.unwrap_err();
        assert!(matches!(error, StoreError::Corrupt { .. }), "{error}");
    }
    assert_eq!(std::fs::read(&path).unwrap(), dropped);
}
