//! Property tests: writing a random graph and reading it back yields the same graph, in both

#![allow(clippy::unwrap_used, clippy::expect_used)]
//! dimensions and both formats.

use mapmerge_geometry::{Se2, Se3};
use mapmerge_io::{format_graph, parse_graph, AnyGraph, GraphFormat};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph, PoseGraph2, PoseGraph3, Vertex};
use nalgebra::{Quaternion, SMatrix, UnitQuaternion, Vector3};
use proptest::prelude::*;
use proptest::sample::Index;

/// Finite numbers of very different magnitudes, to exercise the number formatting.
fn coordinate() -> impl Strategy<Value = f64> {
    prop_oneof![
        6 => -1e3..1e3_f64,
        1 => -1e-7..1e-7_f64,
        1 => -1e20..1e20_f64,
        1 => Just(0.0),
        1 => Just(-0.0),
    ]
}

fn vertex_ids() -> impl Strategy<Value = Vec<u64>> {
    let id = prop_oneof![4 => 0..200_u64, 1 => any::<u64>()];
    prop::collection::btree_set(id, 1..25).prop_map(|s| s.into_iter().collect())
}

/// A symmetric positive-definite matrix: `L Lᵀ + I`, symmetrised exactly.
fn information<const D: usize>() -> impl Strategy<Value = SMatrix<f64, D, D>> {
    prop::collection::vec(-10.0..10.0_f64, D * D).prop_map(|values| {
        let l = SMatrix::<f64, D, D>::from_fn(|i, j| if j <= i { values[i * D + j] } else { 0.0 });
        let m = l * l.transpose() + SMatrix::<f64, D, D>::identity();
        (m + m.transpose()) * 0.5
    })
}

fn se2() -> impl Strategy<Value = Se2> {
    (coordinate(), coordinate(), -4.0..4.0_f64).prop_map(|(x, y, t)| Se2::new(x, y, t))
}

fn se3() -> impl Strategy<Value = Se3> {
    let q = (-1.0..1.0_f64, -1.0..1.0_f64, -1.0..1.0_f64, -1.0..1.0_f64)
        .prop_filter("non-degenerate quaternion", |(a, b, c, d)| {
            a * a + b * b + c * c + d * d > 0.01
        });
    (q, coordinate(), coordinate(), coordinate()).prop_map(|((w, i, j, k), x, y, z)| {
        Se3::new(
            UnitQuaternion::new_normalize(Quaternion::new(w, i, j, k)),
            Vector3::new(x, y, z),
        )
    })
}

/// Edge endpoints as indices into the vertex list; equal endpoints become priors when allowed.
type EdgeSpec<G, const D: usize> = (Index, Index, G, SMatrix<f64, D, D>);

fn build<G: mapmerge_geometry::LieGroup<D>, const D: usize>(
    ids: &[u64],
    poses: &[(G, bool)],
    edges: &[EdgeSpec<G, D>],
    priors: bool,
) -> PoseGraph<G, D> {
    let mut g = PoseGraph::new();
    for (id, (pose, fixed)) in ids.iter().zip(poses) {
        let mut v = Vertex::new(*pose);
        v.fixed = *fixed;
        g.add_vertex(NodeId(*id), v).unwrap();
    }
    for (a, b, measurement, information) in edges {
        let (from, to) = (ids[a.index(ids.len())], ids[b.index(ids.len())]);
        let kind = if from == to {
            if !priors {
                continue;
            }
            EdgeKind::Prior
        } else if from.checked_add(1) == Some(to) {
            EdgeKind::Odometry
        } else {
            EdgeKind::Loop
        };
        let edge = Edge {
            from: NodeId(from),
            to: NodeId(to),
            measurement: *measurement,
            information: *information,
            kind,
        };
        g.add_edge(edge).unwrap();
    }
    g
}

fn planar_graph(priors: bool) -> impl Strategy<Value = PoseGraph2> {
    vertex_ids().prop_flat_map(move |ids| {
        let n = ids.len();
        let poses = prop::collection::vec((se2(), any::<bool>()), n);
        let edges = prop::collection::vec(
            (any::<Index>(), any::<Index>(), se2(), information::<3>()),
            0..40,
        );
        (Just(ids), poses, edges).prop_map(move |(ids, p, e)| build(&ids, &p, &e, priors))
    })
}

fn spatial_graph(priors: bool) -> impl Strategy<Value = PoseGraph3> {
    vertex_ids().prop_flat_map(move |ids| {
        let n = ids.len();
        let poses = prop::collection::vec((se3(), any::<bool>()), n);
        let edges = prop::collection::vec(
            (any::<Index>(), any::<Index>(), se3(), information::<6>()),
            0..30,
        );
        (Just(ids), poses, edges).prop_map(move |(ids, p, e)| build(&ids, &p, &e, priors))
    })
}

fn round_trip(graph: &AnyGraph, format: GraphFormat) -> (String, AnyGraph) {
    let text = format_graph(graph, format).unwrap();
    let loaded = parse_graph(&text, "roundtrip").unwrap_or_else(|e| panic!("{e}\n{text}"));
    assert_eq!(loaded.format, format);
    assert!(loaded.had_vertices);
    (text, loaded.graph)
}

proptest! {
    #[test]
    fn planar_g2o_round_trips_exactly(g in planar_graph(true)) {
        let graph = AnyGraph::Planar(g);
        let (text, back) = round_trip(&graph, GraphFormat::G2o);
        prop_assert_eq!(&back, &graph);
        prop_assert_eq!(format_graph(&back, GraphFormat::G2o).unwrap(), text);
    }

    #[test]
    fn spatial_g2o_round_trips_exactly(g in spatial_graph(true)) {
        let graph = AnyGraph::Spatial(g);
        let (text, back) = round_trip(&graph, GraphFormat::G2o);
        prop_assert_eq!(&back, &graph);
        prop_assert_eq!(format_graph(&back, GraphFormat::G2o).unwrap(), text);
    }

    #[test]
    fn planar_toro_round_trips_exactly_but_fixed_flags(mut g in planar_graph(false)) {
        // TORO has no FIX lines.
        for (_, v) in g.vertices_mut() {
            v.fixed = false;
        }
        let graph = AnyGraph::Planar(g);
        let (text, back) = round_trip(&graph, GraphFormat::Toro);
        prop_assert_eq!(&back, &graph);
        prop_assert_eq!(format_graph(&back, GraphFormat::Toro).unwrap(), text);
    }

    #[test]
    fn spatial_toro_round_trips_up_to_euler_rounding(g in spatial_graph(false)) {
        let (_, back) = round_trip(&AnyGraph::Spatial(g.clone()), GraphFormat::Toro);
        let AnyGraph::Spatial(back) = back else { panic!("3D graph read back as 2D") };
        prop_assert_eq!(back.num_vertices(), g.num_vertices());
        prop_assert_eq!(back.num_edges(), g.num_edges());
        let close = |a: &Se3, b: &Se3| {
            a.translation_m == b.translation_m && a.rotation.angle_to(&b.rotation) < 1e-9
        };
        for ((ia, va), (ib, vb)) in g.vertices().zip(back.vertices()) {
            prop_assert_eq!(ia, ib);
            prop_assert!(close(&va.pose, &vb.pose), "vertex {}: {:?} vs {:?}", ia, va.pose, vb.pose);
            prop_assert!(!vb.fixed);
        }
        for ((ia, ea), (ib, eb)) in g.edges().zip(back.edges()) {
            prop_assert_eq!(ia, ib);
            prop_assert_eq!((ea.from, ea.to, ea.kind), (eb.from, eb.to, eb.kind));
            prop_assert_eq!(ea.information, eb.information);
            prop_assert!(close(&ea.measurement, &eb.measurement), "edge {}", ia);
        }
    }
}

#[test]
fn toro_cannot_write_priors() {
    let mut g = PoseGraph2::new();
    g.add_vertex(NodeId(0), Vertex::new(Se2::new(0.0, 0.0, 0.0)))
        .unwrap();
    let prior = Edge {
        from: NodeId(0),
        to: NodeId(0),
        measurement: Se2::new(1.0, 0.0, 0.0),
        information: SMatrix::<f64, 3, 3>::identity(),
        kind: EdgeKind::Prior,
    };
    g.add_edge(prior).unwrap();
    let graph = AnyGraph::Planar(g);
    let err = format_graph(&graph, GraphFormat::Toro).unwrap_err();
    assert!(err.to_string().contains("prior"), "{err}");
    // g2o can, and reads it back as a prior.
    let (_, back) = round_trip(&graph, GraphFormat::G2o);
    assert_eq!(back, graph);
}

#[test]
fn non_finite_numbers_are_not_written() {
    let mut g = PoseGraph3::new();
    let mut pose = Se3::new(
        UnitQuaternion::identity(),
        Vector3::new(0.0, f64::INFINITY, 0.0),
    );
    g.add_vertex(NodeId(3), Vertex::new(pose)).unwrap();
    let err = format_graph(&AnyGraph::Spatial(g.clone()), GraphFormat::G2o).unwrap_err();
    assert!(err.to_string().contains("vertex 3"), "{err}");
    pose.translation_m.y = 0.0;
    g.vertex_mut(NodeId(3)).unwrap().pose = pose;
    assert!(format_graph(&AnyGraph::Spatial(g), GraphFormat::G2o).is_ok());
}
