//! The pose graph: vertices (poses) and edges (relative measurements), with edits that return
//! records from which the edit can be undone exactly.

use std::collections::{BTreeMap, BTreeSet};

use mapmerge_geometry::LieGroup;
use nalgebra::SMatrix;
use serde::{Deserialize, Serialize};

use crate::ids::{EdgeId, NodeId, VertexMeta};

/// A pose and what is known about it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Vertex<G> {
    /// `world_from_node`: the vertex pose in the graph's frame.
    pub pose: G,
    /// Held constant by the optimizer.
    pub fixed: bool,
    /// Session, robot and time stamp.
    pub meta: VertexMeta,
}

impl<G> Vertex<G> {
    /// A free vertex with default metadata.
    pub fn new(pose: G) -> Self {
        Self {
            pose,
            fixed: false,
            meta: VertexMeta::default(),
        }
    }
}

/// Why an edge exists. Merge edges are the ones a merge adds and an unmerge removes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum EdgeKind {
    /// Between consecutive poses of one trajectory.
    Odometry,
    /// A loop closure within one map.
    Loop,
    /// A loop closure that joins two maps.
    Merge,
    /// An absolute pose measurement; `from == to` and `measurement` is `world_from_node`.
    Prior,
    /// What remains of a removed vertex's edges: an edge of the Chow–Liu tree of their
    /// marginal ([`PoseGraph::marginalize_vertex`]).
    Marginal,
}

/// A measurement between two vertices: `measurement ≈ from⁻¹ · to` (`from_from_to`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Edge<G, const D: usize> {
    /// The vertex the measurement is expressed in.
    pub from: NodeId,
    /// The measured vertex (equal to `from` for priors).
    pub to: NodeId,
    /// `from_from_to`, or `world_from_node` for priors.
    pub measurement: G,
    /// Information matrix (inverse covariance) in the tangent order of `G`.
    pub information: SMatrix<f64, D, D>,
    /// Why the edge exists.
    pub kind: EdgeKind,
}

impl<G, const D: usize> Edge<G, D> {
    /// True for unary (prior) edges.
    pub fn is_prior(&self) -> bool {
        self.kind == EdgeKind::Prior
    }
}

/// What can go wrong when editing a graph.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum GraphError {
    /// A vertex with this id exists already.
    #[error("duplicate vertex id {0}")]
    DuplicateVertex(NodeId),
    /// No vertex with this id.
    #[error("no vertex with id {0}")]
    MissingVertex(NodeId),
    /// No edge with this id.
    #[error("no edge with id {0}")]
    MissingEdge(EdgeId),
    /// An edge id is in use already.
    #[error("duplicate edge id {0}")]
    DuplicateEdge(EdgeId),
    /// A prior edge must have `from == to`, a relative edge must not.
    #[error("edge {from} -> {to}: {reason}")]
    BadEdge {
        /// Start vertex.
        from: NodeId,
        /// End vertex.
        to: NodeId,
        /// What is wrong.
        reason: &'static str,
    },
    /// A vertex that cannot be marginalised.
    #[error("vertex {node} cannot be marginalised: {reason}")]
    NotMarginalizable {
        /// The vertex.
        node: NodeId,
        /// Why.
        reason: &'static str,
    },
}

/// A vertex removed together with the edges that touched it; [`PoseGraph::restore_vertex`] puts
/// it back.
#[derive(Clone, Debug, PartialEq)]
pub struct RemovedVertex<G, const D: usize> {
    /// The removed vertex's id.
    pub id: NodeId,
    /// The removed vertex.
    pub vertex: Vertex<G>,
    /// The incident edges, with their ids.
    pub edges: Vec<(EdgeId, Edge<G, D>)>,
}

/// What [`PoseGraph::union`] added; [`PoseGraph::undo_union`] removes exactly that.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct UnionRecord {
    /// Vertices that came from the other graph.
    pub added_vertices: Vec<NodeId>,
    /// The other graph's edges under their new ids, in the other graph's id order.
    pub added_edges: Vec<EdgeId>,
    /// The connecting edges' ids.
    pub connecting_edges: Vec<EdgeId>,
    /// The edge-id counter before the union.
    pub next_edge_id_before: u64,
}

/// The poses before a [`PoseGraph::reanchor`]; [`PoseGraph::undo_reanchor`] restores them
/// bit for bit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReanchorRecord<G> {
    /// Every vertex pose before the change.
    pub previous_poses: Vec<(NodeId, G)>,
    /// Every prior measurement before the change.
    pub previous_priors: Vec<(EdgeId, G)>,
}

/// A pose graph over the pose type `G` with `D` degrees of freedom.
///
/// Vertices and edges live in ordered maps, so iteration order (and therefore file output and
/// optimizer ordering) is deterministic, and an undone edit compares equal to the original.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(bound(serialize = "G: Serialize", deserialize = "G: Deserialize<'de>"))]
pub struct PoseGraph<G, const D: usize> {
    vertices: BTreeMap<NodeId, Vertex<G>>,
    edges: BTreeMap<EdgeId, Edge<G, D>>,
    next_edge_id: u64,
}

/// A planar pose graph.
pub type PoseGraph2 = PoseGraph<mapmerge_geometry::Se2, 3>;
/// A spatial pose graph.
pub type PoseGraph3 = PoseGraph<mapmerge_geometry::Se3, 6>;

impl<G, const D: usize> Default for PoseGraph<G, D> {
    fn default() -> Self {
        Self {
            vertices: BTreeMap::new(),
            edges: BTreeMap::new(),
            next_edge_id: 0,
        }
    }
}

impl<G: LieGroup<D>, const D: usize> PoseGraph<G, D> {
    /// An empty graph.
    pub fn new() -> Self {
        Self::default()
    }

    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        self.vertices.len()
    }

    /// Number of edges (priors included).
    pub fn num_edges(&self) -> usize {
        self.edges.len()
    }

    /// The vertex with this id.
    pub fn vertex(&self, id: NodeId) -> Option<&Vertex<G>> {
        self.vertices.get(&id)
    }

    /// The vertex with this id, mutably (pose, fixed flag, metadata).
    pub fn vertex_mut(&mut self, id: NodeId) -> Option<&mut Vertex<G>> {
        self.vertices.get_mut(&id)
    }

    /// The edge with this id.
    pub fn edge(&self, id: EdgeId) -> Option<&Edge<G, D>> {
        self.edges.get(&id)
    }

    /// The edge with this id, mutably. Endpoints must not be changed to missing vertices;
    /// prefer remove + add for that.
    pub fn edge_mut(&mut self, id: EdgeId) -> Option<&mut Edge<G, D>> {
        self.edges.get_mut(&id)
    }

    /// Vertices in id order.
    pub fn vertices(&self) -> impl ExactSizeIterator<Item = (NodeId, &Vertex<G>)> + '_ {
        self.vertices.iter().map(|(k, v)| (*k, v))
    }

    /// Vertices in id order, poses mutable.
    pub fn vertices_mut(&mut self) -> impl ExactSizeIterator<Item = (NodeId, &mut Vertex<G>)> + '_ {
        self.vertices.iter_mut().map(|(k, v)| (*k, v))
    }

    /// Edges in id order.
    pub fn edges(&self) -> impl ExactSizeIterator<Item = (EdgeId, &Edge<G, D>)> + '_ {
        self.edges.iter().map(|(k, e)| (*k, e))
    }

    /// True when a vertex with this id exists.
    pub fn contains_vertex(&self, id: NodeId) -> bool {
        self.vertices.contains_key(&id)
    }

    /// The id the next added edge will get.
    pub fn next_edge_id(&self) -> EdgeId {
        EdgeId(self.next_edge_id)
    }

    /// Adds a vertex; fails if the id is taken.
    pub fn add_vertex(&mut self, id: NodeId, vertex: Vertex<G>) -> Result<(), GraphError> {
        if self.vertices.contains_key(&id) {
            return Err(GraphError::DuplicateVertex(id));
        }
        self.vertices.insert(id, vertex);
        Ok(())
    }

    fn check_edge(&self, edge: &Edge<G, D>) -> Result<(), GraphError> {
        for end in [edge.from, edge.to] {
            if !self.vertices.contains_key(&end) {
                return Err(GraphError::MissingVertex(end));
            }
        }
        let bad = |reason| GraphError::BadEdge {
            from: edge.from,
            to: edge.to,
            reason,
        };
        match (edge.is_prior(), edge.from == edge.to) {
            (true, false) => Err(bad("a prior edge must have from == to")),
            (false, true) => Err(bad("a relative edge must join two different vertices")),
            _ => Ok(()),
        }
    }

    /// Adds an edge between existing vertices and returns its new id.
    pub fn add_edge(&mut self, edge: Edge<G, D>) -> Result<EdgeId, GraphError> {
        self.check_edge(&edge)?;
        let id = EdgeId(self.next_edge_id);
        self.next_edge_id += 1;
        self.edges.insert(id, edge);
        Ok(id)
    }

    /// Inserts an edge under a given id (used to restore removed edges).
    pub fn insert_edge_with_id(&mut self, id: EdgeId, edge: Edge<G, D>) -> Result<(), GraphError> {
        if self.edges.contains_key(&id) {
            return Err(GraphError::DuplicateEdge(id));
        }
        self.check_edge(&edge)?;
        self.next_edge_id = self.next_edge_id.max(id.0 + 1);
        self.edges.insert(id, edge);
        Ok(())
    }

    /// Removes an edge and returns it.
    pub fn remove_edge(&mut self, id: EdgeId) -> Result<Edge<G, D>, GraphError> {
        self.edges.remove(&id).ok_or(GraphError::MissingEdge(id))
    }

    /// Ids of the edges that touch `id`, in id order.
    pub fn incident_edges(&self, id: NodeId) -> Vec<EdgeId> {
        self.edges
            .iter()
            .filter(|(_, e)| e.from == id || e.to == id)
            .map(|(k, _)| *k)
            .collect()
    }

    /// Removes a vertex and every edge touching it.
    pub fn remove_vertex(&mut self, id: NodeId) -> Result<RemovedVertex<G, D>, GraphError> {
        let vertex = self
            .vertices
            .remove(&id)
            .ok_or(GraphError::MissingVertex(id))?;
        let incident: Vec<EdgeId> = self.incident_edges(id);
        let edges = incident
            .into_iter()
            .filter_map(|eid| self.edges.remove(&eid).map(|e| (eid, e)))
            .collect();
        Ok(RemovedVertex { id, vertex, edges })
    }

    /// Puts back what [`PoseGraph::remove_vertex`] took out.
    pub fn restore_vertex(&mut self, removed: RemovedVertex<G, D>) -> Result<(), GraphError> {
        self.add_vertex(removed.id, removed.vertex)?;
        for (eid, edge) in removed.edges {
            self.insert_edge_with_id(eid, edge)?;
        }
        Ok(())
    }

    /// Connected components (priors ignored), each sorted by id; components ordered by their
    /// smallest id.
    pub fn connected_components(&self) -> Vec<Vec<NodeId>> {
        let ids: Vec<NodeId> = self.vertices.keys().copied().collect();
        let index: BTreeMap<NodeId, usize> = ids.iter().enumerate().map(|(i, k)| (*k, i)).collect();
        let mut parent: Vec<usize> = (0..ids.len()).collect();
        fn find(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        for edge in self.edges.values() {
            if let (Some(&a), Some(&b)) = (index.get(&edge.from), index.get(&edge.to)) {
                let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
                if ra != rb {
                    parent[ra.max(rb)] = ra.min(rb);
                }
            }
        }
        let mut groups: BTreeMap<usize, Vec<NodeId>> = BTreeMap::new();
        for (i, id) in ids.iter().enumerate() {
            let root = find(&mut parent, i);
            groups.entry(root).or_default().push(*id);
        }
        groups.into_values().collect()
    }

    /// The subgraph on `keep`: those vertices and every edge with both ends among them, with the
    /// original edge ids.
    pub fn subgraph(&self, keep: &BTreeSet<NodeId>) -> Self {
        let vertices = self
            .vertices
            .iter()
            .filter(|(k, _)| keep.contains(k))
            .map(|(k, v)| (*k, *v))
            .collect();
        let edges = self
            .edges
            .iter()
            .filter(|(_, e)| keep.contains(&e.from) && keep.contains(&e.to))
            .map(|(k, e)| (*k, *e))
            .collect();
        Self {
            vertices,
            edges,
            next_edge_id: self.next_edge_id,
        }
    }

    /// Adds every vertex and edge of `other` (vertex ids must be disjoint; edges get new ids)
    /// plus the `connecting` edges. Nothing changes on error.
    pub fn union(
        &mut self,
        other: &Self,
        connecting: &[Edge<G, D>],
    ) -> Result<UnionRecord, GraphError> {
        if let Some(clash) = other
            .vertices
            .keys()
            .find(|k| self.vertices.contains_key(k))
        {
            return Err(GraphError::DuplicateVertex(*clash));
        }
        for edge in connecting {
            for end in [edge.from, edge.to] {
                if !self.vertices.contains_key(&end) && !other.vertices.contains_key(&end) {
                    return Err(GraphError::MissingVertex(end));
                }
            }
        }
        let next_edge_id_before = self.next_edge_id;
        let mut record = UnionRecord {
            added_vertices: other.vertices.keys().copied().collect(),
            added_edges: Vec::with_capacity(other.edges.len()),
            connecting_edges: Vec::with_capacity(connecting.len()),
            next_edge_id_before,
        };
        self.vertices
            .extend(other.vertices.iter().map(|(k, v)| (*k, *v)));
        for edge in other.edges.values() {
            let id = EdgeId(self.next_edge_id);
            self.next_edge_id += 1;
            self.edges.insert(id, *edge);
            record.added_edges.push(id);
        }
        for edge in connecting {
            match self.add_edge(*edge) {
                Ok(id) => record.connecting_edges.push(id),
                Err(err) => {
                    self.undo_union(&record);
                    return Err(err);
                }
            }
        }
        Ok(record)
    }

    /// Removes what a union added and returns it as a graph of its own (vertices with their
    /// current poses, edges under their ids in this graph). The connecting edges are dropped.
    pub fn undo_union(&mut self, record: &UnionRecord) -> Self {
        let mut removed = Self::new();
        for id in &record.connecting_edges {
            self.edges.remove(id);
        }
        for id in &record.added_edges {
            if let Some(edge) = self.edges.remove(id) {
                removed.edges.insert(*id, edge);
            }
        }
        for id in &record.added_vertices {
            if let Some(v) = self.vertices.remove(id) {
                removed.vertices.insert(*id, v);
            }
        }
        removed.next_edge_id = self.next_edge_id;
        self.next_edge_id = record.next_edge_id_before;
        removed
    }

    /// Expresses the whole graph in another frame: every pose `x` becomes `new_from_old · x`
    /// (priors too); relative measurements are unchanged.
    pub fn reanchor(&mut self, new_from_old: &G) -> ReanchorRecord<G> {
        let mut record = ReanchorRecord {
            previous_poses: Vec::with_capacity(self.vertices.len()),
            previous_priors: Vec::new(),
        };
        for (id, v) in self.vertices.iter_mut() {
            record.previous_poses.push((*id, v.pose));
            v.pose = new_from_old.compose(&v.pose);
        }
        for (id, e) in self.edges.iter_mut() {
            if e.is_prior() {
                record.previous_priors.push((*id, e.measurement));
                e.measurement = new_from_old.compose(&e.measurement);
            }
        }
        record
    }

    /// Restores the poses saved by [`PoseGraph::reanchor`] exactly.
    pub fn undo_reanchor(&mut self, record: &ReanchorRecord<G>) {
        for (id, pose) in &record.previous_poses {
            if let Some(v) = self.vertices.get_mut(id) {
                v.pose = *pose;
            }
        }
        for (id, m) in &record.previous_priors {
            if let Some(e) = self.edges.get_mut(id) {
                e.measurement = *m;
            }
        }
    }

    /// `Σ rᵀ Ω r` over all edges, the g2o/GTSAM chi2 (`r` in [`LieGroup::error_coordinates`]).
    pub fn chi2(&self) -> f64 {
        self.edges.values().filter_map(|e| self.edge_chi2(e)).sum()
    }

    /// The chi2 contribution of one edge, or `None` if an endpoint is missing.
    pub fn edge_chi2(&self, edge: &Edge<G, D>) -> Option<f64> {
        let r = self.edge_residual(edge)?;
        Some((r.transpose() * edge.information * r)[(0, 0)])
    }

    /// The residual of one edge: `coords(z⁻¹ · from⁻¹ · to)`, or `coords(z⁻¹ · x)` for a prior.
    pub fn edge_residual(&self, edge: &Edge<G, D>) -> Option<nalgebra::SVector<f64, D>> {
        let to = self.vertices.get(&edge.to)?.pose;
        let predicted = if edge.is_prior() {
            to
        } else {
            self.vertices.get(&edge.from)?.pose.between(&to)
        };
        Some(edge.measurement.between(&predicted).error_coordinates())
    }
}
