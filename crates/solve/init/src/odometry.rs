//! Odometry chaining: compose relative measurements along a spanning tree.

use std::time::Instant;

use mapmerge_geometry::LieGroup;
use mapmerge_posegraph::PoseGraph;

use crate::error::InitError;
use crate::info::InitInfo;
use crate::topology::Topology;

/// Sets every vertex pose by composing measurements outward from the anchors, exactly as the
/// GTSAM peer script (`gtsam_pgo.py`, `with_vertices`) initialises a file without vertices:
///
/// 1. each connected component (priors ignored) has an anchor — its lowest-id fixed vertex, else
///    its lowest id — that keeps its current pose (the identity for files without vertices);
///    other fixed vertices keep theirs too;
/// 2. edges `i -> i+1` (by id), in `(i, j)` order, set `x_{i+1} = x_i · z`;
/// 3. a breadth-first search over all edges sets the rest, using `z⁻¹` for edges traversed
///    backwards.
///
/// Priors are ignored. On error the graph is unchanged.
pub fn initialize_odometry<G: LieGroup<D>, const D: usize>(
    graph: &mut PoseGraph<G, D>,
) -> Result<InitInfo, InitError> {
    let start = Instant::now();
    let topology = Topology::new(graph)?;
    let mut poses = topology.poses.clone();
    let tree = topology.spanning_tree();
    for step in &tree {
        let z = &topology.edges[step.edge].measurement;
        let pose = if step.forward {
            poses[step.parent].compose(z)
        } else {
            poses[step.parent].compose(&z.inverse())
        };
        if !pose.is_finite() {
            return Err(InitError::NonFiniteEstimate {
                stage: "odometry chaining",
                node: topology.ids[step.vertex],
            });
        }
        poses[step.vertex] = pose;
    }
    let vertices_set = topology.write_back(graph, &poses);
    Ok(InitInfo {
        vertices_set,
        components: topology.anchors.len(),
        anchors: topology.anchor_ids(),
        edges_used: tree.len(),
        angle_corrections: 0,
        seconds: start.elapsed().as_secs_f64(),
    })
}
