//! Merging by place recognition in a small ray-cast world: the active epoch recognises the
//! inactive one, the merge lands on the true transform, and an unmerge restores the inactive
//! graph.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::HashMap;
use std::sync::Arc;

use mapmerge_atlas::{
    default_verifier, Atlas, AtlasParams, EpochEndReason, MapId, MergeRequest, UnmergeReason,
};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, Vertex};
use mapmerge_scan::Point2;
use nalgebra::Matrix3;

type Segment = (Point2, Point2);

/// An irregular room with a few obstacles (no symmetry to confuse recognition).
fn world() -> Vec<Segment> {
    let p = Point2::new;
    let polygon = |pts: &[Point2]| -> Vec<Segment> {
        (0..pts.len())
            .map(|i| (pts[i], pts[(i + 1) % pts.len()]))
            .collect()
    };
    let mut walls = polygon(&[
        p(-2.0, -2.0),
        p(14.0, -2.0),
        p(14.0, 3.0),
        p(18.0, 3.0),
        p(18.0, 9.0),
        p(9.0, 9.0),
        p(7.0, 6.5),
        p(3.0, 6.5),
        p(3.0, 10.0),
        p(-2.0, 10.0),
    ]);
    walls.extend(polygon(&[
        p(4.0, 1.0),
        p(5.5, 1.0),
        p(5.5, 2.0),
        p(4.0, 2.0),
    ]));
    walls.extend(polygon(&[p(10.0, 3.0), p(11.0, 4.5), p(9.5, 5.0)]));
    walls.extend(polygon(&[p(0.0, 7.0), p(0.8, 7.0), p(0.8, 8.5)]));
    walls.push((p(15.0, 5.0), p(16.5, 7.5)));
    walls
}

/// A 360° scan from `world_from_robot`, in the robot frame.
fn scan(world: &[Segment], world_from_robot: &Se2) -> Vec<Point2> {
    (0..360)
        .filter_map(|i| {
            let angle = (i as f64).to_radians();
            let d_robot = Point2::new(angle.cos(), angle.sin());
            let d = world_from_robot.rotation_matrix() * d_robot;
            let o = world_from_robot.translation();
            let range = world
                .iter()
                .filter_map(|(a, b)| {
                    let e = b - a;
                    let denom = d.x * e.y - d.y * e.x;
                    if denom.abs() < 1e-12 {
                        return None;
                    }
                    let w = a - o;
                    let t = (w.x * e.y - w.y * e.x) / denom;
                    let u = (w.x * d.y - w.y * d.x) / denom;
                    (t > 0.0 && (0.0..=1.0).contains(&u)).then_some(t)
                })
                .fold(f64::INFINITY, f64::min);
            (range < 15.0).then(|| d_robot * range)
        })
        .collect()
}

/// Adds a trajectory given in world poses to the current epoch, expressed in the epoch's
/// frame `world_from_epoch`.
fn add_epoch(
    atlas: &mut Atlas,
    world: &[Segment],
    path: &[Se2],
    world_from_epoch: &Se2,
) -> Vec<NodeId> {
    let mut nodes: Vec<NodeId> = Vec::new();
    for world_from_robot in path {
        let pose = world_from_epoch.between(world_from_robot);
        let points: Arc<[Point2]> = Arc::from(scan(world, world_from_robot));
        let id = atlas.add_vertex(Vertex::new(pose), points);
        if let Some(prev) = nodes.last() {
            let from = atlas.active().vertex(*prev).unwrap().pose;
            atlas
                .add_edge(Edge {
                    from: *prev,
                    to: id,
                    measurement: from.between(&pose),
                    information: Matrix3::identity() * 100.0,
                    kind: EdgeKind::Odometry,
                })
                .unwrap();
        }
        nodes.push(id);
    }
    nodes
}

/// World poses along a polyline, every 0.5 m, heading along it.
fn along(corners: &[(f64, f64)]) -> Vec<Se2> {
    let mut poses = Vec::new();
    for w in corners.windows(2) {
        let (a, b) = (Point2::new(w[0].0, w[0].1), Point2::new(w[1].0, w[1].1));
        let heading = (b - a).y.atan2((b - a).x);
        let n = ((b - a).norm() / 0.5).ceil() as usize;
        for i in 0..n {
            let p = a + (b - a) * (i as f64 / n as f64);
            poses.push(Se2::new(p.x, p.y, heading));
        }
    }
    poses
}

/// A tour of the room (world frame).
fn room_tour() -> Vec<Se2> {
    along(&[
        (0.0, 0.0),
        (12.0, 0.0),
        (12.0, 4.0),
        (16.0, 5.0),
        (16.0, 8.0),
        (8.0, 8.0),
    ])
}

#[test]
fn recognition_merges_onto_the_true_transform_and_unmerge_restores() {
    merges_onto_the_true_transform(AtlasParams::default());
}

#[test]
fn recognition_with_local_maps_in_the_index_merges_as_well() {
    merges_onto_the_true_transform(AtlasParams {
        index_local_maps: true,
        ..AtlasParams::default()
    });
}

/// The query also described from beside the robot (Scan Context++'s lateral augmentation).
#[test]
fn recognition_with_views_from_beside_merges_as_well() {
    let mut params = AtlasParams::default();
    params.recognition.lateral_offsets_m = vec![-1.0, -0.5, 0.5, 1.0];
    merges_onto_the_true_transform(params);
}

/// Keyframes without their free space: verification scores by the older evidence (inliers,
/// violations), with the thresholds chosen for it.
#[test]
fn recognition_without_free_space_merges_as_well() {
    let mut params = AtlasParams::default();
    params.keyframes.free_space_m = 0.0;
    params.recognition.place.min_score = 0.7;
    params.merge.overlap.min_score = 0.85;
    merges_onto_the_true_transform(params);
}

#[test]
fn an_atlas_restored_between_epochs_recognises_the_place_as_well() {
    merges_onto_the_true_transform_after(AtlasParams::default(), true);
}

/// Epoch 0 drives `old_corners` and epoch 1 `new_corners` (world frame) through `walls`;
/// epoch 1 is merged onto the true transform and then closes loops into the merged data.
/// Returns each loop's error against the true relative pose.
fn loops_into_merged_data(
    walls: &[Segment],
    old_corners: &[(f64, f64)],
    new_corners: &[(f64, f64)],
    params: AtlasParams,
) -> Vec<Se2> {
    let mut atlas = Atlas::new(params).unwrap();
    let old_path = along(old_corners);
    let old = add_epoch(&mut atlas, walls, &old_path, &Se2::identity());
    atlas.end_epoch(EpochEndReason::Kidnap);
    let path = along(new_corners);
    let start = path[0];
    let new = add_epoch(&mut atlas, walls, &path, &start);
    let truth: HashMap<NodeId, Se2> = old
        .into_iter()
        .zip(old_path)
        .chain(new.into_iter().zip(path.iter().copied()))
        .collect();
    let verifier = default_verifier().unwrap();
    let merge = MergeRequest::forced(MapId(0), start.inverse(), "t");
    atlas.merge(merge, Some(&verifier)).unwrap();
    let found = atlas
        .close_loops_into_merged(path.len(), &verifier)
        .unwrap();
    found
        .iter()
        .map(|l| {
            truth[&l.inactive]
                .between(&truth[&l.active])
                .between(&l.inactive_from_active)
        })
        .collect()
}

/// A straight corridor (two walls, nothing else): after a right merge the robot drives on
/// through the old corridor. Place recognition's verifier refuses every match there (a
/// corridor is not unique along its axis), so only `merge.overlap.local_loops` closes loops
/// into the merged data; they are right across the corridor and in heading.
#[test]
fn loops_into_merged_data_in_a_corridor_need_the_local_verifier() {
    let p = Point2::new;
    let corridor = vec![(p(-5.0, -1.0), p(45.0, -1.0)), (p(-5.0, 1.0), p(45.0, 1.0))];
    let loops = |local_loops: bool| {
        let mut params = AtlasParams::default();
        params.merge.overlap.local_loops = local_loops;
        // Epoch 1 drives the same corridor from x = 5 m, slightly off its centre line.
        loops_into_merged_data(
            &corridor,
            &[(0.0, 0.0), (30.0, 0.0)],
            &[(5.0, 0.2), (20.0, 0.2)],
            params,
        )
    };
    assert!(
        loops(false).is_empty(),
        "the place verifier refuses a corridor"
    );
    let errors = loops(true);
    assert!(
        !errors.is_empty(),
        "the local verifier accepts the corridor"
    );
    for error in &errors {
        // Across the corridor and in heading the loops are right; along it (x) they may be
        // anywhere within the gate.
        assert!(
            error.y_m.abs() < 0.05 && error.theta_rad.abs() < 1f64.to_radians(),
            "{error:?}"
        );
        assert!(error.x_m.abs() <= 0.5 + 1e-6, "{error:?}");
    }
}

/// In the irregular room, loops the local matcher refuses (here every one, by a score it
/// cannot reach) are verified again by the place verifier with
/// `merge.overlap.place_verifier_too`, and those it accepts are right.
#[test]
fn loops_the_local_matcher_refuses_are_verified_by_the_place_verifier_too() {
    let loops = |place_verifier_too: bool| {
        let mut params = AtlasParams::default();
        params.loops.min_score = 1.01;
        params.merge.overlap.place_verifier_too = place_verifier_too;
        loops_into_merged_data(
            &world(),
            &[(0.0, 0.0), (12.0, 0.0), (12.0, 4.0), (16.0, 5.0)],
            &[(1.0, 0.3), (11.0, 0.3), (11.5, 4.0)],
            params,
        )
    };
    assert!(loops(false).is_empty(), "the local matcher refuses all");
    let errors = loops(true);
    assert!(!errors.is_empty(), "the place verifier accepts the room");
    for error in &errors {
        assert!(
            error.translation().norm() < 0.1 && error.theta_rad.abs() < 1f64.to_radians(),
            "{error:?}"
        );
    }
}

fn merges_onto_the_true_transform(params: AtlasParams) {
    merges_onto_the_true_transform_after(params, false);
}

/// With `restore`, the atlas is snapshotted after epoch 0 and continues restored (a new run
/// of the lifelong store): its place index is rebuilt from the keyframes.
fn merges_onto_the_true_transform_after(params: AtlasParams, restore: bool) {
    let world = world();
    let mut atlas = Atlas::new(params.clone()).unwrap();
    // Epoch 0 tours the room in the world frame.
    add_epoch(&mut atlas, &world, &room_tour(), &Se2::identity());
    atlas.end_epoch(EpochEndReason::Kidnap);
    if restore {
        let snapshot = atlas.snapshot().unwrap();
        atlas = Atlas::restore(params, Default::default(), snapshot).unwrap();
    }
    let before = atlas.inactive(MapId(0)).unwrap().clone();
    // Epoch 1 starts somewhere else, its frame unknown, and drives back through the room.
    let start = Se2::new(1.0, 8.0, -1.2);
    add_epoch(
        &mut atlas,
        &world,
        &along(&[(1.0, 8.0), (1.5, 4.0), (2.0, 0.5), (9.0, 0.5)]),
        &start,
    );
    let verifier = default_verifier().unwrap();
    let proposals = atlas.find_merges(&verifier);
    assert_eq!(proposals.len(), 1, "{proposals:?}");
    let truth = start.inverse(); // active (epoch 1) from inactive (world)
    let error = truth.between(&proposals[0].active_from_inactive);
    assert!(
        error.translation().norm() < 0.2 && error.theta_rad.abs() < 2f64.to_radians(),
        "{:?} vs {truth:?}",
        proposals[0].active_from_inactive
    );
    let robot = atlas.robot_node().unwrap();
    let robot_pose = atlas.active().vertex(robot).unwrap().pose;
    let event = atlas.merge_by_recognition(&verifier).unwrap().unwrap();
    assert_eq!(event.map, MapId(0));
    assert!(event.overlap_edges > 0, "{event:?}");
    assert_eq!(atlas.active().vertex(robot).unwrap().pose, robot_pose);
    // The merged map agrees with the truth after re-optimisation.
    for (id, v) in before.vertices() {
        let merged = atlas.active().vertex(id).unwrap().pose;
        let d = truth.compose(&v.pose).between(&merged);
        assert!(d.translation().norm() < 0.3, "{id}: {d:?}");
    }
    atlas
        .unmerge_all(UnmergeReason::Requested {
            note: "test".into(),
        })
        .unwrap()
        .unwrap();
    assert_eq!(atlas.inactive(MapId(0)), Some(&before));
}

/// Twelve sessions touring the room, each merged into the map (forced, at the true pose) and
/// maintained: views, local maps and vertices stop growing, every vertex keeps a keyframe or
/// a local map, and the rendered map stays within a few percent of the unpruned one.
#[test]
fn maintenance_keeps_the_atlas_bounded_and_its_map_close_to_the_unpruned_one() {
    use mapmerge_atlas::{MaintenanceParams, MergeRequest, RenderedMap};
    use mapmerge_grid::ClassThresholds;
    let world = world();
    // The room's tour, then back along the left wall.
    let mut tour = room_tour();
    tour.extend(along(&[(8.0, 8.0), (1.0, 8.0), (1.5, 1.0)]));
    let run = |prune: bool| {
        let mut atlas = Atlas::new(AtlasParams::default()).unwrap();
        let params = MaintenanceParams {
            prune,
            ..MaintenanceParams::default()
        };
        let mut counts = Vec::new();
        for session in 0..12 {
            let first = atlas.next_node_id();
            // Each session drives the tour from a different start.
            let mut path = tour.clone();
            path.rotate_left((session * 7) % tour.len());
            add_epoch(&mut atlas, &world, &path, &Se2::identity());
            if session > 0 {
                let map = atlas.inactive_maps().next().map(|(m, _)| m).unwrap();
                atlas
                    .merge(MergeRequest::forced(map, Se2::identity(), "test"), None)
                    .unwrap();
                // Maintenance waits while the merge can be undone.
                assert!(atlas.maintain(&params, first).is_err());
            }
            atlas.end_epoch(EpochEndReason::Restart);
            let report = atlas.maintain(&params, first).unwrap();
            assert_eq!(report.session, session as u32);
            let snapshot = atlas.snapshot().unwrap();
            assert_eq!(snapshot.inactive.len(), 1);
            for graph in snapshot.graphs() {
                for (node, _) in graph.vertices() {
                    assert!(
                        snapshot.keyframes.contains_key(&node)
                            || snapshot.local_maps.contains_key(&node),
                        "vertex {node} anchors nothing"
                    );
                }
            }
            counts.push((
                snapshot.num_vertices(),
                snapshot.keyframes.len(),
                snapshot.local_maps.len(),
            ));
        }
        (atlas, counts)
    };
    let (pruned, counts) = run(true);
    let (unpruned, unpruned_counts) = run(false);
    // Unpruned, everything grows with the sessions; pruned, it stops.
    assert!(unpruned_counts[11].1 > 10 * unpruned_counts[0].1 / 2);
    // No trend: the last four sessions' mean is within 30 % of sessions 2–5's, and no
    // session holds twice as much.
    for which in 0..3 {
        let pick = |c: &(usize, usize, usize)| [c.0, c.1, c.2][which];
        let mean = |range: std::ops::Range<usize>| {
            range.clone().map(|k| pick(&counts[k])).sum::<usize>() as f64 / range.len() as f64
        };
        let (early, late) = (mean(2..6), mean(8..12));
        assert!(late <= 1.3 * early, "{counts:?}");
        assert!(
            counts.iter().skip(2).all(|c| pick(c) as f64 <= 2.0 * early),
            "{counts:?}"
        );
    }
    assert!(
        counts[11].1 < unpruned_counts[11].1 / 4,
        "{counts:?} vs {unpruned_counts:?}"
    );
    // The rendered maps agree on the classes of almost every known cell.
    let render = |atlas: &Atlas| {
        let graph = atlas.inactive_maps().next().unwrap().1.clone();
        let rendered = RenderedMap::render(&graph, atlas.local_maps(), 0.1).unwrap();
        rendered.to_grid().unwrap()
    };
    let (a, b) = (render(&pruned), render(&unpruned));
    let thresholds = ClassThresholds::default();
    let (mut known, mut differ) = (0usize, 0usize);
    for (_, p, l) in b.cells() {
        let class = thresholds.classify(l);
        if class != mapmerge_grid::CellClass::Unknown {
            known += 1;
            differ += usize::from(thresholds.classify(a.log_odds_at(&p)) != class);
        }
    }
    assert!(
        differ as f64 <= 0.1 * known as f64,
        "{differ} of {known} cells differ"
    );
}

/// An atlas whose epoch 0 (now inactive graph 0) drove along the world's south wall and into
/// its east wing: the atlas, that epoch's vertices and their world poses.
fn atlas_with_one_old_epoch(world: &[Segment]) -> (Atlas, Vec<NodeId>, Vec<Se2>) {
    let mut atlas = Atlas::new(AtlasParams::default()).unwrap();
    let old_path = along(&[(0.0, 0.0), (12.0, 0.0), (12.0, 4.0), (16.0, 5.0)]);
    let old = add_epoch(&mut atlas, world, &old_path, &Se2::identity());
    atlas.end_epoch(EpochEndReason::Kidnap);
    (atlas, old, old_path)
}

#[test]
fn a_hypothesis_placed_right_is_confirmed_where_it_puts_the_robot_and_one_placed_wrong_is_not() {
    let world = world();
    let (mut atlas, old, old_path) = atlas_with_one_old_epoch(&world);
    let start = Se2::new(1.0, 8.0, -1.2);
    let path = along(&[(1.0, 8.0), (1.5, 4.0), (2.0, 0.5), (9.0, 0.5)]);
    let new = add_epoch(&mut atlas, &world, &path, &start);
    let verifier = default_verifier().unwrap();
    let robot = *new.last().unwrap();
    // The true placement: the newest keyframe matches the old epoch's nearest vertex, on the
    // true relative pose.
    let truth = start.inverse();
    let found = atlas.confirm_at(MapId(0), &truth, &[robot], &verifier);
    assert_eq!(found.len(), 1, "{found:?}");
    let world_of: HashMap<NodeId, Se2> = old
        .into_iter()
        .zip(old_path)
        .chain(new.iter().copied().zip(path.iter().copied()))
        .collect();
    let l = found[0];
    let error = world_of[&l.inactive]
        .between(&world_of[&l.active])
        .between(&l.inactive_from_active);
    assert!(error.translation().norm() < 0.1, "{error:?}");
    // Placed 1.5 m off, beyond the overlap gate: nothing confirms it.
    let wrong = truth.compose(&Se2::new(1.5, 0.0, 0.0));
    assert!(atlas
        .confirm_at(MapId(0), &wrong, &[robot], &verifier)
        .is_empty());
    // An unknown map confirms nothing.
    assert!(atlas
        .confirm_at(MapId(7), &truth, &[robot], &verifier)
        .is_empty());
    // Retrieval finds the robot at its true pose in the old epoch's map (the map's frame is
    // the world's), whatever a hypothesis says; an unknown map gives nothing.
    let robot_in_world = *path.last().unwrap();
    let placements = atlas.placements_by_retrieval(MapId(0), robot, &verifier);
    assert!(
        placements.iter().any(|(_, map_from_robot, score)| {
            let error = map_from_robot.between(&robot_in_world);
            error.translation().norm() < 0.2 && error.theta_rad.abs() < 0.05 && *score > 0.9
        }),
        "{placements:?}"
    );
    assert!(atlas
        .placements_by_retrieval(MapId(7), robot, &verifier)
        .is_empty());
}

/// A view's surroundings join the local maps of the view and of neighbours within the
/// radius, spaced as asked, in the view's frame: its own points are among them, and a wider
/// radius or closer spacing joins more.
#[test]
fn a_views_surroundings_join_its_neighbours_local_maps_in_its_frame() {
    let world = world();
    let (atlas, old, old_path) = atlas_with_one_old_epoch(&world);
    let view = old[10];
    let alone = atlas.view_keyframe(MapId(0), view).unwrap();
    let near = atlas
        .view_surroundings(MapId(0), view, 0.1, 2.0, 8)
        .unwrap();
    // Nothing else within 0.1 m: the view's own local map.
    assert_eq!(
        near.points_in_keyframe.len(),
        alone.points_in_keyframe.len()
    );
    let wide = atlas
        .view_surroundings(MapId(0), view, 12.0, 2.0, 8)
        .unwrap();
    assert!(wide.points_in_keyframe.len() > alone.points_in_keyframe.len());
    // Every joined point lies on a wall of the world, seen from the view's true pose.
    let world_from_view = old_path[10];
    for p in wide.points_in_keyframe.iter().step_by(7) {
        let w = world_from_view.transform_point(p);
        let on_wall = world.iter().any(|(a, b)| {
            let t = ((w - a).dot(&(b - a)) / (b - a).norm_squared()).clamp(0.0, 1.0);
            (a + (b - a) * t - w).norm() < 0.15
        });
        assert!(on_wall, "{p:?} at {w:?}");
    }
    // One view at most: the view alone.
    let one = atlas
        .view_surroundings(MapId(0), view, 12.0, 2.0, 1)
        .unwrap();
    assert_eq!(one.points_in_keyframe.len(), alone.points_in_keyframe.len());
    assert!(atlas
        .view_surroundings(MapId(3), view, 12.0, 2.0, 8)
        .is_none());
}

/// A new session (`EpochEndReason::Restart`, or an atlas restored between sessions, as
/// from a store) searches the stored map from its first keyframe
/// (`recognition.session_start_search_m`) and finds its pose there; a kidnapped robot's
/// epoch waits for `recognition.min_epoch_keyframes` as before.
#[test]
fn a_new_session_searches_the_stored_map_from_its_first_keyframe() {
    let world = world();
    let tour = room_tour();
    // The new epoch's first keyframes: turning on the spot near the tour's start.
    let start = Se2::new(1.0, 0.3, 0.4);
    let first: Vec<Se2> = (0..3)
        .map(|i| start.compose(&Se2::new(0.0, 0.0, 0.3 * i as f64)))
        .collect();
    let search = |reason: EpochEndReason, restore: bool| {
        let params = AtlasParams::default();
        let mut atlas = Atlas::new(params.clone()).unwrap();
        add_epoch(&mut atlas, &world, &tour, &Se2::identity());
        atlas.end_epoch(reason);
        if restore {
            let snapshot = atlas.snapshot().unwrap();
            atlas = Atlas::restore(params, Default::default(), snapshot).unwrap();
        }
        let nodes = add_epoch(&mut atlas, &world, &first, &start);
        let verifier = default_verifier().unwrap();
        let node = *nodes.last().unwrap();
        let found = atlas.search_constraints(node, &verifier).unwrap();
        (
            found.merge_candidates,
            atlas.constraint_info().merge_queries,
        )
    };
    let (candidates, queries) = search(EpochEndReason::Kidnap, false);
    assert_eq!(queries, 0, "a kidnapped robot's epoch waits");
    assert!(candidates.is_empty());
    for restore in [false, true] {
        let (candidates, queries) = search(EpochEndReason::Restart, restore);
        assert_eq!(
            queries, 1,
            "a new session searches at once (restored: {restore})"
        );
        let truth = start.inverse(); // active (new session) from inactive (world)
        let found = candidates
            .first()
            .expect("the start is found in the stored map");
        let error = truth.between(&found.active_from_inactive);
        assert!(
            error.translation().norm() < 0.2 && error.theta_rad.abs() < 2f64.to_radians(),
            "{:?} vs {truth:?}",
            found.active_from_inactive
        );
    }
}

/// Issue 66: an epoch that never merged (a fragment) rejoins the site map at the session's
/// end, on the true transform; a fragment of a place the site never saw stays apart, and
/// nothing rejoins with rejoining off.
#[test]
fn a_fragment_the_site_map_covers_rejoins_it_on_the_true_transform() {
    use mapmerge_atlas::{AtlasEvent, RejoinParams};
    let world = world();
    let verifier = default_verifier().unwrap();
    let fragmented = |params: &RejoinParams| {
        let mut atlas = Atlas::new(AtlasParams::default()).unwrap();
        // The site: the room's tour in the world frame.
        add_epoch(&mut atlas, &world, &room_tour(), &Se2::identity());
        atlas.end_epoch(EpochEndReason::Restart);
        // A fragment in its own frame, back through the room.
        let start = Se2::new(1.0, 8.0, -1.2);
        let path = along(&[(1.0, 8.0), (1.5, 4.0), (2.0, 0.5), (9.0, 0.5)]);
        let fragment_nodes = add_epoch(&mut atlas, &world, &path, &start);
        atlas.end_epoch(EpochEndReason::Restart);
        // A fragment beyond the room's walls, where the site never was.
        let outside: Vec<Se2> = along(&[(30.0, 0.0), (36.0, 0.0)]);
        add_epoch(&mut atlas, &world, &outside, &Se2::new(30.0, 0.0, 0.0));
        atlas.end_epoch(EpochEndReason::Restart);
        let events = atlas.rejoin_fragments(params, &verifier).unwrap();
        (atlas, events, fragment_nodes, path)
    };
    let (atlas, events, nodes, path) = fragmented(&RejoinParams::default());
    assert_eq!(events.len(), 1, "{events:?}");
    let AtlasEvent::Rejoined(rejoin) = &events[0] else {
        panic!("{events:?}");
    };
    assert_eq!((rejoin.map, rejoin.into), (MapId(1), MapId(0)));
    assert!(rejoin.loops.len() >= 2, "{rejoin:?}");
    assert_eq!(atlas.inactive_maps().len(), 2);
    assert!(atlas.inactive(MapId(1)).is_none());
    let site = atlas.inactive(MapId(0)).unwrap();
    for (node, truth) in nodes.iter().zip(&path) {
        let d = truth.between(&site.vertex(*node).unwrap().pose);
        assert!(
            d.translation().norm() < 0.3 && d.theta_rad.abs() < 2f64.to_radians(),
            "{node}: {d:?}"
        );
    }
    let off = RejoinParams {
        queries: 0,
        ..RejoinParams::default()
    };
    let (atlas, events, _, _) = fragmented(&off);
    assert!(events.is_empty());
    assert_eq!(atlas.inactive_maps().len(), 3);
}

/// A wall's returns in the robot frame: points every 0.1 m along x, from −`half_length_m` to
/// `half_length_m`, at `y_m`.
fn wall_along_x(y_m: f64, half_length_m: f64) -> Arc<[Point2]> {
    let n = (half_length_m / 0.1).round() as i32;
    (-n..=n)
        .map(|i| Point2::new(f64::from(i) * 0.1, y_m))
        .collect()
}

/// Issue 66: views are pruned by what they add. Three views 0.2 m apart in one graph, all
/// new this session: the first two see one wall, the third another. The newest is placed
/// first; the second adds its wall and stays; the first adds nothing and goes. With
/// distance alone (a fixed net) only the newest stays.
#[test]
fn a_view_is_kept_near_another_only_while_it_adds_structure_the_other_did_not_see() {
    use mapmerge_atlas::MaintenanceParams;
    let wall = |y_m: f64| wall_along_x(y_m, 2.0);
    let kept_views = |params: &MaintenanceParams| {
        let mut atlas = Atlas::new(AtlasParams::default()).unwrap();
        let first = atlas.next_node_id();
        let mut nodes: Vec<NodeId> = Vec::new();
        for (k, y) in [2.0, 2.0, -2.0].into_iter().enumerate() {
            let pose = Se2::new(0.2 * k as f64, 0.0, 0.0);
            let node = atlas.add_vertex(Vertex::new(pose), wall(y));
            if let Some(previous) = nodes.last() {
                atlas
                    .add_edge(Edge {
                        from: *previous,
                        to: node,
                        measurement: Se2::new(0.2, 0.0, 0.0),
                        information: Matrix3::identity() * 100.0,
                        kind: EdgeKind::Odometry,
                    })
                    .unwrap();
            }
            nodes.push(node);
        }
        atlas.end_epoch(EpochEndReason::Restart);
        atlas.maintain(params, first).unwrap();
        nodes
            .iter()
            .map(|n| atlas.keyframes().get(*n).is_some())
            .collect::<Vec<bool>>()
    };
    assert_eq!(
        kept_views(&MaintenanceParams::default()),
        vec![false, true, true]
    );
    let net = MaintenanceParams {
        view_min_new_fraction: f64::INFINITY,
        ..MaintenanceParams::default()
    };
    assert_eq!(kept_views(&net), vec![false, false, true]);
}

/// Issue 66, part 1: views are kept by what they add, not by where the robot once drove.
/// Two views 1.5 m apart see one stretch of wall, a third 6 m away another. With a net too
/// coarse to hold a view beside another (5 m), one of the first two goes and the third, the
/// only view of its wall, stays, in recent use or not.
#[test]
fn views_stay_while_they_add_structure() {
    use mapmerge_atlas::MaintenanceParams;
    // A budget that does not bind in this small world, and a coarse net.
    let params = MaintenanceParams {
        max_views_per_m2: 10.0,
        view_spacing_m: 5.0,
        ..MaintenanceParams::default()
    };
    let mut atlas = Atlas::new(AtlasParams::default()).unwrap();
    let first = atlas.next_node_id();
    let wall = |y_m: f64| wall_along_x(y_m, 2.0);
    let poses = [
        Se2::identity(),
        Se2::new(1.5, 0.0, 0.0),
        Se2::new(7.5, 0.0, 0.0),
    ];
    let scans = [wall(2.0), wall(2.0), wall(-2.0)];
    // The first two see the same stretch of wall (in the map frame): the second's scan is
    // shifted back by its 1.5 m.
    let scans: Vec<Arc<[Point2]>> = scans
        .iter()
        .zip(&poses)
        .map(|(scan, pose)| {
            let dx = if pose.x_m == 1.5 { -1.5 } else { 0.0 };
            scan.iter().map(|p| Point2::new(p.x + dx, p.y)).collect()
        })
        .collect();
    let nodes: Vec<NodeId> = poses
        .iter()
        .zip(&scans)
        .map(|(pose, scan)| atlas.add_vertex(Vertex::new(*pose), scan.clone()))
        .collect();
    for pair in nodes.windows(2) {
        let (from, to) = (pair[0], pair[1]);
        let measurement = atlas
            .active()
            .vertex(from)
            .unwrap()
            .pose
            .between(&atlas.active().vertex(to).unwrap().pose);
        atlas
            .add_edge(Edge {
                from,
                to,
                measurement,
                information: Matrix3::identity() * 100.0,
                kind: EdgeKind::Odometry,
            })
            .unwrap();
    }
    atlas.end_epoch(EpochEndReason::Restart);
    let views = |atlas: &Atlas| {
        nodes
            .iter()
            .map(|n| atlas.keyframes().get(*n).is_some())
            .collect::<Vec<_>>()
    };
    atlas.maintain(&params, first).unwrap();
    for session in 0..=params.recent_sessions {
        if session > 0 {
            let first = atlas.next_node_id();
            atlas.maintain(&params, first).unwrap();
        }
        let kept = views(&atlas);
        assert!(
            kept[2],
            "session {session}: the only view of its wall stays"
        );
        assert_eq!(
            kept.iter().filter(|k| **k).count(),
            2,
            "session {session}: {kept:?}"
        );
    }
}

/// Issue 66, part 1: once a place is covered, a session that sees nothing new adds no view.
/// Eight sessions drive the same 6 m of corridor along one wall: the map keeps as many
/// views after the eighth as after the first, as many as its budget of views per m² allows
/// (a larger budget keeps more), and while they are in recent use mostly the same views (the
/// map does not churn). A session that sees a second wall adds views.
#[test]
fn a_covered_place_keeps_as_many_views_however_often_it_is_driven() {
    use mapmerge_atlas::MaintenanceParams;
    let wall = |y_m: f64| wall_along_x(y_m, 3.0);
    let drive = |atlas: &mut Atlas,
                 previous: &mut Option<(NodeId, Se2)>,
                 params: &MaintenanceParams,
                 y_m: f64,
                 walls_y_m: &[f64]| {
        let first = atlas.next_node_id();
        for k in 0..=30 {
            let pose = Se2::new(0.2 * f64::from(k), y_m, 0.0);
            // The scan in the robot frame: the walls at `walls_y_m` in the map.
            let scan: Vec<Point2> = walls_y_m
                .iter()
                .flat_map(|w| wall(w - y_m).to_vec())
                .collect();
            let node = atlas.add_vertex(Vertex::new(pose), scan.into());
            if let Some((from, from_pose)) = *previous {
                atlas
                    .add_edge(Edge {
                        from,
                        to: node,
                        measurement: from_pose.between(&pose),
                        information: Matrix3::identity() * 100.0,
                        kind: EdgeKind::Odometry,
                    })
                    .unwrap();
            }
            *previous = Some((node, pose));
        }
        atlas.maintain(params, first).unwrap();
        atlas
            .keyframes()
            .records()
            .map(|(node, _)| node)
            .collect::<Vec<NodeId>>()
    };
    let lived = |params: &MaintenanceParams| {
        let mut atlas = Atlas::new(AtlasParams::default()).unwrap();
        let mut previous = None;
        let views: Vec<Vec<NodeId>> = (0..8)
            .map(|session| {
                let y_m = 0.1 + 0.01 * f64::from(session);
                drive(&mut atlas, &mut previous, params, y_m, &[2.0])
            })
            .collect();
        let after_new_wall = drive(&mut atlas, &mut previous, params, 0.1, &[2.0, -1.0]);
        let see_it = atlas
            .keyframes()
            .records()
            .filter(|(node, _)| {
                atlas
                    .keyframes()
                    .get(*node)
                    .is_some_and(|points| points.iter().any(|p| p.y < 0.0))
            })
            .count();
        (views, after_new_wall.len(), see_it)
    };
    let params = MaintenanceParams::default();
    let (views, after_new_wall, see_it) = lived(&params);
    let counts: Vec<usize> = views.iter().map(Vec::len).collect();
    assert!(counts[0] >= 2, "{counts:?}");
    assert!(counts.iter().all(|c| *c == counts[0]), "{counts:?}");
    for session in 1..params.recent_sessions as usize {
        let same = views[session]
            .iter()
            .filter(|n| views[0].contains(n))
            .count();
        assert!(
            same + 1 >= counts[0],
            "session {session}: {:?} after {:?}",
            views[session],
            views[0]
        );
    }
    assert!(
        after_new_wall > counts[0],
        "{after_new_wall} after {counts:?}"
    );
    assert!(see_it > 0);
    let (larger, _, _) = lived(&MaintenanceParams {
        max_views_per_m2: 1.0,
        ..params
    });
    assert!(larger[7].len() > counts[7], "{larger:?} against {counts:?}");
}
