//! False loop closures, vertigo's "random outliers" pattern.
//!
//! Sünderhauf & Protzel, "Switchable constraints for robust pose graph SLAM", IROS 2012, Sec. V;
//! the generator is vertigo's `datasets/generateDataset.py` (`--outliers N`, no grouping, not
//! local): two random vertices `v1 < v2` that are not consecutive, a random relative pose
//! (x, y ~ N(0, 0.3 m), yaw ~ N(0, 10°); in 3D also z, roll, pitch), a fixed information matrix.
//! Here the information matrix is copied from a randomly chosen loop closure of the graph
//! itself, so that a false edge weighs as much as a true one whatever the dataset's scale.

use mapmerge_posegraph::{Edge, EdgeId, EdgeKind, NodeId, PoseGraph};
use mapmerge_sim::seeded;
use nalgebra::SMatrix;
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::pose::EvalPose;
use crate::EvalError;

/// How the relative pose of a false loop closure is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum FalseLoopMeasurement {
    /// vertigo's distribution: translation components ~ N(0, `sigma_t_m`), rotation angles
    /// ~ N(0, `sigma_r_rad`). A false edge then claims that two far-apart poses nearly coincide
    /// (perceptual aliasing).
    Vertigo {
        /// Standard deviation of each translation component, m (vertigo: 0.3).
        sigma_t_m: f64,
        /// Standard deviation of each rotation angle, rad (vertigo: 10° = 0.1745).
        sigma_r_rad: f64,
    },
    /// Translation uniform in `±half_extent_m` per axis, rotation uniform (yaw in ±π, or a
    /// uniformly random 3D rotation).
    Uniform {
        /// Half the side of the translation box, m (e.g. 10).
        half_extent_m: f64,
    },
}

impl Default for FalseLoopMeasurement {
    fn default() -> Self {
        FalseLoopMeasurement::Vertigo {
            sigma_t_m: 0.3,
            sigma_r_rad: 10f64.to_radians(),
        }
    }
}

/// Parameters of [`add_false_loop_closures_with`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FalseLoopParams {
    /// Distribution of the false relative poses (default: vertigo's, 0.3 m / 10°).
    pub measurement: FalseLoopMeasurement,
}

/// True for the edges counted as loop closures: every relative edge that is not odometry
/// (kinds `Loop` and `Merge`).
pub fn is_loop_closure<G, const D: usize>(edge: &Edge<G, D>) -> bool {
    matches!(edge.kind, EdgeKind::Loop | EdgeKind::Merge)
}

/// Number of loop closures in `graph` (see [`is_loop_closure`]).
pub fn count_loop_closures<G, const D: usize>(graph: &PoseGraph<G, D>) -> usize
where
    G: mapmerge_geometry::LieGroup<D>,
{
    graph.edges().filter(|(_, e)| is_loop_closure(e)).count()
}

/// How many false loop closures make them the share `fraction` of all loop closures:
/// `round(fraction / (1 − fraction) · true_loops)`; 0.5 gives as many false as true ones,
/// 0.1 one false per nine true. Fails unless `0 ≤ fraction < 1`.
pub fn false_loop_count(fraction: f64, true_loops: usize) -> Result<usize, EvalError> {
    if !(fraction.is_finite() && (0.0..1.0).contains(&fraction)) {
        return Err(EvalError::InvalidFraction(fraction));
    }
    let n = (fraction / (1.0 - fraction) * true_loops as f64).round();
    // `n` is finite and non-negative; saturate absurdly large requests.
    Ok(if n >= usize::MAX as f64 {
        usize::MAX
    } else {
        n as usize
    })
}

/// Adds false loop closures with the default [`FalseLoopParams`] (vertigo's distribution);
/// see [`add_false_loop_closures_with`].
pub fn add_false_loop_closures<G, const D: usize>(
    graph: &mut PoseGraph<G, D>,
    fraction: f64,
    seed: u64,
) -> Result<Vec<EdgeId>, EvalError>
where
    G: EvalPose<D>,
{
    add_false_loop_closures_with(graph, fraction, &FalseLoopParams::default(), seed)
}

/// Appends false loop closures (kind `Loop`) to `graph` so that they make up the share
/// `fraction` of all loop closures afterwards (count: [`false_loop_count`]) and returns their
/// ids, which follow every existing edge id (in a written file: edge lines with index ≥ the
/// original edge count). Each joins two random distinct vertices whose ids are not consecutive
/// (`from < to`, so a reader never mistakes it for odometry), measures a random relative pose
/// drawn from `params.measurement` and copies the information matrix of a random existing loop
/// closure (of a random relative edge if the graph has no loop closure). The same graph,
/// fraction and seed always give the same edges (ChaCha8). Nothing changes on error.
pub fn add_false_loop_closures_with<G, const D: usize>(
    graph: &mut PoseGraph<G, D>,
    fraction: f64,
    params: &FalseLoopParams,
    seed: u64,
) -> Result<Vec<EdgeId>, EvalError>
where
    G: EvalPose<D>,
{
    let true_loops = count_loop_closures(graph);
    let count = false_loop_count(fraction, true_loops)?;
    check_measurement(&params.measurement)?;
    if count == 0 {
        return Ok(Vec::new());
    }
    let ids: Vec<NodeId> = graph.vertices().map(|(id, _)| id).collect();
    let has_pair = match ids.as_slice() {
        [a, b] => a.0.abs_diff(b.0) != 1,
        list => list.len() >= 3,
    };
    if !has_pair {
        return Err(EvalError::NoVertexPair {
            vertices: ids.len(),
        });
    }
    let mut templates: Vec<SMatrix<f64, D, D>> = graph
        .edges()
        .filter(|(_, e)| is_loop_closure(e))
        .map(|(_, e)| e.information)
        .collect();
    if templates.is_empty() {
        templates = graph
            .edges()
            .filter(|(_, e)| !e.is_prior())
            .map(|(_, e)| e.information)
            .collect();
    }
    if templates.is_empty() {
        return Err(EvalError::NoTemplateEdge);
    }

    let mut rng = seeded(seed);
    let mut new_edges = Vec::with_capacity(count);
    for _ in 0..count {
        // 1. Two distinct, non-consecutive vertices (vertigo: `while v1 == v2`, `v2 != v1 + 1`).
        let (from, to) = loop {
            let a = ids[rng.random_range(0..ids.len())];
            let b = ids[rng.random_range(0..ids.len())];
            if a != b && a.0.abs_diff(b.0) != 1 {
                break if a < b { (a, b) } else { (b, a) };
            }
        };
        // 2. A random relative pose.
        let measurement = match params.measurement {
            FalseLoopMeasurement::Vertigo {
                sigma_t_m,
                sigma_r_rad,
            } => G::sample_vertigo(&mut rng, sigma_t_m, sigma_r_rad),
            FalseLoopMeasurement::Uniform { half_extent_m } => {
                G::sample_uniform(&mut rng, half_extent_m)
            }
        };
        // 3. The information matrix of an existing loop closure.
        let information = templates[rng.random_range(0..templates.len())];
        new_edges.push(Edge {
            from,
            to,
            measurement,
            information,
            kind: EdgeKind::Loop,
        });
    }
    let mut added = Vec::with_capacity(count);
    for edge in new_edges {
        match graph.add_edge(edge) {
            Ok(id) => added.push(id),
            Err(err) => {
                for id in added {
                    let _ = graph.remove_edge(id);
                }
                return Err(err.into());
            }
        }
    }
    Ok(added)
}

fn check_measurement(m: &FalseLoopMeasurement) -> Result<(), EvalError> {
    let bad = |field, value: f64| EvalError::InvalidParams {
        field,
        reason: format!("{value} must be finite and >= 0"),
    };
    match *m {
        FalseLoopMeasurement::Vertigo {
            sigma_t_m,
            sigma_r_rad,
        } => {
            if !(sigma_t_m.is_finite() && sigma_t_m >= 0.0) {
                return Err(bad("sigma_t_m", sigma_t_m));
            }
            if !(sigma_r_rad.is_finite() && sigma_r_rad >= 0.0) {
                return Err(bad("sigma_r_rad", sigma_r_rad));
            }
        }
        FalseLoopMeasurement::Uniform { half_extent_m } => {
            if !(half_extent_m.is_finite() && half_extent_m >= 0.0) {
                return Err(bad("half_extent_m", half_extent_m));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;
    use mapmerge_geometry::{LieGroup, Se2, Se3};
    use mapmerge_posegraph::{PoseGraph2, PoseGraph3, Vertex};
    use nalgebra::{Matrix3, Matrix6};
    use proptest::prelude::*;

    /// A chain of `n` poses with loop closures i -> i + 5 for every 5th i.
    fn chain2(n: u64) -> PoseGraph2 {
        let mut g = PoseGraph2::new();
        for i in 0..n {
            g.add_vertex(NodeId(i), Vertex::new(Se2::new(i as f64, 0.0, 0.0)))
                .unwrap();
        }
        for i in 1..n {
            let e = Edge {
                from: NodeId(i - 1),
                to: NodeId(i),
                measurement: Se2::new(1.0, 0.0, 0.0),
                information: Matrix3::identity(),
                kind: EdgeKind::Odometry,
            };
            g.add_edge(e).unwrap();
        }
        for i in (0..n.saturating_sub(5)).step_by(5) {
            let e = Edge {
                from: NodeId(i),
                to: NodeId(i + 5),
                measurement: Se2::new(5.0, 0.0, 0.0),
                information: Matrix3::identity() * 7.0,
                kind: EdgeKind::Loop,
            };
            g.add_edge(e).unwrap();
        }
        g
    }

    #[test]
    fn count_formula() {
        assert_eq!(false_loop_count(0.0, 100).unwrap(), 0);
        assert_eq!(false_loop_count(0.5, 100).unwrap(), 100);
        assert_eq!(false_loop_count(0.1, 90).unwrap(), 10);
        assert_eq!(false_loop_count(0.1, 1954).unwrap(), 217); // 1954 / 9 = 217.1
        assert_eq!(false_loop_count(0.75, 10).unwrap(), 30);
        for bad in [-0.1, 1.0, 1.5, f64::NAN, f64::INFINITY] {
            assert!(matches!(
                false_loop_count(bad, 10),
                Err(EvalError::InvalidFraction(_))
            ));
        }
    }

    #[test]
    fn appends_false_loops_after_existing_edges() {
        let mut g = chain2(100);
        let before = g.num_edges();
        let true_loops = count_loop_closures(&g);
        assert_eq!(true_loops, 19);
        let ids = add_false_loop_closures(&mut g, 0.5, 42).unwrap();
        assert_eq!(ids.len(), 19);
        assert_eq!(g.num_edges(), before + 19);
        for (k, id) in ids.iter().enumerate() {
            assert_eq!(id.0, (before + k) as u64);
            let e = g.edge(*id).unwrap();
            assert_eq!(e.kind, EdgeKind::Loop);
            assert!(e.from < e.to, "{e:?}");
            assert!(e.to.0 - e.from.0 >= 2, "consecutive: {e:?}");
            assert_eq!(e.information, Matrix3::identity() * 7.0);
        }
        // Fraction of all loop closures that is false.
        let all = count_loop_closures(&g) as f64;
        assert!((ids.len() as f64 / all - 0.5).abs() < 1e-12);
    }

    #[test]
    fn reproducible_with_seed_and_different_across_seeds() {
        let base = chain2(60);
        let (mut a, mut b, mut c) = (base.clone(), base.clone(), base.clone());
        add_false_loop_closures(&mut a, 0.3, 9).unwrap();
        add_false_loop_closures(&mut b, 0.3, 9).unwrap();
        add_false_loop_closures(&mut c, 0.3, 10).unwrap();
        assert_eq!(a, b);
        assert_ne!(a, c);
    }

    #[test]
    fn uses_odometry_information_without_loops_and_fails_without_edges() {
        let mut g = PoseGraph2::new();
        for i in 0..4 {
            g.add_vertex(NodeId(i), Vertex::new(Se2::identity()))
                .unwrap();
        }
        // No loop closures: zero false ones for any fraction.
        assert!(add_false_loop_closures(&mut g, 0.5, 1).unwrap().is_empty());
        let mut two = PoseGraph2::new();
        two.add_vertex(NodeId(0), Vertex::new(Se2::identity()))
            .unwrap();
        two.add_vertex(NodeId(1), Vertex::new(Se2::identity()))
            .unwrap();
        let e = Edge {
            from: NodeId(0),
            to: NodeId(1),
            measurement: Se2::identity(),
            information: Matrix3::identity(),
            kind: EdgeKind::Merge,
        };
        two.add_edge(e).unwrap();
        let before = two.clone();
        assert_eq!(
            add_false_loop_closures(&mut two, 0.5, 1),
            Err(EvalError::NoVertexPair { vertices: 2 })
        );
        assert_eq!(two, before);
    }

    #[test]
    fn uniform_measurements_stay_in_their_box() {
        let mut g = chain2(200);
        let params = FalseLoopParams {
            measurement: FalseLoopMeasurement::Uniform {
                half_extent_m: 10.0,
            },
        };
        let ids = add_false_loop_closures_with(&mut g, 0.8, &params, 3).unwrap();
        assert_eq!(ids.len(), 156);
        let mut max_abs = 0.0f64;
        for id in ids {
            let z = g.edge(id).unwrap().measurement;
            assert!(z.x_m.abs() <= 10.0 && z.y_m.abs() <= 10.0);
            max_abs = max_abs.max(z.x_m.abs());
        }
        assert!(max_abs > 5.0, "uniform samples should spread over the box");
        let bad = FalseLoopParams {
            measurement: FalseLoopMeasurement::Uniform {
                half_extent_m: -1.0,
            },
        };
        assert!(add_false_loop_closures_with(&mut g, 0.1, &bad, 3).is_err());
    }

    #[test]
    fn spatial_graphs_get_unit_quaternions() {
        let mut g = PoseGraph3::new();
        for i in 0..10 {
            g.add_vertex(NodeId(i), Vertex::new(Se3::identity()))
                .unwrap();
        }
        let e = Edge {
            from: NodeId(0),
            to: NodeId(9),
            measurement: Se3::identity(),
            information: Matrix6::identity(),
            kind: EdgeKind::Loop,
        };
        g.add_edge(e).unwrap();
        for params in [
            FalseLoopParams::default(),
            FalseLoopParams {
                measurement: FalseLoopMeasurement::Uniform {
                    half_extent_m: 10.0,
                },
            },
        ] {
            let mut h = g.clone();
            let ids = add_false_loop_closures_with(&mut h, 0.9, &params, 5).unwrap();
            assert_eq!(ids.len(), 9);
            for id in ids {
                let z = h.edge(id).unwrap().measurement;
                assert!((z.rotation.quaternion().norm() - 1.0).abs() < 1e-12);
                assert!(z.is_finite());
            }
        }
    }

    proptest! {
        #[test]
        fn count_matches_fraction(true_loops in 0usize..5000, fraction in 0.0f64..0.95) {
            let n = false_loop_count(fraction, true_loops).unwrap();
            let exact = fraction / (1.0 - fraction) * true_loops as f64;
            prop_assert!((n as f64 - exact).abs() <= 0.5 + 1e-9);
        }

        #[test]
        fn every_false_edge_is_valid(n in 3u64..40, fraction in 0.05f64..0.9, seed in any::<u64>()) {
            let mut g = chain2(n.max(6) + 5);
            let before = g.num_edges() as u64;
            let ids = add_false_loop_closures(&mut g, fraction, seed).unwrap();
            for id in ids {
                prop_assert!(id.0 >= before);
                let e = g.edge(id).unwrap();
                prop_assert!(e.from != e.to && e.to.0 != e.from.0 + 1 && e.from.0 != e.to.0 + 1);
            }
        }
    }
}
