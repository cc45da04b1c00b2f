//! Chordal relaxation on synthetic 3D graphs.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::{add_exact_edge, add_noise, helix_3d, max_pose_error, scrambled};
use mapmerge_geometry::{LieGroup, Se3};
use mapmerge_init::{
    initialize_chordal, initialize_odometry, ChordalParams, InitError, RotationWeighting,
};
use mapmerge_posegraph::{NodeId, PoseGraph3, Vertex};
use nalgebra::{Matrix6, UnitQuaternion, Vector3, Vector6};
use proptest::prelude::*;

fn chordal(g: &mut PoseGraph3) -> mapmerge_init::InitInfo {
    initialize_chordal(g, &ChordalParams::default()).unwrap()
}

fn far_pose() -> Se3 {
    Se3::new(
        UnitQuaternion::from_euler_angles(2.0, -1.0, 3.0),
        Vector3::new(5.0, -3.0, 1.0),
    )
}

#[test]
fn exact_helix_is_recovered_with_every_weighting() {
    let truth = helix_3d(300, 4.0);
    for weighting in [
        RotationWeighting::Information,
        RotationWeighting::Trace,
        RotationWeighting::Unit,
    ] {
        let mut g = scrambled(&truth, &[NodeId(0)], far_pose());
        let info = initialize_chordal(
            &mut g,
            &ChordalParams {
                rotation_weighting: weighting,
            },
        )
        .unwrap();
        assert_eq!(info.vertices_set, 299);
        assert_eq!(info.anchors, vec![NodeId(0)]);
        let err = max_pose_error(&g, &truth);
        assert!(err < 1e-9, "{weighting:?}: max pose error {err}");
        assert!(g.chi2() < 1e-12, "{weighting:?}: chi2 {}", g.chi2());
    }
}

#[test]
fn fixed_vertices_anchor_the_estimate_and_are_not_written() {
    let mut truth = helix_3d(150, 2.0);
    for id in [30, 120] {
        truth.vertex_mut(NodeId(id)).unwrap().fixed = true;
    }
    let mut g = scrambled(&truth, &[], Se3::identity());
    let info = chordal(&mut g);
    assert_eq!(info.anchors, vec![NodeId(30)]);
    assert_eq!(info.vertices_set, 148);
    for id in [30, 120] {
        assert_eq!(
            g.vertex(NodeId(id)).unwrap().pose,
            truth.vertex(NodeId(id)).unwrap().pose
        );
    }
    assert!(max_pose_error(&g, &truth) < 1e-9);
}

#[test]
fn noisy_measurements_give_a_close_estimate_better_than_odometry() {
    let truth = helix_3d(400, 5.0);
    let mut noisy = truth.clone();
    add_noise(
        &mut noisy,
        Vector6::new(0.01, 0.01, 0.01, 0.03, 0.03, 0.03),
        11,
    );
    let mut g = scrambled(&noisy, &[NodeId(0)], Se3::identity());
    chordal(&mut g);
    let mut odo = scrambled(&noisy, &[NodeId(0)], Se3::identity());
    initialize_odometry(&mut odo).unwrap();
    let (err_chordal, err_odo) = (max_pose_error(&g, &truth), max_pose_error(&odo, &truth));
    let (chi2_chordal, chi2_odo, chi2_truth) = (g.chi2(), odo.chi2(), noisy.chi2());
    println!("chordal: err {err_chordal:.3} chi2 {chi2_chordal:.1}; odometry: err {err_odo:.3} chi2 {chi2_odo:.1}; truth chi2 {chi2_truth:.1}");
    assert!(err_chordal < 1.0, "{err_chordal}");
    assert!(err_chordal < 0.5 * err_odo);
    assert!(chi2_chordal < 0.05 * chi2_odo);
    assert!(
        chi2_chordal < 3.0 * chi2_truth,
        "{chi2_chordal} vs {chi2_truth}"
    );
}

#[test]
fn disconnected_graphs_and_graphs_without_edges() {
    let mut g = PoseGraph3::new();
    assert_eq!(chordal(&mut g).components, 0);
    for k in 0..6 {
        let pose = Se3::new(
            UnitQuaternion::from_euler_angles(0.3 * k as f64, 1.0, -0.5 * k as f64),
            Vector3::new(k as f64, 2.0, -1.0),
        );
        g.add_vertex(NodeId(k), Vertex::new(pose)).unwrap();
    }
    let before = g.clone();
    let info = chordal(&mut g);
    assert_eq!((info.vertices_set, info.components), (0, 6));
    assert_eq!(g, before);

    // Two triangles {0, 1, 2} and {3, 4, 5}.
    let truth = g.clone();
    for (f, t) in [(0, 1), (1, 2), (2, 0), (4, 3), (4, 5), (3, 5)] {
        add_exact_edge(&mut g, f, t, Matrix6::identity());
    }
    let with_edges = g.clone();
    let mut g = scrambled(&with_edges, &[NodeId(0), NodeId(3)], Se3::identity());
    let info = chordal(&mut g);
    assert_eq!(info.components, 2);
    assert_eq!(info.anchors, vec![NodeId(0), NodeId(3)]);
    assert_eq!(info.vertices_set, 4);
    assert!(max_pose_error(&g, &truth) < 1e-9);
}

#[test]
fn negative_rotation_information_is_an_error_and_leaves_the_graph_unchanged() {
    let truth = helix_3d(30, 1.0);
    let mut g = scrambled(&truth, &[NodeId(0)], Se3::identity());
    let id = g.edges().nth(5).map(|(id, _)| id).unwrap();
    g.edge_mut(id).unwrap().information = -Matrix6::identity();
    let before = g.clone();
    let err = initialize_chordal(&mut g, &ChordalParams::default()).unwrap_err();
    assert!(
        matches!(err, InitError::InvalidInformation { edge, .. } if edge == id),
        "{err}"
    );
    assert_eq!(g, before);
}

fn arbitrary_graph() -> impl Strategy<Value = PoseGraph3> {
    let poses = proptest::collection::vec(
        (
            proptest::array::uniform3(-3.2f64..3.2),
            proptest::array::uniform3(-20.0f64..20.0),
        ),
        30,
    );
    let extra = proptest::collection::vec((0usize..30, 0usize..30), 0..40);
    let parents = proptest::collection::vec(0usize..30, 30);
    (3usize..30, poses, extra, parents).prop_map(|(n, poses, extra, parents)| {
        let mut g = PoseGraph3::new();
        for (k, (r, t)) in poses.iter().take(n).enumerate() {
            let pose = Se3::new(
                UnitQuaternion::from_scaled_axis(Vector3::from(*r)),
                Vector3::from(*t),
            );
            g.add_vertex(NodeId(2 * k as u64 + 1), Vertex::new(pose))
                .unwrap();
        }
        let info = Matrix6::from_diagonal(&Vector6::new(30.0, 20.0, 10.0, 5.0, 6.0, 7.0));
        for (k, parent) in parents.iter().enumerate().take(n).skip(1) {
            let p = parent % k;
            let (f, t) = if k % 2 == 0 { (p, k) } else { (k, p) };
            add_exact_edge(&mut g, 2 * f as u64 + 1, 2 * t as u64 + 1, info);
        }
        for (a, b) in extra {
            let (a, b) = (a % n, b % n);
            if a != b {
                add_exact_edge(&mut g, 2 * a as u64 + 1, 2 * b as u64 + 1, info);
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
        let mut g = scrambled(&truth, &[NodeId(1)], Se3::identity());
        initialize_chordal(&mut g, &ChordalParams::default()).unwrap();
        prop_assert!(max_pose_error(&g, &truth) < 1e-8, "{}", max_pose_error(&g, &truth));
        let mut g = scrambled(&truth, &[NodeId(1)], Se3::identity());
        initialize_odometry(&mut g).unwrap();
        prop_assert!(max_pose_error(&g, &truth) < 1e-8);
    }
}
