//! Node marginalisation by a Chow–Liu tree (iRobot Sec. 4.2; Ta et al. 2018), checked against
//! the exact Schur complement of the linearised graph: exact with two neighbours, exact on
//! every tree edge's pairwise marginal, and within a bound of the exact marginal covariance
//! (Kullback–Leibler divergence) otherwise, closer than another spanning tree and than
//! dropping the edges.
#![allow(clippy::unwrap_used)]

use std::collections::BTreeMap;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::{Edge, EdgeKind, GraphError, NodeId, PoseGraph2, Vertex};
use nalgebra::{DMatrix, Matrix3};
use proptest::prelude::*;

/// The information matrix of `graph` linearised at its poses, one 3×3 block per vertex in id
/// order (vertex `gauge` left out: held fixed).
fn information(graph: &PoseGraph2, gauge: NodeId) -> (DMatrix<f64>, Vec<NodeId>) {
    let ids: Vec<NodeId> = graph
        .vertices()
        .map(|(id, _)| id)
        .filter(|id| *id != gauge)
        .collect();
    let index: BTreeMap<NodeId, usize> = ids.iter().enumerate().map(|(k, id)| (*id, k)).collect();
    let mut h = DMatrix::zeros(3 * ids.len(), 3 * ids.len());
    for (_, edge) in graph.edges() {
        let (from, to) = (
            graph.vertex(edge.from).unwrap().pose,
            graph.vertex(edge.to).unwrap().pose,
        );
        let (_, j_from, j_to) = edge
            .measurement
            .inverse()
            .relative_error_jacobians(&from, &to);
        let blocks = [(index.get(&edge.from), j_from), (index.get(&edge.to), j_to)];
        for (p, jp) in &blocks {
            for (q, jq) in &blocks {
                if let (Some(p), Some(q)) = (p, q) {
                    let term = jp.transpose() * edge.information * jq;
                    let mut view = h.view_mut((3 * **p, 3 * **q), (3, 3));
                    view += term;
                }
            }
        }
    }
    (h, ids)
}

/// The covariance of every vertex but `gauge` and `removed` with `removed` marginalised out
/// exactly (Schur complement), in id order.
fn exact_covariance(graph: &PoseGraph2, gauge: NodeId, removed: NodeId) -> DMatrix<f64> {
    let (h, ids) = information(graph, gauge);
    let k = ids.iter().position(|id| *id == removed).unwrap();
    let keep: Vec<usize> = (0..ids.len())
        .filter(|i| *i != k)
        .flat_map(|i| 3 * i..3 * i + 3)
        .collect();
    let select = |rows: &[usize], cols: &[usize]| {
        DMatrix::from_fn(rows.len(), cols.len(), |r, c| h[(rows[r], cols[c])])
    };
    let v: Vec<usize> = (3 * k..3 * k + 3).collect();
    let schur = select(&keep, &keep)
        - select(&keep, &v) * select(&v, &v).try_inverse().unwrap() * select(&v, &keep);
    schur.try_inverse().unwrap()
}

/// The covariance of every vertex but `gauge`, in id order.
fn covariance(graph: &PoseGraph2, gauge: NodeId) -> Option<DMatrix<f64>> {
    information(graph, gauge).0.try_inverse()
}

/// KL(N(0, p) ‖ N(0, q)).
fn kl(p: &DMatrix<f64>, q: &DMatrix<f64>) -> f64 {
    let q_inv = q.clone().try_inverse().unwrap();
    let ln_det = |m: &DMatrix<f64>| {
        m.clone()
            .cholesky()
            .unwrap()
            .l()
            .diagonal()
            .map(|d| 2.0 * d.ln())
            .sum()
    };
    0.5 * ((&q_inv * p).trace() - p.nrows() as f64 + ln_det(q) - ln_det(p))
}

fn se2() -> impl Strategy<Value = (f64, f64, f64)> {
    (0.3f64..1.5, -0.4f64..0.4, -0.6f64..0.6)
}

fn information_matrix() -> impl Strategy<Value = Matrix3<f64>> {
    (1.0f64..3.0, 1.0f64..3.0, 0.5f64..2.5, -0.5f64..0.5).prop_map(|(a, b, c, r)| {
        let l = Matrix3::new(
            10f64.powf(a),
            0.0,
            0.0,
            r * 10.0,
            10f64.powf(b),
            0.0,
            0.0,
            r,
            10f64.powf(c),
        );
        l * l.transpose() * 0.01 + Matrix3::identity()
    })
}

/// A noisy chain of `steps` with loop edges `(a, b)` (indices modulo the chain), every edge
/// with its own information and a measurement a little off the estimate.
fn random_graph(
    steps: &[(f64, f64, f64)],
    loops: &[(usize, usize)],
    infos: &[Matrix3<f64>],
) -> PoseGraph2 {
    let mut g = PoseGraph2::new();
    let mut pose = Se2::identity();
    g.add_vertex(NodeId(0), Vertex::new(pose)).unwrap();
    for (k, (dx, dy, dt)) in steps.iter().enumerate() {
        pose = pose.compose(&Se2::new(*dx, *dy, *dt));
        g.add_vertex(NodeId(k as u64 + 1), Vertex::new(pose))
            .unwrap();
    }
    let n = steps.len() + 1;
    let pairs = (0..n - 1).map(|k| (k, k + 1)).chain(
        loops
            .iter()
            .map(|(a, b)| (a % n, b % n))
            .filter(|(a, b)| a != b),
    );
    for (k, (a, b)) in pairs.enumerate() {
        let (from, to) = (NodeId(a as u64), NodeId(b as u64));
        let truth = g
            .vertex(from)
            .unwrap()
            .pose
            .between(&g.vertex(to).unwrap().pose);
        let noise = Se2::new(0.01 * (k as f64).sin(), 0.01 * (k as f64).cos(), 0.002);
        g.add_edge(Edge {
            from,
            to,
            measurement: truth.compose(&noise),
            information: infos[k % infos.len()],
            kind: if b == a + 1 {
                EdgeKind::Odometry
            } else {
                EdgeKind::Loop
            },
        })
        .unwrap();
    }
    g
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn the_tree_stays_close_to_the_exact_marginal(
        steps in prop::collection::vec(se2(), 4..9),
        loops in prop::collection::vec((0usize..20, 0usize..20), 0..6),
        infos in prop::collection::vec(information_matrix(), 1..6),
        pick in 1usize..100,
    ) {
        let graph = random_graph(&steps, &loops, &infos);
        let n = graph.num_vertices();
        let removed = NodeId(1 + (pick % (n - 2)) as u64);
        let gauge = NodeId(if removed.0 == 0 { 1 } else { 0 });
        let exact = exact_covariance(&graph, gauge, removed);
        let neighbours = {
            let mut set: Vec<NodeId> = graph
                .incident_edges(removed)
                .into_iter()
                .map(|id| graph.edge(id).unwrap())
                .map(|e| if e.from == removed { e.to } else { e.from })
                .collect();
            set.sort();
            set.dedup();
            set
        };
        let mut approximated = graph.clone();
        let result = approximated.marginalize_vertex(removed).unwrap();
        prop_assert_eq!(result.added.len(), neighbours.len() - 1);
        prop_assert!(result.added.iter().all(|(_, e)| e.kind == EdgeKind::Marginal));
        prop_assert!(approximated.vertex(removed).is_none());
        let approx = covariance(&approximated, gauge).unwrap();
        let divergence = kl(&exact, &approx);
        if neighbours.len() == 2 {
            // One tree edge: exact.
            let scale = exact.amax();
            prop_assert!((&exact - &approx).amax() <= 1e-7 * scale, "{}", (&exact - &approx).amax());
        }
        // The bound: within 4 nats of the exact marginal over the whole graph. Over 1000 such
        // graphs (information ratios up to 10⁴ between edges) the divergence had median 0.15
        // and maximum 2.2 with three neighbours, maximum 2.4 with four and 3.7 with five
        // (docs/benchmarks.md, "The lifelong store").
        prop_assert!(divergence <= 4.0, "KL {divergence} with {} neighbours", neighbours.len());
        // Dropping the vertex's edges instead is further (when it even leaves the graph
        // connected).
        let mut dropped = graph.clone();
        dropped.remove_vertex(removed).unwrap();
        if let Some(drop) = covariance(&dropped, gauge).filter(|c| c.clone().cholesky().is_some()) {
            prop_assert!(divergence <= kl(&exact, &drop) + 1e-9);
        }
    }
}

/// A star: one vertex joined to four others, nothing else.
fn star() -> PoseGraph2 {
    let mut g = PoseGraph2::new();
    let poses = [
        Se2::new(0.0, 0.0, 0.0),
        Se2::new(2.0, 0.1, 0.3),
        Se2::new(-1.0, 1.5, -0.4),
        Se2::new(0.5, -2.0, 1.2),
        Se2::new(3.0, 2.0, 2.5),
    ];
    for (k, pose) in poses.iter().enumerate() {
        g.add_vertex(NodeId(k as u64), Vertex::new(*pose)).unwrap();
    }
    for (k, scale) in [(1, 100.0), (2, 5.0), (3, 40.0), (4, 1.0)] {
        g.add_edge(Edge {
            from: NodeId(0),
            to: NodeId(k),
            measurement: poses[0].between(&poses[k as usize]),
            information: Matrix3::new(
                scale,
                0.1,
                0.0,
                0.1,
                2.0 * scale,
                0.0,
                0.0,
                0.0,
                0.5 * scale,
            ),
            kind: EdgeKind::Loop,
        })
        .unwrap();
    }
    g
}

#[test]
fn every_tree_edge_keeps_its_pairs_exact_marginal_and_the_tree_beats_a_chain() {
    let graph = star();
    let gauge = NodeId(1);
    let exact = exact_covariance(&graph, gauge, NodeId(0));
    let mut approximated = graph.clone();
    let result = approximated.marginalize_vertex(NodeId(0)).unwrap();
    assert_eq!(result.added.len(), 3);
    let approx = covariance(&approximated, gauge).unwrap();
    // The tree holds all four remaining vertices: the covariance of each tree edge's relative
    // pose is the exact one.
    let relative = |cov: &DMatrix<f64>, a: NodeId, b: NodeId| {
        let index = |id: NodeId| (id.0 as usize).checked_sub(2); // gauge 1 and vertex 0 gone
        let pose = |id: NodeId| approximated.vertex(id).unwrap().pose;
        let z = pose(a).between(&pose(b));
        let (_, ja, jb) = z.inverse().relative_error_jacobians(&pose(a), &pose(b));
        let block = |i: Option<usize>, j: Option<usize>| match (i, j) {
            (Some(i), Some(j)) => cov.fixed_view::<3, 3>(3 * i, 3 * j).into_owned(),
            _ => Matrix3::zeros(),
        };
        let (ia, ib) = (index(a), index(b));
        ja * block(ia, ia) * ja.transpose()
            + ja * block(ia, ib) * jb.transpose()
            + jb * block(ib, ia) * ja.transpose()
            + jb * block(ib, ib) * jb.transpose()
    };
    for (_, edge) in &result.added {
        let (a, b) = (
            relative(&exact, edge.from, edge.to),
            relative(&approx, edge.from, edge.to),
        );
        assert!((a - b).amax() <= 1e-9 * a.amax(), "{a} vs {b}");
    }
    // Kruskal's tree is the closest: a chain over the same vertices is further.
    let mut chain = graph.clone();
    chain.remove_vertex(NodeId(0)).unwrap();
    for (a, b) in [(1u64, 2u64), (2, 3), (3, 4)] {
        let (a, b) = (NodeId(a), NodeId(b));
        let covariance_ab = relative(&exact, a, b);
        chain
            .add_edge(Edge {
                from: a,
                to: b,
                measurement: graph
                    .vertex(a)
                    .unwrap()
                    .pose
                    .between(&graph.vertex(b).unwrap().pose),
                information: covariance_ab.try_inverse().unwrap(),
                kind: EdgeKind::Marginal,
            })
            .unwrap();
    }
    let chain_kl = kl(&exact, &covariance(&chain, gauge).unwrap());
    let tree_kl = kl(&exact, &approx);
    assert!(tree_kl <= chain_kl, "tree {tree_kl} vs chain {chain_kl}");
}

#[test]
fn fixed_vertices_and_priors_are_refused_and_leaves_just_go() {
    let mut graph = star();
    graph.vertex_mut(NodeId(0)).unwrap().fixed = true;
    let before = graph.clone();
    assert!(matches!(
        graph.marginalize_vertex(NodeId(0)),
        Err(GraphError::NotMarginalizable { .. })
    ));
    assert_eq!(graph, before);
    graph.vertex_mut(NodeId(0)).unwrap().fixed = false;
    let prior = Edge {
        from: NodeId(0),
        to: NodeId(0),
        measurement: Se2::identity(),
        information: Matrix3::identity(),
        kind: EdgeKind::Prior,
    };
    graph.add_edge(prior).unwrap();
    let before = graph.clone();
    assert!(graph.marginalize_vertex(NodeId(0)).is_err());
    assert_eq!(graph, before);
    // A leaf (one neighbour) goes with its edge and adds nothing.
    let result = graph.marginalize_vertex(NodeId(4)).unwrap();
    assert!(result.added.is_empty());
    assert_eq!(result.removed.edges.len(), 1);
}
