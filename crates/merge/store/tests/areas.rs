//! The map manager's areas in the store: committed, loaded, kept beside the atlas, rolled
//! back and forgotten like the atlas's rows; refused when they do not fit their sessions.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;

use mapmerge_areas::{manage_mapped, segment, ManagedMap, ManagerParams, MappedSession};
use mapmerge_atlas::{Atlas, AtlasParams};
use mapmerge_place::PlaceVerifierParams;
use mapmerge_posegraph::PoseGraph2;
use mapmerge_sim::{simulate_session_alone, SimParams};
use mapmerge_store::{AreasCommit, SessionCommit, Store, StoreError};

/// Session `index` of a simulated office, split at its doors, each span "mapped" by its
/// odometry (the store does not care how).
fn mapped(index: usize) -> MappedSession {
    let mut params = SimParams::default()
        .with_preset_name("office")
        .unwrap()
        .with_duration_secs(60.0);
    params.kidnap.max_per_session = 0;
    let log = simulate_session_alone(&params, 1, index).unwrap().log;
    let poses: Vec<_> = log
        .scans
        .iter()
        .map(|r| r.odom_from_robot.unwrap())
        .collect();
    let segmentation = segment(
        poses.iter().copied().zip(log.scans.iter().map(|r| &r.scan)),
        &ManagerParams::default(),
    )
    .unwrap();
    let trajectories: Vec<_> = segmentation
        .spans
        .iter()
        .map(|span| poses[span.scans.clone()].to_vec())
        .collect();
    MappedSession {
        name: format!("office session {index}"),
        log,
        graphs: vec![PoseGraph2::new(); trajectories.len()],
        segmentation,
        trajectories,
    }
}

fn managed(sessions: &[MappedSession]) -> ManagedMap {
    let verifier = PlaceVerifierParams::default().verifier().unwrap();
    manage_mapped(sessions, &ManagerParams::default(), &verifier).unwrap()
}

fn commit(store: &mut Store, sessions: &[MappedSession], map: &ManagedMap) -> i64 {
    store
        .commit_areas(&AreasCommit {
            session: &sessions.last().unwrap().name,
            sessions,
            map,
        })
        .unwrap()
}

#[test]
fn areas_are_versioned_beside_the_atlas_and_rolled_back_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let mut store = Store::open(&dir.path().join("site.mapmerge")).unwrap();
    assert_eq!(store.load_areas(None).unwrap(), None);
    let first = vec![mapped(0)];
    assert!(
        first[0].segmentation.spans.len() >= 2,
        "a session with a door"
    );
    let first_map = managed(&first);
    assert_eq!(commit(&mut store, &first, &first_map), 1);
    let loaded = store.load_areas(None).unwrap().unwrap();
    assert_eq!(
        (loaded.version, &loaded.sessions, &loaded.map),
        (1, &first, &first_map)
    );
    // No atlas yet: the version holds none.
    assert!(matches!(
        store.load(None),
        Err(StoreError::NoAtlas { version: 1, .. })
    ));

    // An atlas session keeps the areas; areas keep the atlas.
    let atlas = Atlas::new(AtlasParams::default())
        .unwrap()
        .snapshot()
        .unwrap();
    let version = store
        .commit_session(&SessionCommit {
            session: "atlas",
            atlas: &atlas,
            events: &[],
            reference_poses: &BTreeMap::new(),
        })
        .unwrap();
    assert_eq!(version, 2);
    assert_eq!(store.load_areas(None).unwrap().unwrap().sessions, first);
    let both = vec![first[0].clone(), mapped(1)];
    let both_map = managed(&both);
    assert_eq!(commit(&mut store, &both, &both_map), 3);
    assert_eq!(store.load(None).unwrap().unwrap().atlas, atlas);
    let info = store.versions().unwrap();
    assert_eq!(info[2].areas, both_map.hybrid.areas.len() as i64);
    assert_eq!(info[1].areas, first_map.hybrid.areas.len() as i64);
    store.check().unwrap();

    // Each version loads what it held.
    let at_2 = store.load_areas(Some(2)).unwrap().unwrap();
    assert_eq!(
        (at_2.sessions, at_2.map),
        (first.clone(), first_map.clone())
    );
    let at_3 = store.load_areas(Some(3)).unwrap().unwrap();
    assert_eq!((at_3.sessions, at_3.map), (both.clone(), both_map.clone()));

    // Undo restores what was there.
    assert_eq!(store.rollback_to(2).unwrap(), 1);
    let back = store.load_areas(None).unwrap().unwrap();
    assert_eq!(
        (back.version, back.sessions, back.map),
        (2, first.clone(), first_map)
    );
    store.check().unwrap();

    // Forgotten versions lose their areas with their atlas; the newest keeps both.
    store.keep_versions(std::num::NonZeroUsize::new(1).unwrap());
    commit(&mut store, &both, &both_map);
    assert!(matches!(
        store.load_areas(Some(2)),
        Err(StoreError::NotRetained { version: 2, .. })
    ));
    assert_eq!(store.load_areas(None).unwrap().unwrap().sessions, both);
    assert_eq!(store.load(None).unwrap().unwrap().atlas, atlas);
    store.check().unwrap();
}

#[test]
fn areas_that_do_not_fit_their_sessions_are_refused_before_anything_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let mut store = Store::open(&dir.path().join("site.mapmerge")).unwrap();
    let sessions = vec![mapped(0)];
    let map = managed(&sessions);
    let mut no_placement = map.clone();
    no_placement.session_placed.clear();
    let mut lost_area = map.clone();
    lost_area.hybrid.areas.truncate(1);
    let mut short_trajectory = sessions.clone();
    short_trajectory[0].trajectories[0].pop();
    for (sessions, map) in [
        (&sessions, &no_placement),
        (&sessions, &lost_area),
        (&short_trajectory, &map),
    ] {
        let refused = store.commit_areas(&AreasCommit {
            session: "bad",
            sessions,
            map,
        });
        assert!(
            matches!(refused, Err(StoreError::BadAreas { .. })),
            "{refused:?}"
        );
    }
    assert!(store.versions().unwrap().is_empty());
}

#[test]
fn a_damaged_area_row_is_reported_as_corruption() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("site.mapmerge");
    {
        let mut store = Store::open(&path).unwrap();
        let sessions = vec![mapped(0)];
        commit(&mut store, &sessions, &managed(&sessions));
    }
    {
        let raw = rusqlite::Connection::open(&path).unwrap();
        let mut body: Vec<u8> = raw
            .query_row("SELECT body FROM area_sessions", [], |row| row.get(0))
            .unwrap();
        body[100] ^= 0xff;
        raw.execute("UPDATE area_sessions SET body = ?1", [body])
            .unwrap();
    }
    // Refused for writing (issue 67: the check runs before any write); read, it says why.
    assert!(matches!(
        Store::open(&path),
        Err(StoreError::Corrupt { .. })
    ));
    let store = Store::open_read_only(&path).unwrap();
    assert!(matches!(
        store.load_areas(None),
        Err(StoreError::Corrupt { .. })
    ));
    assert!(matches!(store.check(), Err(StoreError::Corrupt { .. })));
}
