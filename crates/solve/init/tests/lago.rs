//! LAGO on synthetic planar graphs.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::{add_exact_edge, add_noise, max_pose_error, scrambled, spiral_2d};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_init::{initialize_lago, initialize_odometry, InitError, LagoParams};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph2, Vertex};
use nalgebra::{Matrix3, Vector3};
use proptest::prelude::*;

fn lago(g: &mut PoseGraph2) -> mapmerge_init::InitInfo {
    initialize_lago(g, &LagoParams::default()).unwrap()
}

#[test]
fn exact_spiral_with_headings_wrapping_many_times_is_recovered() {
    // Five laps: the unwrapped heading grows by 10π, and loop closures a lap apart differ from
    // the tree by 2π.
    let truth = spiral_2d(500, 5.0);
    let mut g = scrambled(&truth, &[NodeId(0)], Se2::identity());
    let info = lago(&mut g);
    assert_eq!(info.vertices_set, 499);
    assert_eq!(info.components, 1);
    assert_eq!(info.edges_used, truth.num_edges());
    assert!(info.angle_corrections > 0, "{}", info.angle_corrections);
    let err = max_pose_error(&g, &truth);
    assert!(err < 1e-9, "max pose error {err}");
    assert!(g.chi2() < 1e-12, "chi2 {}", g.chi2());
}

#[test]
fn unit_weights_also_recover_exact_data() {
    let truth = spiral_2d(200, 3.0);
    let mut g = scrambled(&truth, &[NodeId(0)], Se2::new(1.0, 1.0, 1.0));
    initialize_lago(
        &mut g,
        &LagoParams {
            weight_by_information: false,
        },
    )
    .unwrap();
    assert!(max_pose_error(&g, &truth) < 1e-9);
}

#[test]
fn fixed_vertices_anchor_the_estimate_and_are_not_written() {
    let mut truth = spiral_2d(300, 3.0);
    for id in [40, 200] {
        truth.vertex_mut(NodeId(id)).unwrap().fixed = true;
    }
    let mut g = scrambled(&truth, &[], Se2::identity());
    let info = lago(&mut g);
    assert_eq!(info.anchors, vec![NodeId(40)]);
    assert_eq!(info.vertices_set, 298);
    for id in [40, 200] {
        assert_eq!(
            g.vertex(NodeId(id)).unwrap().pose,
            truth.vertex(NodeId(id)).unwrap().pose
        );
    }
    assert!(
        max_pose_error(&g, &truth) < 1e-9,
        "{}",
        max_pose_error(&g, &truth)
    );
}

#[test]
fn noisy_measurements_give_a_close_estimate_better_than_odometry() {
    let truth = spiral_2d(500, 5.0);
    let mut noisy = truth.clone();
    add_noise(&mut noisy, Vector3::new(0.02, 0.02, 0.01), 7);
    let mut g = scrambled(&noisy, &[NodeId(0)], Se2::identity());
    lago(&mut g);
    let mut odo = scrambled(&noisy, &[NodeId(0)], Se2::identity());
    initialize_odometry(&mut odo).unwrap();
    let (err_lago, err_odo) = (max_pose_error(&g, &truth), max_pose_error(&odo, &truth));
    let (chi2_lago, chi2_odo, chi2_truth) = (g.chi2(), odo.chi2(), noisy.chi2());
    println!("lago: err {err_lago:.3} chi2 {chi2_lago:.1}; odometry: err {err_odo:.3} chi2 {chi2_odo:.1}; truth chi2 {chi2_truth:.1}");
    assert!(err_lago < 1.0, "{err_lago}");
    assert!(err_lago < 0.5 * err_odo);
    assert!(chi2_lago < 0.05 * chi2_odo);
    // Near the optimum: within a few times the chi2 of the true poses.
    assert!(chi2_lago < 3.0 * chi2_truth, "{chi2_lago} vs {chi2_truth}");
}

#[test]
fn disconnected_components_each_keep_their_anchor() {
    let a = spiral_2d(100, 2.0);
    let mut truth = PoseGraph2::new();
    for (id, v) in a.vertices() {
        truth.add_vertex(id, *v).unwrap();
        let shifted = Se2::new(-20.0, 3.0, 2.5).compose(&v.pose);
        truth
            .add_vertex(NodeId(id.0 + 1000), Vertex::new(shifted))
            .unwrap();
    }
    truth
        .add_vertex(NodeId(5000), Vertex::new(Se2::new(1.0, 2.0, 3.0)))
        .unwrap();
    for (_, e) in a.edges() {
        truth.add_edge(*e).unwrap();
        let (f, t) = (e.from.0 + 1000, e.to.0 + 1000);
        add_exact_edge(&mut truth, f, t, e.information);
    }
    let mut g = scrambled(
        &truth,
        &[NodeId(0), NodeId(1000), NodeId(5000)],
        Se2::identity(),
    );
    let info = lago(&mut g);
    assert_eq!(info.components, 3);
    assert_eq!(info.anchors, vec![NodeId(0), NodeId(1000), NodeId(5000)]);
    assert_eq!(info.vertices_set, 198);
    assert!(max_pose_error(&g, &truth) < 1e-9);
}

#[test]
fn graphs_without_edges_are_unchanged() {
    let mut g = PoseGraph2::new();
    assert_eq!(lago(&mut g).components, 0);
    for k in 0..4 {
        g.add_vertex(NodeId(k), Vertex::new(Se2::new(k as f64, 0.0, 0.1)))
            .unwrap();
    }
    let before = g.clone();
    let info = lago(&mut g);
    assert_eq!((info.vertices_set, info.components), (0, 4));
    assert_eq!(g, before);
}

#[test]
fn negative_heading_information_is_an_error_and_leaves_the_graph_unchanged() {
    let mut g = spiral_2d(20, 1.0);
    let id = g.edges().nth(3).map(|(id, _)| id).unwrap();
    g.edge_mut(id).unwrap().information = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
    let mut scrambled = scrambled(&g, &[NodeId(0)], Se2::identity());
    let before = scrambled.clone();
    let err = initialize_lago(&mut scrambled, &LagoParams::default()).unwrap_err();
    assert!(
        matches!(err, InitError::InvalidInformation { edge, .. } if edge == id),
        "{err}"
    );
    assert_eq!(scrambled, before);
}

#[test]
fn a_bridge_without_information_is_a_solver_error_not_a_panic() {
    let mut g = PoseGraph2::new();
    for k in 0..3 {
        g.add_vertex(NodeId(k), Vertex::new(Se2::identity()))
            .unwrap();
    }
    for (f, t) in [(0, 1), (1, 2)] {
        g.add_edge(Edge {
            from: NodeId(f),
            to: NodeId(t),
            measurement: Se2::new(1.0, 0.0, 0.1),
            information: if f == 1 {
                Matrix3::zeros()
            } else {
                Matrix3::identity()
            },
            kind: EdgeKind::Odometry,
        })
        .unwrap();
    }
    let before = g.clone();
    let err = initialize_lago(&mut g, &LagoParams::default()).unwrap_err();
    assert!(matches!(err, InitError::LinearSolve { .. }), "{err}");
    assert_eq!(g, before);
}

fn arbitrary_graph() -> impl Strategy<Value = PoseGraph2> {
    let poses = proptest::collection::vec((-50.0f64..50.0, -50.0f64..50.0, -10.0f64..10.0), 40);
    let extra = proptest::collection::vec((0usize..40, 0usize..40), 0..60);
    let parents = proptest::collection::vec(0usize..40, 40);
    (3usize..40, poses, extra, parents).prop_map(|(n, poses, extra, parents)| {
        let mut g = PoseGraph2::new();
        for (k, (x, y, t)) in poses.iter().take(n).enumerate() {
            g.add_vertex(NodeId(3 * k as u64), Vertex::new(Se2::new(*x, *y, *t)))
                .unwrap();
        }
        let info = Matrix3::new(5.0, 1.0, 0.5, 1.0, 4.0, 0.0, 0.5, 0.0, 9.0);
        // A random spanning tree (random parent among earlier vertices, random direction),
        // then random extra edges.
        for (k, parent) in parents.iter().enumerate().take(n).skip(1) {
            let p = parent % k;
            let (f, t) = if k % 2 == 0 { (p, k) } else { (k, p) };
            add_exact_edge(&mut g, 3 * f as u64, 3 * t as u64, info);
        }
        for (a, b) in extra {
            let (a, b) = (a % n, b % n);
            if a != b {
                add_exact_edge(&mut g, 3 * a as u64, 3 * b as u64, info);
            }
        }
        g
    })
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 64,
        failure_persistence: Some(Box::new(proptest::test_runner::FileFailurePersistence::WithSource("regressions"))),
        ..ProptestConfig::default()
    })]
    #[test]
    fn exact_random_graphs_are_recovered(truth in arbitrary_graph()) {
        let mut g = scrambled(&truth, &[NodeId(0)], Se2::new(0.5, -0.5, 3.0));
        initialize_lago(&mut g, &LagoParams::default()).unwrap();
        prop_assert!(max_pose_error(&g, &truth) < 1e-8, "{}", max_pose_error(&g, &truth));
        let mut g = scrambled(&truth, &[NodeId(0)], Se2::new(0.5, -0.5, 3.0));
        initialize_odometry(&mut g).unwrap();
        prop_assert!(max_pose_error(&g, &truth) < 1e-8);
    }
}
