//! Graph simplification, first operation (iRobot, Sec. 4.2): keep `|E| ≤ c·|V|` by removing the
//! least informative edges while the graph stays as connected as it was.

use std::collections::BTreeMap;

use mapmerge_geometry::LieGroup;

use crate::{Edge, EdgeId, NodeId, PoseGraph};

/// How informative an edge is: `ln det Ω` (the log-volume of its information ellipsoid);
/// `-∞` for a singular or non-finite information matrix.
pub fn edge_information_ln_det<G, const D: usize>(edge: &Edge<G, D>) -> f64 {
    match edge.information.cholesky() {
        Some(cholesky) => {
            let diagonal = cholesky.l_dirty().diagonal();
            let ln_det: f64 = diagonal.iter().map(|d| 2.0 * d.ln()).sum();
            if ln_det.is_finite() {
                ln_det
            } else {
                f64::NEG_INFINITY
            }
        }
        None => f64::NEG_INFINITY,
    }
}

/// Disjoint sets over vertex ids (union by size, path halving).
pub(crate) struct DisjointSets {
    parent: Vec<usize>,
    size: Vec<usize>,
}

impl DisjointSets {
    pub(crate) fn new(n: usize) -> Self {
        Self {
            parent: (0..n).collect(),
            size: vec![1; n],
        }
    }

    fn find(&mut self, mut x: usize) -> usize {
        while let Some(&p) = self.parent.get(x) {
            if p == x {
                break;
            }
            let grandparent = self.parent.get(p).copied().unwrap_or(p);
            if let Some(slot) = self.parent.get_mut(x) {
                *slot = grandparent;
            }
            x = grandparent;
        }
        x
    }

    /// Joins the sets of `a` and `b`; false when they were one set already.
    pub(crate) fn union(&mut self, a: usize, b: usize) -> bool {
        let (a, b) = (self.find(a), self.find(b));
        if a == b {
            return false;
        }
        let (size_a, size_b) = (
            self.size.get(a).copied().unwrap_or(1),
            self.size.get(b).copied().unwrap_or(1),
        );
        let (big, small) = if size_a >= size_b { (a, b) } else { (b, a) };
        if let Some(slot) = self.parent.get_mut(small) {
            *slot = big;
        }
        if let Some(slot) = self.size.get_mut(big) {
            *slot = size_a + size_b;
        }
        true
    }
}

impl<G: LieGroup<D>, const D: usize> PoseGraph<G, D> {
    /// Removes the least informative edges ([`edge_information_ln_det`], ties by edge id)
    /// until at most `max_edges_per_vertex · |V|` remain, never one of a maximum spanning
    /// forest by information and never a prior, so every connected component stays
    /// connected. Returns the removed edges in removal order; inserting them back
    /// (`insert_edge_with_id`) restores the graph exactly. A limit below what the forest and
    /// the priors need leaves those.
    pub fn prune_edges(&mut self, max_edges_per_vertex: f64) -> Vec<(EdgeId, Edge<G, D>)> {
        let limit = if max_edges_per_vertex.is_finite() && max_edges_per_vertex >= 0.0 {
            (max_edges_per_vertex * self.num_vertices() as f64).floor() as usize
        } else {
            usize::MAX
        };
        if self.num_edges() <= limit {
            return Vec::new();
        }
        let index: BTreeMap<NodeId, usize> = self
            .vertices()
            .enumerate()
            .map(|(k, (id, _))| (id, k))
            .collect();
        // Most informative first; Kruskal keeps a maximum spanning forest.
        let mut ranked: Vec<(f64, EdgeId)> = self
            .edges()
            .map(|(id, e)| (edge_information_ln_det(e), id))
            .collect();
        ranked.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        let mut sets = DisjointSets::new(index.len());
        let mut removable: Vec<EdgeId> = Vec::new();
        for (_, id) in &ranked {
            let Some(edge) = self.edge(*id) else { continue };
            if edge.is_prior() {
                continue;
            }
            let ends = (index.get(&edge.from), index.get(&edge.to));
            let (Some(&a), Some(&b)) = ends else { continue };
            if !sets.union(a, b) {
                removable.push(*id);
            }
        }
        // Least informative first.
        let excess = self.num_edges() - limit;
        removable
            .into_iter()
            .rev()
            .take(excess)
            .filter_map(|id| Some((id, self.remove_edge(id).ok()?)))
            .collect()
    }
}
