//! The optimizer on synthetic graphs with known answers.
#![allow(clippy::unwrap_used)]

use mapmerge_geometry::{LieGroup, Se2, Se3};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph, PoseGraph2, PoseGraph3, Vertex};
use mapmerge_solve::{
    marginal_covariances, optimize, optimize_gnc, Algorithm, GncParams, OptimizerParams,
    RobustKernel, Termination,
};
use nalgebra::{Matrix3, Matrix6, SMatrix, UnitQuaternion, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A square-lattice walk with loop closures between poses that are close in space.
fn truth_2d(n: usize, rng: &mut ChaCha8Rng) -> Vec<Se2> {
    let mut poses = vec![Se2::identity()];
    for i in 1..n {
        let turn = if i % 10 == 0 {
            if rng.random_bool(0.5) {
                core::f64::consts::FRAC_PI_2
            } else {
                -core::f64::consts::FRAC_PI_2
            }
        } else {
            0.0
        };
        let last = poses[i - 1];
        poses.push(last.compose(&Se2::new(1.0, 0.0, turn)));
    }
    poses
}

fn noisy<G: LieGroup<D>, const D: usize>(z: G, sigma: f64, rng: &mut ChaCha8Rng) -> G {
    let xi = SMatrix::<f64, D, 1>::from_fn(|_, _| sigma * (rng.random::<f64>() * 2.0 - 1.0) * 1.7);
    z.compose(&G::exp(&xi))
}

fn build<G: LieGroup<D>, const D: usize>(
    truth: &[G],
    close: impl Fn(&G, &G) -> bool,
    sigma: f64,
    rng: &mut ChaCha8Rng,
) -> PoseGraph<G, D> {
    let mut g = PoseGraph::<G, D>::new();
    let info = SMatrix::<f64, D, D>::identity() / (sigma * sigma).max(1e-12);
    let mut est = truth[0];
    g.add_vertex(NodeId(0), Vertex::new(est)).unwrap();
    for i in 1..truth.len() {
        let z = noisy(truth[i - 1].between(&truth[i]), sigma, rng);
        est = est.compose(&z);
        g.add_vertex(NodeId(i as u64), Vertex::new(est)).unwrap();
        g.add_edge(Edge {
            from: NodeId(i as u64 - 1),
            to: NodeId(i as u64),
            measurement: z,
            information: info,
            kind: EdgeKind::Odometry,
        })
        .unwrap();
    }
    for i in 0..truth.len() {
        for j in (i + 5)..truth.len() {
            if close(&truth[i], &truth[j]) {
                let z = noisy(truth[i].between(&truth[j]), sigma, rng);
                g.add_edge(Edge {
                    from: NodeId(i as u64),
                    to: NodeId(j as u64),
                    measurement: z,
                    information: info,
                    kind: EdgeKind::Loop,
                })
                .unwrap();
            }
        }
    }
    g
}

fn near_2d(a: &Se2, b: &Se2) -> bool {
    (a.translation() - b.translation()).norm() < 1.01
}

#[test]
fn exact_measurements_recover_truth_2d() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let truth = truth_2d(300, &mut rng);
    let mut g: PoseGraph2 = build(&truth, near_2d, 0.0, &mut rng);
    // Corrupt the initial guess.
    for (i, (_, v)) in g.vertices_mut().enumerate() {
        if i > 0 {
            v.pose = v.pose.compose(&Se2::new(0.05, -0.03, 0.02));
        }
    }
    for algorithm in [Algorithm::LevenbergMarquardt, Algorithm::GaussNewton] {
        let mut g = g.clone();
        let params = OptimizerParams {
            algorithm,
            ..Default::default()
        };
        let info = optimize(&mut g, &params).unwrap();
        assert!(
            info.final_chi2 < 1e-10 * info.initial_chi2.max(1.0),
            "{algorithm:?}: {info:?}"
        );
        assert_eq!(info.gauge_fixed, vec![NodeId(0)]);
        for (id, v) in g.vertices() {
            let t = truth[id.0 as usize];
            assert!((v.pose.translation() - t.translation()).norm() < 1e-6);
        }
    }
}

#[test]
fn noisy_graph_converges_and_chi2_matches_graph_chi2_2d() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let truth = truth_2d(500, &mut rng);
    let mut g: PoseGraph2 = build(&truth, near_2d, 0.02, &mut rng);
    let info = optimize(&mut g, &OptimizerParams::default()).unwrap();
    assert!(info.termination.is_success());
    assert!(info.final_chi2 < info.initial_chi2);
    assert!((g.chi2() - info.final_chi2).abs() < 1e-9 * info.final_chi2.max(1.0));
    // A minimum: no small perturbation of a vertex lowers chi2.
    let best = g.chi2();
    for id in [NodeId(17), NodeId(250), NodeId(499)] {
        for k in 0..3 {
            let mut h = g.clone();
            let mut xi = Vector3::zeros();
            xi[k] = 1e-4;
            let v = h.vertex_mut(id).unwrap();
            v.pose = v.pose.retract(&xi);
            assert!(h.chi2() >= best - 1e-9);
        }
    }
}

fn truth_3d(n: usize) -> Vec<Se3> {
    // A helix: loops come back near earlier poses in x/y at different heights.
    (0..n)
        .map(|i| {
            let a = i as f64 * 0.2;
            Se3::new(
                UnitQuaternion::from_euler_angles(0.0, 0.0, a + core::f64::consts::FRAC_PI_2),
                Vector3::new(5.0 * a.cos(), 5.0 * a.sin(), 0.05 * i as f64),
            )
        })
        .collect()
}

#[test]
fn exact_and_noisy_3d() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let truth = truth_3d(200);
    let near = |a: &Se3, b: &Se3| (a.translation_m - b.translation_m).norm() < 2.5;
    let mut g: PoseGraph3 = build(&truth, near, 0.0, &mut rng);
    for (i, (_, v)) in g.vertices_mut().enumerate() {
        if i > 0 {
            v.pose = v
                .pose
                .retract(&Vector6::new(0.01, -0.02, 0.01, 0.05, 0.02, -0.03));
        }
    }
    let info = optimize(&mut g, &OptimizerParams::default()).unwrap();
    assert!(info.final_chi2 < 1e-10, "{info:?}");
    for (id, v) in g.vertices() {
        assert!((v.pose.translation_m - truth[id.0 as usize].translation_m).norm() < 1e-6);
    }
    let mut noisy_graph: PoseGraph3 = build(&truth, near, 0.01, &mut rng);
    let info = optimize(&mut noisy_graph, &OptimizerParams::default()).unwrap();
    assert!(info.termination.is_success(), "{info:?}");
    assert!((noisy_graph.chi2() - info.final_chi2).abs() < 1e-9 * info.final_chi2);
}

#[test]
fn robust_kernels_reduce_the_pull_of_a_false_loop() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let truth = truth_2d(200, &mut rng);
    let clean: PoseGraph2 = build(&truth, near_2d, 0.01, &mut rng);
    let mut reference = clean.clone();
    optimize(&mut reference, &OptimizerParams::default()).unwrap();
    let mut corrupted = clean.clone();
    corrupted
        .add_edge(Edge {
            from: NodeId(20),
            to: NodeId(150),
            measurement: Se2::new(0.5, 0.0, 0.0),
            information: Matrix3::identity() * 1e4,
            kind: EdgeKind::Loop,
        })
        .unwrap();
    let error = |g: &PoseGraph2| -> f64 {
        g.vertices()
            .map(|(id, v)| {
                (v.pose.translation() - reference.vertex(id).unwrap().pose.translation()).norm()
            })
            .fold(0.0, f64::max)
    };
    let mut plain = corrupted.clone();
    optimize(&mut plain, &OptimizerParams::default()).unwrap();
    let plain_error = error(&plain);
    assert!(
        plain_error > 1.0,
        "the false loop should distort plain least squares: {plain_error}"
    );
    for robust in [
        RobustKernel::Huber { delta: 3.4 },
        RobustKernel::Cauchy { c: 3.4 },
        RobustKernel::Dcs { phi: 1.0 },
    ] {
        let mut g = corrupted.clone();
        optimize(
            &mut g,
            &OptimizerParams {
                robust,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(
            error(&g) < plain_error,
            "{robust:?}: {} vs {plain_error}",
            error(&g)
        );
    }
    let mut g = corrupted.clone();
    let gnc = optimize_gnc(&mut g, &GncParams::default()).unwrap();
    let false_id = corrupted.edges().last().unwrap().0;
    assert!(gnc.rejected.contains(&false_id), "{:?}", gnc.rejected);
    assert!(gnc.rejected.len() <= 2, "{:?}", gnc.rejected);
    assert!(error(&g) < 0.05, "{}", error(&g));
}

#[test]
fn marginals_match_a_chain_with_known_covariance() {
    // A chain of odometry from a fixed origin: covariance grows; the last vertex of a 1-step
    // chain has exactly the edge covariance propagated.
    let mut g = PoseGraph2::new();
    let mut v0 = Vertex::new(Se2::identity());
    v0.fixed = true;
    g.add_vertex(NodeId(0), v0).unwrap();
    g.add_vertex(NodeId(1), Vertex::new(Se2::new(1.0, 0.0, 0.3)))
        .unwrap();
    let info = Matrix3::new(100.0, 0.0, 0.0, 0.0, 400.0, 0.0, 0.0, 0.0, 900.0);
    g.add_edge(Edge {
        from: NodeId(0),
        to: NodeId(1),
        measurement: Se2::new(1.0, 0.0, 0.3),
        information: info,
        kind: EdgeKind::Odometry,
    })
    .unwrap();
    let cov = marginal_covariances(&g, &[NodeId(0), NodeId(1)]).unwrap();
    assert_eq!(cov[0], Matrix3::zeros());
    // At the optimum the residual Jacobian wrt x1 is R(0)=I-ish; covariance = Ω⁻¹ in x1's frame.
    let expected = info.try_inverse().unwrap();
    assert!((cov[1] - expected).norm() < 1e-9, "{}", cov[1]);
    let g3 = PoseGraph3::new();
    assert!(marginal_covariances(&g3, &[]).is_err());
    let _ = Matrix6::<f64>::identity();
}

#[test]
fn numerical_failure_keeps_last_good_state() {
    // A vertex with no edges and not fixed gives a singular system.
    let mut g = PoseGraph2::new();
    g.add_vertex(NodeId(0), Vertex::new(Se2::identity()))
        .unwrap();
    g.add_vertex(NodeId(1), Vertex::new(Se2::new(1.0, 0.0, 0.0)))
        .unwrap();
    g.add_vertex(NodeId(2), Vertex::new(Se2::new(2.0, 0.0, 0.0)))
        .unwrap();
    g.add_edge(Edge {
        from: NodeId(0),
        to: NodeId(1),
        measurement: Se2::new(1.1, 0.0, 0.0),
        information: Matrix3::identity(),
        kind: EdgeKind::Odometry,
    })
    .unwrap();
    // Vertex 2 is its own component: gauge-fixed, so the problem is well posed.
    let info = optimize(&mut g, &OptimizerParams::default()).unwrap();
    assert!(info.gauge_fixed.contains(&NodeId(2)));
    assert!(info.final_chi2 < 1e-12);
    // Rank-deficient information: only x constrained.
    let mut h = PoseGraph2::new();
    h.add_vertex(NodeId(0), Vertex::new(Se2::identity()))
        .unwrap();
    h.add_vertex(NodeId(1), Vertex::new(Se2::new(1.0, 0.0, 0.0)))
        .unwrap();
    h.add_edge(Edge {
        from: NodeId(0),
        to: NodeId(1),
        measurement: Se2::new(1.5, 0.0, 0.0),
        information: Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        kind: EdgeKind::Odometry,
    })
    .unwrap();
    let before = h.clone();
    let info = optimize(
        &mut h,
        &OptimizerParams {
            algorithm: Algorithm::GaussNewton,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(
        matches!(info.termination, Termination::NumericalFailure(_)),
        "{info:?}"
    );
    assert_eq!(h, before, "the last good state (the input) is kept");
}
