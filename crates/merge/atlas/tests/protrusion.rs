//! Protrusion detection's segmentation (iRobot Sec. 5.4) on hand-made versions: new space is
//! found where the child's map is free and the parent's is not, its features match its shape,
//! and removing it from the session's local maps leaves no new space.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;

use mapmerge_atlas::{
    new_regions, remove_regions, Atlas, AtlasParams, AtlasSnapshot, LocalMapGrid, ProtrusionParams,
};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph2, Vertex};
use mapmerge_scan::Point2;
use nalgebra::Matrix3;

/// A 360° scan from the centre of an empty `w × h` box (robot frame = box centre).
fn box_scan(w: f64, h: f64) -> Vec<Point2> {
    (0..720)
        .map(|i| {
            let a = (i as f64 * 0.5).to_radians();
            let (c, s) = (a.cos(), a.sin());
            let t = ((w / 2.0) / c.abs().max(1e-9)).min((h / 2.0) / s.abs().max(1e-9));
            Point2::new(c * t, s * t)
        })
        .collect()
}

/// An atlas snapshot with one graph of the given vertices (x positions), each anchoring a
/// local map of a box seen from its centre.
fn version(rooms: &[(u64, f64, f64, f64)]) -> AtlasSnapshot {
    let mut snapshot = Atlas::new(AtlasParams::default())
        .unwrap()
        .snapshot()
        .unwrap();
    let mut graph = PoseGraph2::new();
    let mut local_maps = BTreeMap::new();
    for (id, x, w, h) in rooms {
        graph
            .add_vertex(NodeId(*id), Vertex::new(Se2::new(*x, 0.0, 0.0)))
            .unwrap();
        // Three scans from near the centre (one miss alone does not make a cell free).
        let scans: Vec<(Se2, Vec<Point2>)> = [(0.0, 0.0), (0.3, 0.2), (-0.2, 0.3)]
            .iter()
            .map(|(dx, dy)| {
                let points = box_scan(*w, *h)
                    .into_iter()
                    .map(|p| p - Point2::new(*dx, *dy))
                    .collect();
                (Se2::new(*dx, *dy, 0.0), points)
            })
            .collect();
        let map = LocalMapGrid::from_keyframes(
            0.05,
            scans.iter().map(|(pose, points)| (*pose, &points[..])),
        )
        .unwrap();
        local_maps.insert(NodeId(*id), map);
    }
    let ids: Vec<NodeId> = graph.vertices().map(|(n, _)| n).collect();
    for pair in ids.windows(2) {
        let (a, b) = (
            graph.vertex(pair[0]).unwrap().pose,
            graph.vertex(pair[1]).unwrap().pose,
        );
        graph
            .add_edge(Edge {
                from: pair[0],
                to: pair[1],
                measurement: a.between(&b),
                information: Matrix3::identity(),
                kind: EdgeKind::Odometry,
            })
            .unwrap();
    }
    snapshot.inactive.insert(mapmerge_atlas::MapId(0), graph);
    snapshot.local_maps = local_maps;
    snapshot.counters.next_node = 100;
    snapshot.counters.next_map = 1;
    snapshot
}

#[test]
fn a_new_room_is_one_region_of_its_size_and_removing_it_leaves_none() {
    // The parent saw one 4 m × 4 m room around x = 0 (two vertices); the child also a
    // 3 m × 3 m room around x = 6.
    let parent = version(&[(0, 0.0, 4.0, 4.0), (1, 0.5, 4.0, 4.0)]);
    let child = version(&[(0, 0.0, 4.0, 4.0), (1, 0.5, 4.0, 4.0), (2, 6.0, 3.0, 3.0)]);
    let params = ProtrusionParams::default();
    let (rendered, regions) = new_regions(&parent, &child, &params).unwrap();
    assert_eq!(regions.len(), 1, "{regions:?}");
    let features = regions[0].features;
    // The free inside of a 3 m box, less the wall cells and the opening's margins.
    assert!((6.0..9.5).contains(&features.area_m2), "{features:?}");
    // A square of side s has equal axes 4 s / √12 (the second moments of a uniform square).
    let side = features.area_m2.sqrt();
    assert!(
        (features.minor_axis_m - 4.0 * side / 12f64.sqrt()).abs() < 0.05,
        "{features:?}"
    );
    assert!(
        (features.major_axis_m - features.minor_axis_m).abs() < 0.05,
        "{features:?}"
    );
    assert!(features.mean_distance_m > 0.3, "{features:?}");
    assert!(
        (regions[0].centre_m[0] - 6.0).abs() < 0.3,
        "{:?}",
        regions[0].centre_m
    );
    // Nothing new when nothing changed.
    assert!(new_regions(&parent, &parent, &params).unwrap().1.is_empty());
    // Removed from the session's local map, the room is unknown again.
    let mut cleaned = child.clone();
    let region = &regions[0];
    assert_eq!(
        remove_regions(&parent, &mut cleaned, &rendered, &[region]),
        1
    );
    assert_eq!(cleaned.local_maps[&NodeId(0)], child.local_maps[&NodeId(0)]);
    let (_, after) = new_regions(&parent, &cleaned, &params).unwrap();
    assert!(after.is_empty(), "{after:?}");
}

#[test]
fn the_parents_frame_does_not_matter() {
    // The same versions, the child's graph moved as a whole: the same region is found.
    let parent = version(&[(0, 0.0, 4.0, 4.0), (1, 0.5, 4.0, 4.0)]);
    let mut child = version(&[(0, 0.0, 4.0, 4.0), (1, 0.5, 4.0, 4.0), (2, 6.0, 3.0, 3.0)]);
    let moved = Se2::new(3.0, -2.0, 0.7);
    let graph = child.inactive.get_mut(&mapmerge_atlas::MapId(0)).unwrap();
    let ids: Vec<NodeId> = graph.vertices().map(|(n, _)| n).collect();
    for id in ids {
        let v = graph.vertex_mut(id).unwrap();
        v.pose = moved.compose(&v.pose);
    }
    let (_, regions) = new_regions(&parent, &child, &ProtrusionParams::default()).unwrap();
    assert_eq!(regions.len(), 1, "{regions:?}");
    assert!(
        (6.0..9.5).contains(&regions[0].features.area_m2),
        "{:?}",
        regions[0].features
    );
}

#[test]
fn a_slipped_map_is_realigned_and_only_the_space_it_made_is_lost() {
    // The parent saw a 4 m × 4 m room. The session mapped a new 3 m × 3 m room at x = 6,
    // then saw the first room again after an undetected slip: that map lies 0.4 m and 10°
    // off, painting free space through the parent's walls.
    let parent = version(&[(0, 0.0, 4.0, 4.0), (1, 0.0, 4.0, 4.0)]);
    let rooms = [
        (0, 0.0, 4.0, 4.0),
        (1, 0.0, 4.0, 4.0),
        (2, 6.0, 3.0, 3.0),
        (3, 0.0, 4.0, 4.0),
    ];
    let params = ProtrusionParams::default();
    // Without the slip only the new room is new, and nothing moves.
    let (_, regions) = new_regions(&parent, &version(&rooms), &params).unwrap();
    assert_eq!(regions.len(), 1, "{regions:?}");
    assert!(regions[0].features.realigned_loss < 0.05, "{regions:?}");
    assert!(regions[0].features.realigned_shift_m < 0.05, "{regions:?}");

    let mut child = version(&rooms);
    let graph = child.inactive.get_mut(&mapmerge_atlas::MapId(0)).unwrap();
    graph.vertex_mut(NodeId(3)).unwrap().pose = Se2::new(0.4, 0.3, 10f64.to_radians());
    let (_, regions) = new_regions(&parent, &child, &params).unwrap();
    let (room, ghosts): (Vec<_>, Vec<_>) = regions
        .iter()
        .partition(|r| (r.centre_m[0] - 6.0).abs() < 1.0);
    assert_eq!(room.len(), 1, "{regions:?}");
    assert!(!ghosts.is_empty(), "{regions:?}");
    // The new room stays: it was mapped before the slip.
    assert!(room[0].features.realigned_loss < 0.05, "{room:?}");
    // What the slipped map painted beyond the parent's walls is gone once it is realigned,
    // and the realignment moved it by about the slip.
    for ghost in ghosts {
        let f = ghost.features;
        assert!(f.realigned_loss > 0.9, "{f:?}");
        assert!((0.3..1.0).contains(&f.realigned_shift_m), "{f:?}");
        assert!(f.observer_wall_offset_m > 0.1, "{f:?}");
    }
}
