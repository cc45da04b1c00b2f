//! Graph simplification, second operation (iRobot, Sec. 4.2): remove a vertex and replace its
//! edges by a sparse approximation of the marginal over its neighbours, a Chow–Liu tree (Ta
//! et al. 2018, the seed's ref. [5]; Kretzschmar & Stachniss 2012), rather than drop them.
//!
//! 1. Linearise every edge at `v` at the current estimate and marginalise `v` out of their
//!    joint information: the Schur complement `Λ = H_NN − H_Nv H_vv⁻¹ H_vN` over the
//!    neighbours `N`. It is exact to first order and dense.
//! 2. Approximate `Λ` by a tree of relative-pose edges. A spanning tree's relative poses are
//!    coordinates of the neighbours up to a common motion (which `Λ` cannot see), so
//!    `q = Π_(i,j)∈T p(d_ij)`, with `p(d_ij)` the exact marginal of the relative pose
//!    `d_ij = x_i⁻¹ x_j`, is the tree's Chow–Liu approximation in those coordinates. Its
//!    divergence `KL(p‖q) = ½ (Σ_T ln det C_ij − ln det Σ)` is smallest for the spanning tree
//!    of least `Σ ln det C_ij` (Kruskal), where `C_ij` is the marginal covariance of `d_ij`.
//! 3. Each tree edge is a relative-pose edge: measurement the current `x_i⁻¹ x_j`,
//!    information `C_ij⁻¹`. With two neighbours the tree is one edge and exact.

use std::collections::BTreeMap;

use mapmerge_geometry::LieGroup;
use nalgebra::{DMatrix, SMatrix};

use crate::simplify::DisjointSets;
use crate::{Edge, EdgeId, EdgeKind, GraphError, NodeId, PoseGraph, RemovedVertex};

/// What [`PoseGraph::marginalize_vertex`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct Marginalized<G, const D: usize> {
    /// The vertex and the edges that were removed.
    pub removed: RemovedVertex<G, D>,
    /// The tree edges that replace them, with their new ids.
    pub added: Vec<(EdgeId, Edge<G, D>)>,
}

impl<G: LieGroup<D>, const D: usize> PoseGraph<G, D> {
    /// Removes `node` and replaces its edges by the Chow–Liu tree of their marginal over its
    /// neighbours (see the module documentation); new edges have kind
    /// [`EdgeKind::Marginal`]. Refused, with the graph unchanged, for a fixed vertex or one
    /// with a prior (an absolute measurement has no relative-pose tree) and when the
    /// linearised system is singular or not finite.
    pub fn marginalize_vertex(&mut self, node: NodeId) -> Result<Marginalized<G, D>, GraphError> {
        let refuse = |reason: &'static str| GraphError::NotMarginalizable { node, reason };
        let vertex = self.vertex(node).ok_or(GraphError::MissingVertex(node))?;
        if vertex.fixed {
            return Err(refuse("the vertex is fixed"));
        }
        let incident = self.incident_edges(node);
        let mut neighbours: Vec<NodeId> = Vec::new();
        for id in &incident {
            let edge = self.edge(*id).ok_or(GraphError::MissingEdge(*id))?;
            if edge.is_prior() {
                return Err(refuse("the vertex has a prior"));
            }
            let other = if edge.from == node {
                edge.to
            } else {
                edge.from
            };
            if !neighbours.contains(&other) {
                neighbours.push(other);
            }
        }
        neighbours.sort();
        let tree = if neighbours.len() >= 2 {
            self.chow_liu_tree(node, &incident, &neighbours)
                .ok_or_else(|| refuse("its linearised marginal is singular or not finite"))?
        } else {
            Vec::new()
        };
        // Nothing below fails: the neighbours exist and the edges join distinct vertices.
        let removed = self.remove_vertex(node)?;
        let mut added = Vec::with_capacity(tree.len());
        for edge in tree {
            let id = self.add_edge(edge)?;
            added.push((id, edge));
        }
        Ok(Marginalized { removed, added })
    }

    /// The tree edges over `neighbours` (sorted) that replace `node`'s `incident` edges;
    /// `None` on a singular or non-finite system.
    fn chow_liu_tree(
        &self,
        node: NodeId,
        incident: &[EdgeId],
        neighbours: &[NodeId],
    ) -> Option<Vec<Edge<G, D>>> {
        let n = neighbours.len();
        // Block 0 is `node`, block k + 1 is neighbour k.
        let block: BTreeMap<NodeId, usize> = std::iter::once(node)
            .chain(neighbours.iter().copied())
            .enumerate()
            .map(|(k, id)| (id, k))
            .collect();
        let pose = |id: NodeId| self.vertex(id).map(|v| v.pose);
        let mut h = DMatrix::<f64>::zeros(D * (n + 1), D * (n + 1));
        for id in incident {
            let edge = self.edge(*id)?;
            let (from, to) = (pose(edge.from)?, pose(edge.to)?);
            let (_, j_from, j_to) = edge
                .measurement
                .inverse()
                .relative_error_jacobians(&from, &to);
            let (a, b) = (*block.get(&edge.from)?, *block.get(&edge.to)?);
            for (p, jp) in [(a, &j_from), (b, &j_to)] {
                for (q, jq) in [(a, &j_from), (b, &j_to)] {
                    let term = jp.transpose() * edge.information * jq;
                    let mut view = h.view_mut((D * p, D * q), (D, D));
                    view += term;
                }
            }
        }
        // Schur complement onto the neighbours.
        let h_vv = h.view((0, 0), (D, D)).into_owned();
        let h_nv = h.view((D, 0), (D * n, D)).into_owned();
        let h_nn = h.view((D, D), (D * n, D * n)).into_owned();
        let h_vv_inv = h_vv.cholesky()?.inverse();
        let lambda = &h_nn - &h_nv * h_vv_inv * h_nv.transpose();
        // Its covariance in the gauge of neighbour 0 (held fixed: zero rows).
        let reduced = lambda.view((D, D), (D * (n - 1), D * (n - 1))).into_owned();
        let reduced = (&reduced + reduced.transpose()) * 0.5;
        let sigma_reduced = reduced.cholesky()?.inverse();
        let mut sigma = DMatrix::<f64>::zeros(D * n, D * n);
        sigma
            .view_mut((D, D), (D * (n - 1), D * (n - 1)))
            .copy_from(&sigma_reduced);
        let sigma_block = |i: usize, j: usize| -> SMatrix<f64, D, D> {
            sigma.fixed_view::<D, D>(D * i, D * j).into_owned()
        };
        // Every pair's relative-pose marginal: covariance, log-determinant, measurement.
        let mut pairs: Vec<(f64, usize, usize, G, SMatrix<f64, D, D>)> = Vec::new();
        for i in 0..n {
            for j in (i + 1)..n {
                let (xi, xj) = (pose(neighbours[i])?, pose(neighbours[j])?);
                let measurement = xi.between(&xj);
                let (_, a_i, a_j) = measurement.inverse().relative_error_jacobians(&xi, &xj);
                let c = a_i * sigma_block(i, i) * a_i.transpose()
                    + a_i * sigma_block(i, j) * a_j.transpose()
                    + a_j * sigma_block(j, i) * a_i.transpose()
                    + a_j * sigma_block(j, j) * a_j.transpose();
                let c = (c + c.transpose()) * 0.5;
                let cholesky = c.cholesky()?;
                let ln_det: f64 = cholesky
                    .l_dirty()
                    .diagonal()
                    .iter()
                    .map(|d| 2.0 * d.ln())
                    .sum();
                let information = cholesky.inverse();
                let information = (information + information.transpose()) * 0.5;
                if !(ln_det.is_finite() && information.iter().all(|x| x.is_finite())) {
                    return None;
                }
                pairs.push((ln_det, i, j, measurement, information));
            }
        }
        // The spanning tree of least Σ ln det C (ties by neighbour order).
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
        let mut sets = DisjointSets::new(n);
        let mut tree = Vec::with_capacity(n - 1);
        for (_, i, j, measurement, information) in pairs {
            if sets.union(i, j) {
                tree.push(Edge {
                    from: neighbours[i],
                    to: neighbours[j],
                    measurement,
                    information,
                    kind: EdgeKind::Marginal,
                });
            }
        }
        Some(tree)
    }
}
