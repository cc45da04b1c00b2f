//! Odometry chaining on synthetic graphs.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::{helix_3d, max_pose_error, scrambled, spiral_2d};
use mapmerge_geometry::{LieGroup, Se2, Se3};
use mapmerge_init::{initialize_odometry, InitError};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph2, Vertex};
use nalgebra::Matrix3;

fn edge(from: u64, to: u64, z: Se2) -> Edge<Se2, 3> {
    let kind = if to == from + 1 {
        EdgeKind::Odometry
    } else {
        EdgeKind::Loop
    };
    Edge {
        from: NodeId(from),
        to: NodeId(to),
        measurement: z,
        information: Matrix3::identity(),
        kind,
    }
}

fn graph_with(ids: &[u64]) -> PoseGraph2 {
    let mut g = PoseGraph2::new();
    for &id in ids {
        g.add_vertex(NodeId(id), Vertex::new(Se2::identity()))
            .unwrap();
    }
    g
}

fn pose(g: &PoseGraph2, id: u64) -> Se2 {
    g.vertex(NodeId(id)).unwrap().pose
}

fn close(a: Se2, b: Se2) -> bool {
    a.local(&b).norm() < 1e-12
}

#[test]
fn exact_2d_spiral_is_recovered_from_the_anchor() {
    let truth = spiral_2d(300, 4.0);
    let mut g = scrambled(&truth, &[NodeId(0)], Se2::new(3.0, -1.0, 2.0));
    let info = initialize_odometry(&mut g).unwrap();
    assert_eq!(info.vertices_set, 299);
    assert_eq!(info.components, 1);
    assert_eq!(info.anchors, vec![NodeId(0)]);
    assert_eq!(info.edges_used, 299);
    assert!(
        max_pose_error(&g, &truth) < 1e-9,
        "{}",
        max_pose_error(&g, &truth)
    );
}

#[test]
fn exact_3d_helix_is_recovered_from_the_anchor() {
    let truth = helix_3d(200, 3.0);
    let mut g = scrambled(&truth, &[NodeId(0)], Se3::identity());
    initialize_odometry(&mut g).unwrap();
    assert!(
        max_pose_error(&g, &truth) < 1e-9,
        "{}",
        max_pose_error(&g, &truth)
    );
}

#[test]
fn consecutive_edges_are_chained_before_the_breadth_first_search() {
    // Edge 0 -> 2 comes first in edge order and disagrees with 0 -> 1 -> 2: the chain wins,
    // as in gtsam_pgo.py.
    let mut g = graph_with(&[0, 1, 2]);
    let (z02, z01, z12) = (
        Se2::new(5.0, 5.0, 1.0),
        Se2::new(1.0, 0.0, 0.5),
        Se2::new(2.0, 0.0, 0.0),
    );
    g.add_edge(edge(0, 2, z02)).unwrap();
    g.add_edge(edge(0, 1, z01)).unwrap();
    g.add_edge(edge(1, 2, z12)).unwrap();
    initialize_odometry(&mut g).unwrap();
    assert!(close(pose(&g, 2), z01.compose(&z12)));

    // Without the chain edge 1 -> 2, vertex 2 is reached from 0 by the BFS.
    let mut g = graph_with(&[0, 1, 2]);
    g.add_edge(edge(0, 2, z02)).unwrap();
    g.add_edge(edge(0, 1, z01)).unwrap();
    initialize_odometry(&mut g).unwrap();
    assert!(close(pose(&g, 2), z02));
}

#[test]
fn backward_edges_use_the_inverse_measurement_and_the_anchor_keeps_its_pose() {
    let mut g = graph_with(&[3, 4, 9]);
    let anchor = Se2::new(-2.0, 7.0, 3.0);
    g.vertex_mut(NodeId(3)).unwrap().pose = anchor;
    let (z43, z94) = (Se2::new(1.0, 2.0, -0.4), Se2::new(-3.0, 0.5, 2.9));
    g.add_edge(edge(4, 3, z43)).unwrap();
    g.add_edge(edge(9, 4, z94)).unwrap();
    let info = initialize_odometry(&mut g).unwrap();
    assert_eq!(info.anchors, vec![NodeId(3)]);
    assert_eq!(pose(&g, 3), anchor);
    assert!(close(pose(&g, 4), anchor.compose(&z43.inverse())));
    assert!(close(pose(&g, 9), pose(&g, 4).compose(&z94.inverse())));
}

#[test]
fn each_component_has_its_own_anchor_and_fixed_vertices_are_kept() {
    let mut g = graph_with(&[0, 1, 2, 10, 11, 20]);
    let fixed = Se2::new(4.0, 4.0, -1.0);
    {
        let v = g.vertex_mut(NodeId(11)).unwrap();
        v.pose = fixed;
        v.fixed = true;
    }
    let isolated = Se2::new(9.0, 9.0, 0.3);
    g.vertex_mut(NodeId(20)).unwrap().pose = isolated;
    let z = Se2::new(1.0, 0.0, 0.2);
    g.add_edge(edge(0, 1, z)).unwrap();
    g.add_edge(edge(1, 2, z)).unwrap();
    g.add_edge(edge(10, 11, z)).unwrap();
    let info = initialize_odometry(&mut g).unwrap();
    assert_eq!(info.components, 3);
    assert_eq!(info.anchors, vec![NodeId(0), NodeId(11), NodeId(20)]);
    assert_eq!(info.vertices_set, 3);
    assert_eq!(pose(&g, 11), fixed);
    assert_eq!(pose(&g, 20), isolated);
    assert!(close(pose(&g, 10), fixed.compose(&z.inverse())));
    assert!(close(pose(&g, 2), z.compose(&z)));
}

#[test]
fn graphs_without_edges_or_vertices_are_left_alone() {
    let mut empty = PoseGraph2::new();
    let info = initialize_odometry(&mut empty).unwrap();
    assert_eq!((info.vertices_set, info.components), (0, 0));

    let mut g = graph_with(&[1, 5, 7]);
    g.vertex_mut(NodeId(5)).unwrap().pose = Se2::new(1.0, 2.0, 3.0);
    let before = g.clone();
    let info = initialize_odometry(&mut g).unwrap();
    assert_eq!((info.vertices_set, info.components), (0, 3));
    assert_eq!(g, before);
}

#[test]
fn priors_are_ignored() {
    let mut g = graph_with(&[0, 1]);
    let z = Se2::new(1.0, 0.0, 0.2);
    g.add_edge(edge(0, 1, z)).unwrap();
    g.add_edge(Edge {
        from: NodeId(1),
        to: NodeId(1),
        measurement: Se2::new(50.0, 50.0, 1.0),
        information: Matrix3::identity(),
        kind: EdgeKind::Prior,
    })
    .unwrap();
    let info = initialize_odometry(&mut g).unwrap();
    assert_eq!(info.components, 1);
    assert!(close(pose(&g, 1), z));
}

#[test]
fn non_finite_measurement_is_an_error_and_leaves_the_graph_unchanged() {
    let mut g = graph_with(&[0, 1, 2]);
    g.add_edge(edge(0, 1, Se2::new(1.0, 0.0, 0.0))).unwrap();
    g.add_edge(edge(
        1,
        2,
        Se2 {
            x_m: f64::NAN,
            y_m: 0.0,
            theta_rad: 0.0,
        },
    ))
    .unwrap();
    // Compare vertices only: the NaN edge is not equal to itself.
    let before: Vec<_> = g.vertices().map(|(id, v)| (id, *v)).collect();
    let err = initialize_odometry(&mut g).unwrap_err();
    assert!(
        matches!(
            err,
            InitError::NonFiniteMeasurement {
                from: NodeId(1),
                to: NodeId(2),
                ..
            }
        ),
        "{err}"
    );
    assert!(g.vertices().map(|(id, v)| (id, *v)).eq(before));
}

#[test]
fn non_finite_anchor_is_an_error() {
    let mut g = graph_with(&[0, 1]);
    g.vertex_mut(NodeId(0)).unwrap().pose = Se2 {
        x_m: f64::INFINITY,
        y_m: 0.0,
        theta_rad: 0.0,
    };
    g.add_edge(edge(0, 1, Se2::new(1.0, 0.0, 0.0))).unwrap();
    assert!(matches!(
        initialize_odometry(&mut g),
        Err(InitError::NonFiniteAnchor { node: NodeId(0) })
    ));
}
