//! Merge/undo invariants on random graphs (Holoch et al., Sec. III): undo restores the inactive
//! graphs bit for bit and keeps every current-epoch vertex; merges keep the robot's pose; ids
//! stay unique; pruning refuses other-epoch data while a merge is undoable; the event log
//! round-trips.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use mapmerge_atlas::{
    read_events, Atlas, AtlasError, AtlasParams, BackupStore, DiskBackups, EpochEndReason, EpochId,
    EventLogWriter, LoopEdge, MapId, MergeReason, MergeRequest, UnmergeReason,
};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph2, Vertex};
use mapmerge_scan::Point2;
use nalgebra::Matrix3;
use proptest::prelude::*;

/// One random step of a trajectory.
fn step() -> impl Strategy<Value = (f64, f64, f64)> {
    (0.1f64..1.5, -0.3f64..0.3, -0.8f64..0.8)
}

fn pose() -> impl Strategy<Value = Se2> {
    (-20f64..20.0, -20f64..20.0, -3.1f64..3.1).prop_map(|(x, y, t)| Se2::new(x, y, t))
}

/// A noisy odometry chain with a loop edge now and then, added to the current epoch.
fn add_path(
    atlas: &mut Atlas<impl BackupStore>,
    steps: &[(f64, f64, f64)],
    start: Se2,
) -> Vec<NodeId> {
    let mut nodes = Vec::new();
    let mut pose = start;
    for (i, (dx, dy, dt)) in steps.iter().enumerate() {
        let z = Se2::new(*dx, *dy, *dt);
        let noisy = Se2::new(dx + 0.01 * (i as f64).sin(), *dy, dt - 0.005);
        pose = pose.compose(&noisy);
        let points: Arc<[Point2]> = Arc::from(vec![Point2::new(i as f64, 1.0); 3]);
        let mut vertex = Vertex::new(pose);
        vertex.meta.stamp_secs = Some(i as f64 * 0.5);
        let id = atlas.add_vertex(vertex, points);
        if let Some(prev) = nodes.last() {
            atlas
                .add_edge(Edge {
                    from: *prev,
                    to: id,
                    measurement: z,
                    information: Matrix3::identity() * 100.0,
                    kind: EdgeKind::Odometry,
                })
                .unwrap();
        }
        if i >= 5 && i % 4 == 0 {
            let back = nodes[i - 5];
            let m = atlas.active().vertex(back).unwrap().pose.between(&pose);
            atlas
                .add_edge(Edge {
                    from: back,
                    to: id,
                    measurement: m,
                    information: Matrix3::identity() * 10.0,
                    kind: EdgeKind::Loop,
                })
                .unwrap();
        }
        nodes.push(id);
    }
    nodes
}

fn bits(graph: &PoseGraph2) -> Vec<u8> {
    postcard::to_stdvec(graph).unwrap()
}

fn all_ids_unique(atlas: &Atlas<impl BackupStore>) -> bool {
    let mut seen = BTreeSet::new();
    let active = atlas.active().vertices().map(|(id, _)| id);
    let inactive = atlas
        .inactive_maps()
        .flat_map(|(_, g)| g.vertices().map(|(id, _)| id).collect::<Vec<_>>());
    active.chain(inactive).all(|id| seen.insert(id))
}

fn robot_pose(atlas: &Atlas<impl BackupStore>) -> Se2 {
    atlas
        .active()
        .vertex(atlas.robot_node().unwrap())
        .unwrap()
        .pose
}

/// A merge's transform, or a loop edge (active index, inactive index, measurement).
type MergeSpec = (Se2, Option<(usize, usize, Se2)>);

#[derive(Clone, Debug)]
struct Scenario {
    /// Paths of the older epochs, each becoming an inactive map.
    old: Vec<Vec<(f64, f64, f64)>>,
    /// Merge epoch 1 into ... before ending it (an inactive map of two epochs).
    pre_merge: bool,
    /// The current epoch's path before the merges.
    current: Vec<(f64, f64, f64)>,
    /// Per merge: the transform, or a loop edge (active index, inactive index, measurement).
    merges: Vec<MergeSpec>,
    /// Vertices added after the merges, with a loop edge into merged data now and then.
    after: Vec<(f64, f64, f64)>,
}

fn scenario() -> impl Strategy<Value = Scenario> {
    (
        prop::collection::vec(prop::collection::vec(step(), 2..12), 2..5),
        any::<bool>(),
        prop::collection::vec(step(), 1..10),
        prop::collection::vec(
            (pose(), prop::option::of((0usize..100, 0usize..100, pose()))),
            1..4,
        ),
        prop::collection::vec(step(), 0..8),
    )
        .prop_map(|(old, pre_merge, current, merges, after)| Scenario {
            old,
            pre_merge,
            current,
            merges,
            after,
        })
}

/// Runs a scenario and checks every invariant; returns the atlas for further checks. With
/// `restore_into`, the atlas is snapshotted just before the undo and continues as the atlas
/// restored from that snapshot into those backups (the undo must not notice).
fn run<B: BackupStore>(s: &Scenario, backups: B, restore_into: Option<B>) -> Atlas<B> {
    let mut atlas = Atlas::with_backups(AtlasParams::default(), backups).unwrap();
    for (i, path) in s.old.iter().enumerate() {
        add_path(&mut atlas, path, Se2::new(i as f64, 0.0, 0.0));
        if i == 1 && s.pre_merge {
            // A merge that becomes final when the epoch ends: map 0 holds two epochs then.
            atlas
                .merge(
                    MergeRequest::forced(MapId(0), Se2::new(0.5, 0.5, 0.1), "pre"),
                    None,
                )
                .unwrap();
        }
        let events = atlas.end_epoch(EpochEndReason::Kidnap);
        assert_eq!(events.len(), 2);
    }
    assert!(
        atlas.backups().stored().is_empty(),
        "final merges keep no backup"
    );
    let current = atlas.current_epoch();
    add_path(&mut atlas, &s.current, Se2::identity());
    let maps_before: BTreeMap<MapId, Vec<u8>> =
        atlas.inactive_maps().map(|(id, g)| (id, bits(g))).collect();
    let graphs_before: BTreeMap<MapId, PoseGraph2> = atlas
        .inactive_maps()
        .map(|(id, g)| (id, g.clone()))
        .collect();

    // Several merges in a row, each keeping the robot where it was.
    let mut merged_maps = Vec::new();
    for (k, (transform, edge)) in s.merges.iter().enumerate() {
        let Some((map, graph)) = atlas.inactive_maps().next().map(|(m, g)| (m, g.clone())) else {
            break;
        };
        let robot = robot_pose(&atlas);
        let request = match edge {
            None => MergeRequest::forced(map, *transform, format!("merge {k}")),
            Some((ia, ib, z)) => {
                let actives: Vec<NodeId> = atlas.active().vertices().map(|(id, _)| id).collect();
                let inactives: Vec<NodeId> = graph.vertices().map(|(id, _)| id).collect();
                MergeRequest {
                    map,
                    active_from_inactive: None,
                    loops: vec![LoopEdge {
                        active: actives[ia % actives.len()],
                        inactive: inactives[ib % inactives.len()],
                        inactive_from_active: *z,
                        information: Matrix3::identity() * 50.0,
                    }],
                    reason: MergeReason::Forced {
                        note: "loop".into(),
                    },
                }
            }
        };
        let event = atlas.merge(request, None).unwrap();
        assert_eq!(event.map, map);
        assert_eq!(event.loop_edges, 1);
        assert_eq!(event.active_epoch, current);
        let after = robot_pose(&atlas);
        assert_eq!(
            (
                after.x_m.to_bits(),
                after.y_m.to_bits(),
                after.theta_rad.to_bits()
            ),
            (
                robot.x_m.to_bits(),
                robot.y_m.to_bits(),
                robot.theta_rad.to_bits()
            ),
            "the robot must not jump"
        );
        assert!(atlas.inactive(map).is_none());
        assert!(all_ids_unique(&atlas));
        merged_maps.push(map);
    }
    assert!(atlas.is_undoable());
    assert_eq!(atlas.backups().stored().len(), merged_maps.len());

    // The robot goes on; some new vertices close loops into merged data.
    let merged_nodes: Vec<NodeId> = atlas
        .active()
        .vertices()
        .filter(|(_, v)| EpochId::of(&v.meta) != current)
        .map(|(id, _)| id)
        .collect();
    let mut pose = robot_pose(&atlas);
    let mut previous = atlas.robot_node().unwrap();
    for (i, (dx, dy, dt)) in s.after.iter().enumerate() {
        let z = Se2::new(*dx, *dy, *dt);
        pose = pose.compose(&z);
        let id = atlas.add_vertex(Vertex::new(pose), Arc::from(Vec::new()));
        atlas
            .add_edge(Edge {
                from: previous,
                to: id,
                measurement: z,
                information: Matrix3::identity() * 100.0,
                kind: EdgeKind::Odometry,
            })
            .unwrap();
        if i % 3 == 1 {
            let other = merged_nodes[i % merged_nodes.len()];
            let m = atlas.active().vertex(other).unwrap().pose.between(&pose);
            atlas
                .add_edge(Edge {
                    from: other,
                    to: id,
                    measurement: m,
                    information: Matrix3::identity(),
                    kind: EdgeKind::Loop,
                })
                .unwrap();
        }
        previous = id;
    }

    // Pruning refuses other-epoch data while the merges can be undone (Sec. III-B).
    for node in &merged_nodes {
        assert!(!atlas.can_prune(*node));
    }
    let refused = atlas.prune_vertex(merged_nodes[0]);
    assert!(
        matches!(refused, Err(AtlasError::PruneRefused { node, .. }) if node == merged_nodes[0])
    );
    assert!(atlas.can_prune(atlas.robot_node().unwrap()));

    if let Some(fresh) = restore_into {
        let snapshot = atlas.snapshot().unwrap();
        let restored = Atlas::restore(AtlasParams::default(), fresh, snapshot.clone()).unwrap();
        assert_eq!(restored.snapshot().unwrap(), snapshot);
        assert_eq!(restored.backups().stored(), atlas.backups().stored());
        atlas = restored;
    }

    // The current epoch as it is before the undo.
    let current_vertices: BTreeSet<NodeId> = atlas
        .active()
        .vertices()
        .filter(|(_, v)| EpochId::of(&v.meta) == current)
        .map(|(id, _)| id)
        .collect();
    let current_edges: BTreeSet<_> = atlas
        .active()
        .edges()
        .filter(|(_, e)| current_vertices.contains(&e.from) && current_vertices.contains(&e.to))
        .map(|(id, _)| id)
        .collect();
    let robot = robot_pose(&atlas);

    let event = atlas
        .unmerge_all(UnmergeReason::InvalidMerge {
            detector: "test".into(),
            invalidity: 0.9,
        })
        .unwrap()
        .unwrap();
    assert_eq!(event.restored_maps, merged_maps);
    assert_eq!(event.removed_vertices, merged_nodes.len());

    // Every inactive graph back bit for bit, under its id.
    let maps_after: BTreeMap<MapId, Vec<u8>> =
        atlas.inactive_maps().map(|(id, g)| (id, bits(g))).collect();
    assert_eq!(maps_after, maps_before);
    for (id, g) in atlas.inactive_maps() {
        assert_eq!(Some(g), graphs_before.get(&id));
    }
    // Every current-epoch vertex and the edges among them stay; nothing else does.
    let kept: BTreeSet<NodeId> = atlas.active().vertices().map(|(id, _)| id).collect();
    assert_eq!(kept, current_vertices);
    let kept_edges: BTreeSet<_> = atlas.active().edges().map(|(id, _)| id).collect();
    assert_eq!(kept_edges, current_edges);
    assert_eq!(robot_pose(&atlas), robot);
    assert!(!atlas.is_undoable());
    assert!(atlas.backups().stored().is_empty());
    assert!(all_ids_unique(&atlas));
    // Every vertex still has its scan.
    for (_, g) in atlas.inactive_maps() {
        for (id, _) in g.vertices() {
            assert!(atlas.keyframes().get(id).is_some());
        }
    }
    // Nothing left to undo; pruning other epochs' data is allowed again.
    assert!(atlas
        .unmerge_all(UnmergeReason::Requested {
            note: "again".into()
        })
        .unwrap()
        .is_none());
    atlas
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn undo_restores_inactive_graphs_exactly_and_keeps_the_current_epoch(s in scenario()) {
        let atlas = run(&s, mapmerge_atlas::MemoryBackups::default(), None);

        // The event log round-trips through JSON lines.
        let mut writer = EventLogWriter::new(Vec::new());
        for event in atlas.events() {
            writer.write(event).unwrap();
        }
        let bytes = writer.into_inner();
        let back = read_events(bytes.as_slice()).unwrap();
        prop_assert_eq!(back.as_slice(), atlas.events());
    }

    #[test]
    fn an_atlas_restored_from_its_snapshot_undoes_merges_exactly(s in scenario()) {
        let fresh = mapmerge_atlas::MemoryBackups::default();
        run(&s, mapmerge_atlas::MemoryBackups::default(), Some(fresh));
    }
}

#[test]
fn inconsistent_snapshots_are_refused() {
    let mut atlas = Atlas::new(AtlasParams::default()).unwrap();
    add_path(&mut atlas, &[(1.0, 0.0, 0.0); 4], Se2::identity());
    let good = atlas.snapshot().unwrap();
    let restore = |snapshot| {
        Atlas::restore(
            AtlasParams::default(),
            mapmerge_atlas::MemoryBackups::default(),
            snapshot,
        )
    };
    assert!(restore(good.clone()).is_ok());
    let mut bad_local_map = good.clone();
    bad_local_map.local_maps.insert(
        NodeId(0),
        mapmerge_atlas::LocalMapGrid {
            resolution_m: 0.05,
            origin_m: [0.0, 0.0],
            width: 3,
            height: 2,
            cells: vec![1; 5],
            keyframes: 1,
        },
    );
    let mut stale_counter = good.clone();
    stale_counter.counters.next_node = 2;
    let mut lost_robot = good.clone();
    lost_robot.counters.robot = Some(NodeId(99));
    let mut no_backup = good;
    no_backup
        .counters
        .merges
        .push(mapmerge_atlas::AppliedMerge {
            merge: mapmerge_atlas::MergeId(0),
            map: MapId(0),
            active_from_inactive: [0.0; 3],
        });
    no_backup.counters.next_merge = 1;
    for bad in [bad_local_map, stale_counter, lost_robot, no_backup] {
        assert!(matches!(restore(bad), Err(AtlasError::BadSnapshot(_))));
    }
}

#[test]
fn disk_backups_restore_exactly_too() {
    let dir = std::env::temp_dir().join(format!("mapmerge-atlas-disk-{}", std::process::id()));
    let scenario = Scenario {
        old: vec![
            vec![(1.0, 0.0, 0.1); 6],
            vec![(0.5, 0.1, -0.2); 9],
            vec![(0.7, 0.0, 0.3); 4],
        ],
        pre_merge: true,
        current: vec![(0.3, 0.0, 0.0); 5],
        merges: vec![
            (Se2::new(1.0, 2.0, 0.3), None),
            (Se2::identity(), Some((3, 2, Se2::new(0.2, 0.0, 0.1)))),
        ],
        after: vec![(0.4, 0.0, 0.05); 7],
    };
    let atlas = run(&scenario, DiskBackups::new(&dir).unwrap(), None);
    assert!(atlas.backups().stored().is_empty());
    // Restored from a snapshot into another folder, mid-merge.
    let restored_dir = dir.join("restored");
    let atlas = run(
        &scenario,
        DiskBackups::new(dir.join("first")).unwrap(),
        Some(DiskBackups::new(&restored_dir).unwrap()),
    );
    assert!(atlas.backups().stored().is_empty());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn pruning_is_free_again_after_the_epoch_ends() {
    let mut atlas = Atlas::new(AtlasParams::default()).unwrap();
    let old = add_path(&mut atlas, &[(1.0, 0.0, 0.0); 4], Se2::identity());
    atlas.end_epoch(EpochEndReason::Restart);
    add_path(&mut atlas, &[(1.0, 0.0, 0.0); 3], Se2::identity());
    atlas
        .merge(
            MergeRequest::forced(MapId(0), Se2::new(0.0, 1.0, 0.0), "t"),
            None,
        )
        .unwrap();
    assert!(!atlas.can_prune(old[1]));
    let ended = atlas.end_epoch(EpochEndReason::TrackingLost);
    assert!(matches!(
        &ended[0],
        mapmerge_atlas::AtlasEvent::EpochEnded { finalized_merges, .. } if finalized_merges.len() == 1
    ));
    // The merged graph is inactive now and final: prunable, scan and all.
    assert!(atlas.can_prune(old[1]));
    atlas.prune_vertex(old[1]).unwrap();
    assert!(atlas.keyframes().get(old[1]).is_none());
    assert!(!atlas.can_prune(old[1]));
}

#[test]
fn merge_errors_leave_the_atlas_unchanged() {
    let mut atlas = Atlas::new(AtlasParams::default()).unwrap();
    add_path(&mut atlas, &[(1.0, 0.0, 0.0); 4], Se2::identity());
    atlas.end_epoch(EpochEndReason::Kidnap);
    // No vertex in the active graph yet: nowhere to put the robot.
    let err = atlas.merge(MergeRequest::forced(MapId(0), Se2::identity(), "x"), None);
    assert!(matches!(err, Err(AtlasError::EmptyActive(_))));
    let current = add_path(&mut atlas, &[(1.0, 0.0, 0.0); 2], Se2::identity());
    let err = atlas.merge(MergeRequest::forced(MapId(7), Se2::identity(), "x"), None);
    assert!(matches!(err, Err(AtlasError::MissingMap(MapId(7)))));
    // A loop whose ends are swapped is refused.
    let bad = MergeRequest {
        map: MapId(0),
        active_from_inactive: None,
        loops: vec![LoopEdge {
            active: NodeId(0),
            inactive: current[0],
            inactive_from_active: Se2::identity(),
            information: Matrix3::identity(),
        }],
        reason: MergeReason::Forced { note: "x".into() },
    };
    assert!(matches!(
        atlas.merge(bad, None),
        Err(AtlasError::BadMerge { .. })
    ));
    assert_eq!(atlas.inactive_maps().len(), 1);
    assert_eq!(atlas.active().num_vertices(), 2);
    assert!(!atlas.is_undoable());
}
