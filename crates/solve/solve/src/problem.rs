//! A pose graph compiled into flat arrays for the optimizer: dense vertex indices, free-variable
//! slots, and per-edge residuals and Jacobians.

use mapmerge_geometry::LieGroup;
use mapmerge_posegraph::{EdgeId, EdgeKind, NodeId, PoseGraph};
use nalgebra::{SMatrix, SVector};
use rayon::prelude::*;

use crate::error::SolveError;
use crate::robust::RobustKernel;

/// Edges per rayon task when linearising; small graphs stay on one thread.
const EDGES_PER_TASK: usize = 2048;

/// One edge in index form.
#[derive(Clone, Debug)]
pub(crate) struct CompiledEdge<G, const D: usize> {
    pub id: EdgeId,
    pub kind: EdgeKind,
    /// Dense vertex index of `from` (equal to `to` for priors).
    pub from: u32,
    pub to: u32,
    pub is_prior: bool,
    /// `z⁻¹`, precomputed.
    pub measurement_inverse: G,
    pub information: SMatrix<f64, D, D>,
}

/// The linearisation of one edge: `r`, `J_from`, `J_to` and the edge's squared error.
#[derive(Clone, Copy, Debug)]
pub(crate) struct EdgeLinearization<const D: usize> {
    pub residual: SVector<f64, D>,
    pub jacobian_from: SMatrix<f64, D, D>,
    pub jacobian_to: SMatrix<f64, D, D>,
    pub chi2: f64,
}

/// The optimisation problem: poses by dense index, which of them are free, and the edges.
#[derive(Clone, Debug)]
pub(crate) struct Problem<G, const D: usize> {
    pub ids: Vec<NodeId>,
    pub poses: Vec<G>,
    /// `free_slot[v]` = column block of vertex `v`, or `u32::MAX` when held fixed.
    pub free_slot: Vec<u32>,
    pub num_free: usize,
    pub edges: Vec<CompiledEdge<G, D>>,
    /// Vertices the optimizer fixed to remove the gauge freedom.
    pub gauge_fixed: Vec<NodeId>,
}

pub(crate) const FIXED: u32 = u32::MAX;

impl<G: LieGroup<D>, const D: usize> Problem<G, D> {
    /// Compiles a graph. Components without a fixed vertex or a prior get their lowest id fixed.
    pub fn compile(graph: &PoseGraph<G, D>) -> Result<Self, SolveError> {
        let n = graph.num_vertices();
        if n == 0 {
            return Err(SolveError::EmptyGraph);
        }
        let mut ids = Vec::with_capacity(n);
        let mut poses = Vec::with_capacity(n);
        let mut fixed = Vec::with_capacity(n);
        for (id, v) in graph.vertices() {
            if !v.pose.is_finite() {
                return Err(SolveError::NonFinitePose(id));
            }
            ids.push(id);
            poses.push(v.pose);
            fixed.push(v.fixed);
        }
        // The graph lists its vertices in id order, so `ids` is sorted.
        debug_assert!(ids.windows(2).all(|w| w[0] < w[1]));
        let index_of = |id: &NodeId| ids.binary_search(id).ok().map(|i| i as u32);
        let mut edges = Vec::with_capacity(graph.num_edges());
        let mut anchored = fixed.clone();
        for (eid, e) in graph.edges() {
            let (Some(from), Some(to)) = (index_of(&e.from), index_of(&e.to)) else {
                return Err(SolveError::DanglingEdge(eid));
            };
            if !e.measurement.is_finite() || e.information.iter().any(|x| !x.is_finite()) {
                return Err(SolveError::NonFiniteEdge(eid));
            }
            if e.is_prior() {
                anchored[to as usize] = true;
            }
            edges.push(CompiledEdge {
                id: eid,
                kind: e.kind,
                from,
                to,
                is_prior: e.is_prior(),
                measurement_inverse: e.measurement.inverse(),
                information: e.information,
            });
        }
        // Gauge: one anchored vertex per connected component.
        let mut gauge_fixed = Vec::new();
        for component in graph.connected_components() {
            let has_anchor = component
                .iter()
                .any(|id| index_of(id).is_some_and(|i| anchored[i as usize]));
            if !has_anchor {
                if let Some(i) = component.first().and_then(index_of) {
                    fixed[i as usize] = true;
                    gauge_fixed.push(component[0]);
                }
            }
        }
        let mut free_slot = vec![FIXED; n];
        let mut num_free = 0usize;
        for (v, slot) in free_slot.iter_mut().enumerate() {
            if !fixed[v] {
                *slot = num_free as u32;
                num_free += 1;
            }
        }
        Ok(Self {
            ids,
            poses,
            free_slot,
            num_free,
            edges,
            gauge_fixed,
        })
    }

    /// Writes the poses back into the graph.
    pub fn write_back(&self, graph: &mut PoseGraph<G, D>) {
        for (id, pose) in self.ids.iter().zip(&self.poses) {
            if let Some(v) = graph.vertex_mut(*id) {
                v.pose = *pose;
            }
        }
    }

    /// Residual and Jacobians of one edge at `poses`: `r = coords(z⁻¹ · x_from⁻¹ · x_to)`
    /// ([`LieGroup::relative_error_jacobians`]), or `coords(z⁻¹ · x)` for a prior.
    #[inline]
    pub fn linearize_edge(edge: &CompiledEdge<G, D>, poses: &[G]) -> EdgeLinearization<D> {
        let x_to = &poses[edge.to as usize];
        let (residual, jacobian_from, jacobian_to) = if edge.is_prior {
            let error = edge.measurement_inverse.compose(x_to);
            (
                error.error_coordinates(),
                SMatrix::zeros(),
                error.error_coordinates_jacobian(),
            )
        } else {
            edge.measurement_inverse
                .relative_error_jacobians(&poses[edge.from as usize], x_to)
        };
        let chi2 = (residual.transpose() * edge.information * residual)[(0, 0)];
        EdgeLinearization {
            residual,
            jacobian_from,
            jacobian_to,
            chi2,
        }
    }

    /// Squared error of one edge at `poses`.
    #[inline]
    pub fn edge_chi2(edge: &CompiledEdge<G, D>, poses: &[G]) -> f64 {
        let x_to = &poses[edge.to as usize];
        let r = if edge.is_prior {
            edge.measurement_inverse.compose(x_to).error_coordinates()
        } else {
            edge.measurement_inverse
                .relative_error(&poses[edge.from as usize], x_to)
        };
        (r.transpose() * edge.information * r)[(0, 0)]
    }

    /// `(Σ w_e χ²_e, Σ w_e ρ(χ²_e))` at `poses`, with per-edge weights `w`.
    pub fn cost(&self, poses: &[G], weights: &[f64], kernel: &RobustKernel) -> (f64, f64) {
        let per_edge = |(edge, w): (&CompiledEdge<G, D>, &f64)| {
            if *w == 0.0 {
                return (0.0, 0.0);
            }
            let s = Self::edge_chi2(edge, poses);
            (w * s, w * kernel.cost(s))
        };
        let add = |a: (f64, f64), b: (f64, f64)| (a.0 + b.0, a.1 + b.1);
        if self.edges.len() < EDGES_PER_TASK {
            self.edges
                .iter()
                .zip(weights)
                .map(per_edge)
                .fold((0.0, 0.0), add)
        } else {
            self.edges
                .par_iter()
                .zip(weights.par_iter())
                .with_min_len(EDGES_PER_TASK)
                .map(per_edge)
                .reduce(|| (0.0, 0.0), add)
        }
    }

    /// Linearises every edge into `out` (same order as `edges`).
    pub fn linearize_all(&self, out: &mut Vec<EdgeLinearization<D>>) {
        let poses = &self.poses;
        out.clear();
        if self.edges.len() < EDGES_PER_TASK {
            out.extend(self.edges.iter().map(|e| Self::linearize_edge(e, poses)));
        } else {
            self.edges
                .par_iter()
                .with_min_len(EDGES_PER_TASK)
                .map(|e| Self::linearize_edge(e, poses))
                .collect_into_vec(out);
        }
    }

    /// Applies `x ← x · Exp(δ)` to every free vertex, writing into `out`.
    pub fn retract_into(&self, delta: &[f64], out: &mut Vec<G>) {
        out.clear();
        out.extend(self.poses.iter().zip(&self.free_slot).map(|(pose, &slot)| {
            if slot == FIXED {
                *pose
            } else {
                let start = slot as usize * D;
                let step = SVector::<f64, D>::from_column_slice(&delta[start..start + D]);
                pose.retract(&step)
            }
        }));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapmerge_geometry::{Se2, Se3};
    use nalgebra::{UnitQuaternion, Vector3};

    fn check_edge_jacobians<G: LieGroup<D>, const D: usize>(from: G, to: G, z: G, prior: bool) {
        let edge = CompiledEdge {
            id: EdgeId(0),
            kind: EdgeKind::Loop,
            from: 0,
            to: if prior { 0 } else { 1 },
            is_prior: prior,
            measurement_inverse: z.inverse(),
            information: SMatrix::identity(),
        };
        let poses = if prior { vec![to] } else { vec![from, to] };
        let lin = Problem::<G, D>::linearize_edge(&edge, &poses);
        let h = 1e-6;
        for (which, analytic) in [(0usize, lin.jacobian_from), (1, lin.jacobian_to)] {
            if prior && which == 0 {
                continue;
            }
            let slot = if prior { 0 } else { which };
            for k in 0..D {
                let mut delta = SVector::<f64, D>::zeros();
                delta[k] = h;
                let mut plus = poses.clone();
                plus[slot] = plus[slot].retract(&delta);
                let mut minus = poses.clone();
                minus[slot] = minus[slot].retract(&(-delta));
                let rp = Problem::<G, D>::linearize_edge(&edge, &plus).residual;
                let rm = Problem::<G, D>::linearize_edge(&edge, &minus).residual;
                let numeric = (rp - rm) / (2.0 * h);
                let column = analytic.column(k);
                assert!(
                    (numeric - column).norm() < 1e-6,
                    "jacobian {which} col {k}: {numeric} vs {column}"
                );
            }
        }
    }

    #[test]
    fn se2_edge_jacobians_match_numeric() {
        let a = Se2::new(1.0, -2.0, 0.7);
        let b = Se2::new(3.0, 0.5, -2.9);
        let z = Se2::new(2.1, 1.4, 2.5);
        check_edge_jacobians(a, b, z, false);
        check_edge_jacobians(a, b, z, true);
    }

    #[test]
    fn se3_edge_jacobians_match_numeric() {
        let a = Se3::new(
            UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1),
            Vector3::new(1.0, 2.0, -0.5),
        );
        let b = Se3::new(
            UnitQuaternion::from_euler_angles(-0.4, 0.5, 2.0),
            Vector3::new(-1.0, 0.3, 0.8),
        );
        let z = Se3::new(
            UnitQuaternion::from_euler_angles(0.1, 0.2, 0.6),
            Vector3::new(0.2, -1.0, 0.4),
        );
        check_edge_jacobians(a, b, z, false);
        check_edge_jacobians(a, b, z, true);
    }
}
