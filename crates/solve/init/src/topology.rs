//! The graph as the initialisers see it: dense vertex indices, relative edges with adjacency,
//! connected components with their anchors, and the odometry-first spanning tree.

use mapmerge_geometry::LieGroup;
use mapmerge_posegraph::{EdgeId, NodeId, PoseGraph};
use nalgebra::SMatrix;

use crate::error::InitError;

/// A relative (non-prior) edge between dense vertex indices.
pub(crate) struct RelEdge<G, const D: usize> {
    /// The edge's id in the graph.
    pub id: EdgeId,
    /// Dense index of the start vertex.
    pub from: usize,
    /// Dense index of the end vertex.
    pub to: usize,
    /// `from_from_to`.
    pub measurement: G,
    /// Information in the tangent order of `G`.
    pub information: SMatrix<f64, D, D>,
}

/// One entry of a vertex's adjacency list.
#[derive(Clone, Copy)]
pub(crate) struct Incidence {
    /// The vertex at the other end.
    pub neighbor: usize,
    /// Position of the edge in [`Topology::edges`].
    pub edge: usize,
    /// True when the edge points from this vertex to `neighbor`.
    pub forward: bool,
}

/// A vertex reached by the spanning tree: its pose follows from `parent`'s through `edge`.
#[derive(Clone, Copy)]
pub(crate) struct TreeStep {
    /// The vertex set by this step.
    pub vertex: usize,
    /// The vertex it is reached from.
    pub parent: usize,
    /// Position of the edge in [`Topology::edges`].
    pub edge: usize,
    /// True when the edge points from `parent` to `vertex` (use the measurement as is),
    /// false when it is traversed backwards (use its inverse).
    pub forward: bool,
}

/// Dense view of a pose graph. Vertex index `k` is the `k`-th vertex in id order.
pub(crate) struct Topology<G, const D: usize> {
    /// Vertex ids by dense index (sorted).
    pub ids: Vec<NodeId>,
    /// Current poses by dense index.
    pub poses: Vec<G>,
    /// True for vertices whose pose is kept: fixed vertices and component anchors.
    pub constant: Vec<bool>,
    /// The anchor of each component (dense indices), components ordered by smallest id.
    pub anchors: Vec<usize>,
    /// Relative edges in edge-id order.
    pub edges: Vec<RelEdge<G, D>>,
    adjacency_offsets: Vec<usize>,
    adjacency: Vec<Incidence>,
}

impl<G: LieGroup<D>, const D: usize> Topology<G, D> {
    /// Writes the non-anchor `poses` into `graph` and reports what was done (the last step of
    /// every initialiser).
    pub(crate) fn finish(
        &self,
        graph: &mut PoseGraph<G, D>,
        poses: &[G],
        angle_corrections: usize,
        start: std::time::Instant,
    ) -> crate::info::InitInfo {
        let vertices_set = self.write_back(graph, poses);
        crate::info::InitInfo {
            vertices_set,
            components: self.anchors.len(),
            anchors: self.anchor_ids(),
            edges_used: self.edges.len(),
            angle_corrections,
            seconds: start.elapsed().as_secs_f64(),
        }
    }

    /// Indexes `graph`. Fails if an edge measurement or an anchor pose is not finite.
    pub fn new(graph: &PoseGraph<G, D>) -> Result<Self, InitError> {
        let n = graph.num_vertices();
        let mut ids = Vec::with_capacity(n);
        let mut poses = Vec::with_capacity(n);
        let mut fixed = Vec::with_capacity(n);
        for (id, vertex) in graph.vertices() {
            ids.push(id);
            poses.push(vertex.pose);
            fixed.push(vertex.fixed);
        }
        let index_of = |id: NodeId| ids.binary_search(&id).ok();

        let mut edges = Vec::with_capacity(graph.num_edges());
        for (id, edge) in graph.edges() {
            if edge.is_prior() {
                continue;
            }
            // The graph guarantees both ends exist; skip defensively if not.
            let (Some(from), Some(to)) = (index_of(edge.from), index_of(edge.to)) else {
                continue;
            };
            if !edge.measurement.is_finite() {
                return Err(InitError::NonFiniteMeasurement {
                    edge: id,
                    from: edge.from,
                    to: edge.to,
                });
            }
            if edge.information.iter().any(|v| !v.is_finite()) {
                return Err(InitError::InvalidInformation {
                    edge: id,
                    from: edge.from,
                    to: edge.to,
                    reason: "not finite",
                });
            }
            edges.push(RelEdge {
                id,
                from,
                to,
                measurement: edge.measurement,
                information: edge.information,
            });
        }

        // Adjacency in edge order, each edge listed at both ends (counting sort, no per-vertex
        // allocation).
        let mut adjacency_offsets = vec![0usize; n + 1];
        for e in &edges {
            adjacency_offsets[e.from + 1] += 1;
            adjacency_offsets[e.to + 1] += 1;
        }
        for k in 0..n {
            adjacency_offsets[k + 1] += adjacency_offsets[k];
        }
        let mut cursor = adjacency_offsets.clone();
        let mut adjacency = vec![
            Incidence {
                neighbor: 0,
                edge: 0,
                forward: true
            };
            2 * edges.len()
        ];
        for (k, e) in edges.iter().enumerate() {
            adjacency[cursor[e.from]] = Incidence {
                neighbor: e.to,
                edge: k,
                forward: true,
            };
            cursor[e.from] += 1;
            adjacency[cursor[e.to]] = Incidence {
                neighbor: e.from,
                edge: k,
                forward: false,
            };
            cursor[e.to] += 1;
        }

        // Components by union-find; anchor = lowest-id fixed vertex, else lowest id.
        let mut parent: Vec<usize> = (0..n).collect();
        fn find(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        for e in &edges {
            let (a, b) = (find(&mut parent, e.from), find(&mut parent, e.to));
            if a != b {
                parent[a.max(b)] = a.min(b);
            }
        }
        // Roots are the smallest index of their component, so components appear in root order.
        let mut component_of_root = vec![usize::MAX; n];
        let mut lowest = Vec::new();
        let mut lowest_fixed: Vec<Option<usize>> = Vec::new();
        for (k, &is_fixed) in fixed.iter().enumerate() {
            let root = find(&mut parent, k);
            if component_of_root[root] == usize::MAX {
                component_of_root[root] = lowest.len();
                lowest.push(k);
                lowest_fixed.push(None);
            }
            let c = component_of_root[root];
            if is_fixed && lowest_fixed[c].is_none() {
                lowest_fixed[c] = Some(k);
            }
        }
        let anchors: Vec<usize> = lowest
            .iter()
            .zip(&lowest_fixed)
            .map(|(l, f)| f.unwrap_or(*l))
            .collect();
        let mut constant = fixed;
        for &a in &anchors {
            constant[a] = true;
        }
        for k in 0..n {
            if constant[k] && !poses[k].is_finite() {
                return Err(InitError::NonFiniteAnchor { node: ids[k] });
            }
        }
        Ok(Self {
            ids,
            poses,
            constant,
            anchors,
            edges,
            adjacency_offsets,
            adjacency,
        })
    }

    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        self.ids.len()
    }

    /// The edges at vertex `k`, in edge order.
    pub fn incident(&self, k: usize) -> &[Incidence] {
        &self.adjacency[self.adjacency_offsets[k]..self.adjacency_offsets[k + 1]]
    }

    /// The anchors as node ids.
    pub fn anchor_ids(&self) -> Vec<NodeId> {
        self.anchors.iter().map(|&k| self.ids[k]).collect()
    }

    /// The odometry-first spanning forest, in the order poses are set (what
    /// /work/shared/peers/gtsam_pgo.py `with_vertices` does):
    /// 1. every constant vertex (fixed or anchor) is set;
    /// 2. edges `i -> i+1` (by id), in `(i, j)` order, set `i+1` from `i`;
    /// 3. a breadth-first search over all edges (either direction, queue seeded with the vertices
    ///    set so far, in the order they were set) reaches the rest.
    ///
    /// Every non-constant vertex appears exactly once, since each component has an anchor.
    pub fn spanning_tree(&self) -> Vec<TreeStep> {
        let n = self.num_vertices();
        let mut is_set = self.constant.clone();
        let mut order: Vec<usize> = (0..n).filter(|&k| is_set[k]).collect();
        order.reserve(n - order.len());
        let mut steps = Vec::with_capacity(n - order.len());

        let mut chain: Vec<usize> = (0..self.edges.len())
            .filter(|&k| {
                let e = &self.edges[k];
                self.ids[e.from].0.checked_add(1) == Some(self.ids[e.to].0)
            })
            .collect();
        // Dense indices follow id order, so this is the (i, j) order; stable, so parallel edges
        // keep edge order.
        chain.sort_by_key(|&k| self.edges[k].from);
        for k in chain {
            let e = &self.edges[k];
            if is_set[e.from] && !is_set[e.to] {
                is_set[e.to] = true;
                order.push(e.to);
                steps.push(TreeStep {
                    vertex: e.to,
                    parent: e.from,
                    edge: k,
                    forward: true,
                });
            }
        }

        let mut head = 0;
        while head < order.len() {
            let a = order[head];
            head += 1;
            for inc in self.incident(a) {
                if !is_set[inc.neighbor] {
                    is_set[inc.neighbor] = true;
                    order.push(inc.neighbor);
                    steps.push(TreeStep {
                        vertex: inc.neighbor,
                        parent: a,
                        edge: inc.edge,
                        forward: inc.forward,
                    });
                }
            }
        }
        steps
    }

    /// Dense unknown index of every vertex (`None` for constants) and the number of unknowns.
    pub fn unknown_indices(&self) -> (Vec<Option<usize>>, usize) {
        let mut count = 0;
        let map = self
            .constant
            .iter()
            .map(|&c| {
                if c {
                    None
                } else {
                    count += 1;
                    Some(count - 1)
                }
            })
            .collect();
        (map, count)
    }

    /// Writes `poses[k]` into every non-constant vertex of `graph` (the graph this topology was
    /// built from) and returns how many were written.
    pub fn write_back(&self, graph: &mut PoseGraph<G, D>, poses: &[G]) -> usize {
        let mut written = 0;
        for (k, (_, vertex)) in graph.vertices_mut().enumerate() {
            if k < poses.len() && !self.constant[k] {
                vertex.pose = poses[k];
                written += 1;
            }
        }
        written
    }
}
