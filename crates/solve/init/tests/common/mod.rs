//! Shared test helpers: loading the public graphs and building synthetic ones.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use mapmerge_geometry::{LieGroup, Se2, Se3};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph, PoseGraph2, PoseGraph3, Vertex};
use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector3};

pub fn max_pose_error<G: LieGroup<D>, const D: usize>(
    a: &PoseGraph<G, D>,
    b: &PoseGraph<G, D>,
) -> f64 {
    a.vertices()
        .map(|(id, v)| {
            let other = b.vertex(id).expect("same ids").pose;
            v.pose.local(&other).norm()
        })
        .fold(0.0, f64::max)
}

/// A copy of `truth` with exact measurements kept and every non-fixed vertex but `keep` moved
/// to `start`.
pub fn scrambled<G: LieGroup<D>, const D: usize>(
    truth: &PoseGraph<G, D>,
    keep: &[NodeId],
    start: G,
) -> PoseGraph<G, D> {
    let mut g = truth.clone();
    for (id, v) in g.vertices_mut() {
        if !v.fixed && !keep.contains(&id) {
            v.pose = start;
        }
    }
    g
}

/// Adds an edge with the exact measurement `from⁻¹ · to` of the graph's current poses.
pub fn add_exact_edge<G: LieGroup<D>, const D: usize>(
    g: &mut PoseGraph<G, D>,
    from: u64,
    to: u64,
    information: nalgebra::SMatrix<f64, D, D>,
) {
    let a = g.vertex(NodeId(from)).unwrap().pose;
    let b = g.vertex(NodeId(to)).unwrap().pose;
    g.add_edge(Edge {
        from: NodeId(from),
        to: NodeId(to),
        measurement: a.between(&b),
        information,
        kind: if to == from + 1 {
            EdgeKind::Odometry
        } else {
            EdgeKind::Loop
        },
    })
    .unwrap();
}

/// A planar trajectory of `n` poses driving `laps` counter-clockwise circles (so the unwrapped
/// heading grows by 2π per lap) while drifting outwards, with exact odometry, a loop closure
/// from every pose to the one a lap earlier, and some reversed and long-range edges.
pub fn spiral_2d(n: u64, laps: f64) -> PoseGraph2 {
    let mut g = PoseGraph2::new();
    let per_lap = (n as f64 / laps).round() as u64;
    for k in 0..n {
        let heading = 2.0 * std::f64::consts::PI * k as f64 / per_lap as f64;
        let radius = 5.0 + 0.02 * k as f64;
        let pose = Se2::new(
            radius * heading.cos() + 1.0,
            radius * heading.sin() - 2.0,
            heading + std::f64::consts::FRAC_PI_2 + 0.1 * (k as f64).sin(),
        );
        g.add_vertex(NodeId(k), Vertex::new(pose)).unwrap();
    }
    let info = Matrix3::new(40.0, 2.0, 1.0, 2.0, 30.0, -1.5, 1.0, -1.5, 200.0);
    for k in 0..n - 1 {
        if k % 7 == 3 {
            add_exact_edge(&mut g, k + 1, k, info); // reversed odometry
        } else {
            add_exact_edge(&mut g, k, k + 1, info);
        }
    }
    let loop_info = Matrix3::from_diagonal(&Vector3::new(10.0, 10.0, 50.0));
    for k in per_lap..n {
        if k % 3 == 0 {
            add_exact_edge(&mut g, k, k - per_lap, loop_info);
        }
    }
    for k in (0..n).step_by(37) {
        let other = (k * 7919 + 13) % n;
        if other != k {
            add_exact_edge(&mut g, other, k, loop_info);
        }
    }
    g
}

/// A 3D trajectory of `n` poses: a helix with tumbling orientation (rotations far from the
/// identity and accumulating), exact odometry, loop closures between turns, some reversed edges.
pub fn helix_3d(n: u64, turns: f64) -> PoseGraph3 {
    let mut g = PoseGraph3::new();
    let per_turn = (n as f64 / turns).round() as u64;
    for k in 0..n {
        let a = 2.0 * std::f64::consts::PI * k as f64 / per_turn as f64;
        let t = Vector3::new(
            8.0 * a.cos(),
            8.0 * a.sin(),
            0.3 * k as f64 / per_turn as f64,
        );
        let r = UnitQuaternion::from_euler_angles(0.4 * (0.7 * a).sin(), 0.3 * a.cos(), a)
            * UnitQuaternion::from_euler_angles(0.0, 0.05 * k as f64, 0.0);
        g.add_vertex(NodeId(k), Vertex::new(Se3::new(r, t)))
            .unwrap();
    }
    let mut info = Matrix6::from_diagonal(&nalgebra::Vector6::new(
        400.0, 300.0, 200.0, 100.0, 120.0, 80.0,
    ));
    info[(3, 4)] = 5.0;
    info[(4, 3)] = 5.0;
    info[(0, 3)] = 3.0;
    info[(3, 0)] = 3.0;
    for k in 0..n - 1 {
        if k % 5 == 2 {
            add_exact_edge(&mut g, k + 1, k, info);
        } else {
            add_exact_edge(&mut g, k, k + 1, info);
        }
    }
    let loop_info = Matrix6::identity() * 50.0;
    for k in per_turn..n {
        if k % 4 == 1 {
            add_exact_edge(&mut g, k - per_turn, k, loop_info);
        }
    }
    g
}

/// A standard normal sample (Box–Muller).
pub fn gaussian(rng: &mut impl rand::Rng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// Replaces every relative measurement `z` by `z · Exp(σ ⊙ n)`, `n` standard normal.
pub fn add_noise<G: LieGroup<D>, const D: usize>(
    g: &mut PoseGraph<G, D>,
    sigma: nalgebra::SVector<f64, D>,
    seed: u64,
) {
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let ids: Vec<_> = g.edges().map(|(id, _)| id).collect();
    for id in ids {
        let e = g.edge_mut(id).unwrap();
        if e.is_prior() {
            continue;
        }
        let xi = nalgebra::SVector::<f64, D>::from_fn(|k, _| sigma[k] * gaussian(&mut rng));
        e.measurement = e.measurement.retract(&xi);
    }
}
