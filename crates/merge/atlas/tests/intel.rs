//! The atlas on real data: the Intel Research Lab log cut into two sessions (a kidnap between
//! them), each mapped by the project's front-end; the second recognises the first, merges onto
//! the right transform, keeps mapping, and an unmerge restores the first session's graph
//! exactly while keeping every vertex of the second.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use mapmerge_atlas::{
    default_verifier, Atlas, AtlasParams, EpochEndReason, EpochId, MapId, UnmergeReason,
};
use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_posegraph::{Edge, NodeId, PoseGraph2};
use mapmerge_scan::{LaserLog, Point2};
use mapmerge_slam::{FrontEnd, FrontEndParams};

/// A session's graph, each node's points, each node's scan index.
type Session = (
    PoseGraph2,
    BTreeMap<NodeId, Arc<[Point2]>>,
    BTreeMap<NodeId, usize>,
);

/// Runs the front-end over `scans` and returns its graph, each node's points and scan index.
fn session(log: &LaserLog, scans: std::ops::Range<usize>) -> Session {
    let mut front_end = FrontEnd::new(FrontEndParams::default()).unwrap();
    let mut odometry = Se2::identity();
    let mut scan_of = BTreeMap::new();
    for index in scans {
        let record = &log.scans[index];
        odometry = record.odom_from_robot.unwrap_or(odometry);
        if let Some(node) = front_end
            .add_scan(&odometry, &record.scan)
            .unwrap()
            .keyframe
        {
            scan_of.insert(node, index);
        }
    }
    front_end.finish();
    let points = scan_of
        .keys()
        .map(|node| (*node, Arc::from(front_end.keyframe_points(*node).unwrap())))
        .collect();
    (front_end.graph().clone(), points, scan_of)
}

/// How many of its newest keyframes the robot queries, and how often.
const QUERY_EVERY: usize = 15;

#[test]
fn intel_two_sessions_merge_by_recognition_and_unmerge_exactly() {
    let Some(path) = mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz") else {
        return;
    };
    let log = mapmerge_io::read_carmen(&path).unwrap();
    let corrected: Vec<Se2> = log
        .scans
        .iter()
        .map(|s| s.odom_from_robot.unwrap())
        .collect();
    let (first, second) = (0..500, 500..log.scans.len());
    let started = std::time::Instant::now();
    let (graph_a, points_a, scans_a) = session(&log, first.clone());
    let (graph_b, points_b, scans_b) = session(&log, second.clone());
    let front_end_secs = started.elapsed().as_secs_f64();

    let mut params = AtlasParams::default();
    params.recognition.recent_queries = QUERY_EVERY;
    let mut atlas = Atlas::new(params);
    let new_a = atlas
        .import_graph(&graph_a, |n| points_a.get(&n).cloned())
        .unwrap();
    atlas.end_epoch(EpochEndReason::Kidnap);
    let inactive_before = atlas.inactive(MapId(0)).unwrap().clone();

    // The second session, keyframe by keyframe; like a live robot it queries its newest
    // keyframes every few keyframes until it recognises the first session.
    let nodes_b: Vec<NodeId> = graph_b.vertices().map(|(id, _)| id).collect();
    let mut new_b: BTreeMap<NodeId, NodeId> = BTreeMap::new();
    let feed = |atlas: &mut Atlas, new_b: &mut BTreeMap<NodeId, NodeId>, old: NodeId| {
        let id = atlas.add_vertex(*graph_b.vertex(old).unwrap(), points_b[&old].clone());
        new_b.insert(old, id);
        for (_, e) in graph_b.edges().filter(|(_, e)| e.from.max(e.to) == old) {
            atlas
                .add_edge(Edge {
                    from: new_b[&e.from],
                    to: new_b[&e.to],
                    ..*e
                })
                .unwrap();
        }
    };
    let verifier = default_verifier().unwrap();
    let started = std::time::Instant::now();
    let mut merged = None;
    let mut robot_pose = Se2::identity();
    let mut fed = 0;
    while merged.is_none() && fed < nodes_b.len() {
        feed(&mut atlas, &mut new_b, nodes_b[fed]);
        fed += 1;
        if fed % QUERY_EVERY == 0 {
            robot_pose = atlas
                .active()
                .vertex(atlas.robot_node().unwrap())
                .unwrap()
                .pose;
            merged = atlas.merge_by_recognition(&verifier).unwrap();
        }
    }
    let event = merged.expect("the second session recognises the first");
    let merge_secs = started.elapsed().as_secs_f64();
    eprintln!(
        "front-ends {front_end_secs:.1} s, recognition + merge after {fed} keyframes {merge_secs:.1} s: {event:?}"
    );
    let robot = atlas.robot_node().unwrap();
    assert_eq!(atlas.active().vertex(robot).unwrap().pose, robot_pose);

    // The transform is the truth: session frames are the poses of their first scans.
    let truth = corrected[second.start].between(&corrected[first.start]);
    let t = event.active_from_inactive;
    let error = truth.between(&Se2::new(t[0], t[1], t[2]));
    assert!(
        error.translation().norm() < 0.5
            && wrap_angle_rad(error.theta_rad).abs() < 5f64.to_radians(),
        "merge {t:?} vs truth {truth:?}"
    );
    // Every merge edge agrees with the corrected poses.
    let scan_of: BTreeMap<NodeId, usize> = new_a
        .iter()
        .map(|(old, new)| (*new, scans_a[old]))
        .chain(new_b.iter().map(|(old, new)| (*new, scans_b[old])))
        .collect();
    for (_, e) in atlas
        .active()
        .edges()
        .filter(|(_, e)| e.kind == mapmerge_posegraph::EdgeKind::Merge)
    {
        let z = corrected[scan_of[&e.from]].between(&corrected[scan_of[&e.to]]);
        let d = z.between(&e.measurement);
        assert!(
            d.translation().norm() < 0.5 && wrap_angle_rad(d.theta_rad).abs() < 0.1,
            "{e:?}: {d:?}"
        );
    }

    // The robot maps on after the merge: the rest of the second session.
    let current = atlas.current_epoch();
    for old in &nodes_b[fed..] {
        feed(&mut atlas, &mut new_b, *old);
    }
    let current_vertices: BTreeSet<NodeId> = new_b.values().copied().collect();

    // An invalid-merge detector fires: everything merged goes, the second session stays.
    let undo = atlas
        .unmerge_all(UnmergeReason::InvalidMerge {
            detector: "test".into(),
            invalidity: 1.0,
        })
        .unwrap()
        .unwrap();
    assert_eq!(undo.restored_maps, vec![MapId(0)]);
    assert_eq!(atlas.inactive(MapId(0)), Some(&inactive_before));
    let kept: BTreeSet<NodeId> = atlas.active().vertices().map(|(id, _)| id).collect();
    assert_eq!(kept, current_vertices);
    assert!(atlas
        .active()
        .vertices()
        .all(|(_, v)| EpochId::of(&v.meta) == current));
    assert_eq!(atlas.active().num_edges(), graph_b.num_edges());
}
