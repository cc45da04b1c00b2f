//! Every structural edit can be undone exactly (property tests on random graphs).
#![allow(clippy::unwrap_used)]

use std::collections::BTreeSet;

use mapmerge_geometry::{LieGroup, Se2, Se3};
use mapmerge_posegraph::{
    Edge, EdgeKind, GraphError, NodeId, PoseGraph, PoseGraph2, PoseGraph3, SessionId, Vertex,
    VertexMeta,
};
use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector3};
use proptest::prelude::*;

fn se2() -> impl Strategy<Value = Se2> {
    (-50.0..50.0f64, -50.0..50.0f64, -3.1..3.1f64).prop_map(|(x, y, t)| Se2::new(x, y, t))
}

fn se3() -> impl Strategy<Value = Se3> {
    (
        -3.0..3.0f64,
        -1.5..1.5f64,
        -3.0..3.0f64,
        -50.0..50.0f64,
        -50.0..50.0f64,
        -5.0..5.0f64,
    )
        .prop_map(|(r, p, y, a, b, c)| {
            Se3::new(
                UnitQuaternion::from_euler_angles(r, p, y),
                Vector3::new(a, b, c),
            )
        })
}

/// A graph with ids `first..first + n`, a chain of odometry and some loops and priors.
fn graph<G: LieGroup<D>, const D: usize>(
    poses: Vec<G>,
    loops: Vec<(usize, usize)>,
    first: u64,
    session: u32,
) -> PoseGraph<G, D> {
    let mut g = PoseGraph::<G, D>::new();
    let n = poses.len();
    for (i, p) in poses.iter().enumerate() {
        let mut v = Vertex::new(*p);
        v.meta = VertexMeta {
            session: SessionId(session),
            stamp_secs: Some(i as f64),
            ..Default::default()
        };
        v.fixed = i == 0;
        g.add_vertex(NodeId(first + i as u64), v).unwrap();
    }
    let id = |i: usize| NodeId(first + i as u64);
    let info = nalgebra::SMatrix::<f64, D, D>::identity();
    for i in 1..n {
        let z = poses[i - 1].between(&poses[i]);
        g.add_edge(Edge {
            from: id(i - 1),
            to: id(i),
            measurement: z,
            information: info,
            kind: EdgeKind::Odometry,
        })
        .unwrap();
    }
    for (a, b) in loops {
        let (a, b) = (a % n, b % n);
        let edge = if a == b {
            Edge {
                from: id(a),
                to: id(a),
                measurement: poses[a],
                information: info,
                kind: EdgeKind::Prior,
            }
        } else {
            Edge {
                from: id(a),
                to: id(b),
                measurement: poses[a].between(&poses[b]),
                information: info,
                kind: EdgeKind::Loop,
            }
        };
        g.add_edge(edge).unwrap();
    }
    g
}

fn check_union_undo<G: LieGroup<D>, const D: usize>(
    a: PoseGraph<G, D>,
    b: PoseGraph<G, D>,
    bridge: G,
) -> Result<(), TestCaseError> {
    let mut merged = a.clone();
    let from = *a.vertices().next().map(|(id, _)| id).as_ref().unwrap();
    let to = *b.vertices().last().map(|(id, _)| id).as_ref().unwrap();
    let connecting = [Edge {
        from,
        to,
        measurement: bridge,
        information: nalgebra::SMatrix::identity(),
        kind: EdgeKind::Merge,
    }];
    let record = merged.union(&b, &connecting).unwrap();
    prop_assert_eq!(merged.num_vertices(), a.num_vertices() + b.num_vertices());
    prop_assert_eq!(merged.num_edges(), a.num_edges() + b.num_edges() + 1);
    prop_assert_eq!(merged.connected_components().len(), 1);
    let removed = merged.undo_union(&record);
    prop_assert_eq!(&merged, &a, "undo_union restores the first graph exactly");
    prop_assert_eq!(removed.num_vertices(), b.num_vertices());
    prop_assert_eq!(removed.num_edges(), b.num_edges());
    // A clash of ids changes nothing.
    let mut clash = a.clone();
    prop_assert!(matches!(
        clash.union(&a, &[]),
        Err(GraphError::DuplicateVertex(_))
    ));
    prop_assert_eq!(&clash, &a);
    Ok(())
}

fn check_remove_restore<G: LieGroup<D>, const D: usize>(
    g: PoseGraph<G, D>,
    pick: usize,
) -> Result<(), TestCaseError> {
    let ids: Vec<NodeId> = g.vertices().map(|(id, _)| id).collect();
    let id = ids[pick % ids.len()];
    let mut h = g.clone();
    let removed = h.remove_vertex(id).unwrap();
    prop_assert!(!h.contains_vertex(id));
    prop_assert!(h.edges().all(|(_, e)| e.from != id && e.to != id));
    h.restore_vertex(removed).unwrap();
    prop_assert_eq!(&h, &g);
    Ok(())
}

fn check_reanchor_undo<G: LieGroup<D>, const D: usize>(
    g: PoseGraph<G, D>,
    new_from_old: G,
) -> Result<(), TestCaseError> {
    let mut h = g.clone();
    let chi2 = g.chi2();
    let record = h.reanchor(&new_from_old);
    // Relative measurements still agree: chi2 is unchanged up to rounding.
    prop_assert!((h.chi2() - chi2).abs() < 1e-6 * (1.0 + chi2));
    h.undo_reanchor(&record);
    prop_assert_eq!(&h, &g, "undo_reanchor restores poses bit for bit");
    Ok(())
}

fn check_subgraph<G: LieGroup<D>, const D: usize>(
    g: PoseGraph<G, D>,
    keep_every: usize,
) -> Result<(), TestCaseError> {
    let keep: BTreeSet<NodeId> = g
        .vertices()
        .map(|(id, _)| id)
        .step_by(keep_every.max(1))
        .collect();
    let sub = g.subgraph(&keep);
    prop_assert_eq!(sub.num_vertices(), keep.len());
    for (eid, e) in sub.edges() {
        prop_assert!(keep.contains(&e.from) && keep.contains(&e.to));
        prop_assert_eq!(g.edge(eid), Some(e));
    }
    let expected = g
        .edges()
        .filter(|(_, e)| keep.contains(&e.from) && keep.contains(&e.to))
        .count();
    prop_assert_eq!(sub.num_edges(), expected);
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn planar_edits_undo_exactly(
        pa in prop::collection::vec(se2(), 2..30),
        pb in prop::collection::vec(se2(), 2..30),
        la in prop::collection::vec((0usize..100, 0usize..100), 0..10),
        lb in prop::collection::vec((0usize..100, 0usize..100), 0..10),
        bridge in se2(), anchor in se2(), pick in 0usize..100, every in 1usize..5,
    ) {
        let a: PoseGraph2 = graph(pa, la, 0, 0);
        let b: PoseGraph2 = graph(pb, lb, 1000, 1);
        check_union_undo(a.clone(), b, bridge)?;
        check_remove_restore(a.clone(), pick)?;
        check_reanchor_undo(a.clone(), anchor)?;
        check_subgraph(a, every)?;
    }

    #[test]
    fn spatial_edits_undo_exactly(
        pa in prop::collection::vec(se3(), 2..20),
        pb in prop::collection::vec(se3(), 2..20),
        la in prop::collection::vec((0usize..100, 0usize..100), 0..8),
        bridge in se3(), anchor in se3(), pick in 0usize..100,
    ) {
        let a: PoseGraph3 = graph(pa, la, 0, 0);
        let b: PoseGraph3 = graph(pb, vec![], 500, 1);
        check_union_undo(a.clone(), b, bridge)?;
        check_remove_restore(a.clone(), pick)?;
        check_reanchor_undo(a, anchor)?;
    }
}

#[test]
fn components_and_bad_edges() {
    let mut g = PoseGraph2::new();
    for i in 0..6 {
        g.add_vertex(NodeId(i), Vertex::new(Se2::new(i as f64, 0.0, 0.0)))
            .unwrap();
    }
    let info = Matrix3::identity();
    let z = Se2::new(1.0, 0.0, 0.0);
    g.add_edge(Edge {
        from: NodeId(0),
        to: NodeId(1),
        measurement: z,
        information: info,
        kind: EdgeKind::Odometry,
    })
    .unwrap();
    g.add_edge(Edge {
        from: NodeId(3),
        to: NodeId(4),
        measurement: z,
        information: info,
        kind: EdgeKind::Odometry,
    })
    .unwrap();
    assert_eq!(
        g.connected_components(),
        vec![
            vec![NodeId(0), NodeId(1)],
            vec![NodeId(2)],
            vec![NodeId(3), NodeId(4)],
            vec![NodeId(5)]
        ]
    );
    let missing = Edge {
        from: NodeId(0),
        to: NodeId(9),
        measurement: z,
        information: info,
        kind: EdgeKind::Loop,
    };
    assert_eq!(
        g.add_edge(missing),
        Err(GraphError::MissingVertex(NodeId(9)))
    );
    let self_loop = Edge {
        from: NodeId(2),
        to: NodeId(2),
        measurement: z,
        information: info,
        kind: EdgeKind::Loop,
    };
    assert!(matches!(
        g.add_edge(self_loop),
        Err(GraphError::BadEdge { .. })
    ));
    let bad_prior = Edge {
        from: NodeId(2),
        to: NodeId(3),
        measurement: z,
        information: info,
        kind: EdgeKind::Prior,
    };
    assert!(matches!(
        g.add_edge(bad_prior),
        Err(GraphError::BadEdge { .. })
    ));
    assert_eq!(
        g.add_vertex(NodeId(1), Vertex::new(z)),
        Err(GraphError::DuplicateVertex(NodeId(1)))
    );
    let _ = Matrix6::<f64>::identity();
}
