//! Edge pruning (iRobot, Sec. 4.2): bounded edges, connectivity kept, exactly undoable.
#![allow(clippy::unwrap_used)]

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::{edge_information_ln_det, Edge, EdgeKind, NodeId, PoseGraph2, Vertex};
use nalgebra::Matrix3;
use proptest::prelude::*;

/// Two chains (two components) with loops of varied information and a prior on each chain.
fn graph(n: usize, loops: &[(usize, usize, f64)]) -> PoseGraph2 {
    let mut g = PoseGraph2::new();
    for i in 0..2 * n {
        let pose = Se2::new(i as f64 * 0.7, (i % 5) as f64, 0.1 * i as f64);
        g.add_vertex(NodeId(i as u64), Vertex::new(pose)).unwrap();
    }
    let edge = |g: &PoseGraph2, a: usize, b: usize, scale: f64, kind| Edge {
        from: NodeId(a as u64),
        to: NodeId(b as u64),
        measurement: g
            .vertex(NodeId(a as u64))
            .unwrap()
            .pose
            .between(&g.vertex(NodeId(b as u64)).unwrap().pose),
        information: Matrix3::identity() * scale,
        kind,
    };
    for chain in 0..2 {
        for i in 1..n {
            let e = edge(
                &g,
                chain * n + i - 1,
                chain * n + i,
                10.0,
                EdgeKind::Odometry,
            );
            g.add_edge(e).unwrap();
        }
        let first = chain * n;
        let mut prior = edge(&g, first, first, 1e6, EdgeKind::Prior);
        prior.measurement = g.vertex(NodeId(first as u64)).unwrap().pose;
        g.add_edge(prior).unwrap();
    }
    for &(a, b, scale) in loops {
        // Loops stay within a chain.
        let chain = a % 2;
        let (a, b) = (chain * n + a % n, chain * n + b % n);
        if a != b {
            let e = edge(&g, a, b, scale, EdgeKind::Loop);
            g.add_edge(e).unwrap();
        }
    }
    g
}

proptest! {
    #[test]
    fn pruning_bounds_edges_keeps_components_and_undoes_exactly(
        n in 3usize..30,
        loops in proptest::collection::vec((0usize..60, 0usize..60, 0.01f64..100.0), 0..80),
        c in 0.5f64..3.0,
    ) {
        let original = graph(n, &loops);
        let mut pruned = original.clone();
        let removed = pruned.prune_edges(c);
        // Connectivity: the same components.
        prop_assert_eq!(pruned.connected_components(), original.connected_components());
        // Bounded, unless the forest and the priors need more.
        let limit = (c * pruned.num_vertices() as f64).floor() as usize;
        let forest_and_priors = pruned.num_vertices() - original.connected_components().len() + 2;
        prop_assert!(pruned.num_edges() <= limit.max(forest_and_priors),
            "{} edges, limit {}, forest and priors {}", pruned.num_edges(), limit, forest_and_priors);
        // Priors are never removed, and the removed edges come least informative first.
        prop_assert!(removed.iter().all(|(_, e)| e.kind != EdgeKind::Prior));
        for pair in removed.windows(2) {
            prop_assert!(edge_information_ln_det(&pair[0].1) <= edge_information_ln_det(&pair[1].1));
        }
        // Undo: inserting the removed edges back restores the graph exactly.
        for (id, edge) in removed.into_iter().rev() {
            pruned.insert_edge_with_id(id, edge).unwrap();
        }
        prop_assert_eq!(pruned, original);
    }
}

#[test]
fn the_least_informative_loop_goes_first() {
    // A chain of 4 with two loops 0–3: the weak one is removed, the strong one kept.
    let mut g = graph(4, &[(0, 2, 100.0), (0, 3, 0.01), (1, 3, 50.0)]);
    let weak = g
        .edges()
        .find(|(_, e)| e.kind == EdgeKind::Loop && e.information[(0, 0)] < 1.0)
        .map(|(id, _)| id)
        .unwrap();
    let before = g.num_edges();
    let removed = g.prune_edges((before - 1) as f64 / g.num_vertices() as f64);
    assert_eq!(removed.len(), 1);
    assert_eq!(removed[0].0, weak);
    // Nothing to do within the limit.
    assert!(g.prune_edges(10.0).is_empty());
}
