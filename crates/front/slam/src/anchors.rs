//! Every scan of a log anchored to a keyframe node, so its pose follows the optimised graph.

use std::collections::{BTreeMap, BTreeSet};

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::{NodeId, PoseGraph};
use serde::{Deserialize, Serialize};

/// For each scan, in log order: the keyframe node it hangs on and its pose in that node's
/// frame (`node_from_robot`). A keyframe's own scan hangs on its node at the identity.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ScanAnchors {
    anchors: Vec<(NodeId, Se2)>,
}

/// Where every node was before vertices were removed: its graph (any key that tells graphs
/// apart) and its pose in that graph.
pub type NodesBefore = BTreeMap<NodeId, (u32, Se2)>;

impl ScanAnchors {
    /// No scans yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Anchors the next scan to `node` at `node_from_robot`.
    pub fn push(&mut self, node: NodeId, node_from_robot: Se2) {
        self.anchors.push((node, node_from_robot));
    }

    /// Keeps the first `len` scans' anchors (scans taken back to be fed again).
    pub fn truncate(&mut self, len: usize) {
        self.anchors.truncate(len);
    }

    /// Number of scans anchored.
    pub fn len(&self) -> usize {
        self.anchors.len()
    }

    /// True when no scan is anchored.
    pub fn is_empty(&self) -> bool {
        self.anchors.is_empty()
    }

    /// The anchor of scan `index`.
    pub fn get(&self, index: usize) -> Option<(NodeId, Se2)> {
        self.anchors.get(index).copied()
    }

    /// Every anchor, in scan order.
    pub fn iter(&self) -> impl ExactSizeIterator<Item = (NodeId, Se2)> + '_ {
        self.anchors.iter().copied()
    }

    /// Hangs the scans whose node was removed on the remaining node of the same graph
    /// nearest in id (the nearest in time), at the pose they had: `before` holds every node
    /// as it was, `remains` says whether a node is still there. Scans whose graph lost every
    /// node keep their vanished node (they have no pose any more). Returns how many scans
    /// were hung anew.
    pub fn reanchor(&mut self, before: &NodesBefore, remains: impl Fn(NodeId) -> bool) -> usize {
        let mut remaining: BTreeMap<u32, BTreeSet<NodeId>> = BTreeMap::new();
        for (&node, &(graph, _)) in before {
            if remains(node) {
                remaining.entry(graph).or_default().insert(node);
            }
        }
        let mut moved = 0;
        for (node, node_from_robot) in &mut self.anchors {
            if remains(*node) {
                continue;
            }
            let Some(&(graph, map_from_node)) = before.get(node) else {
                continue;
            };
            let Some(nodes) = remaining.get(&graph) else {
                continue;
            };
            let earlier = nodes.range(..*node).next_back();
            let later = nodes.range(*node..).next();
            let nearest = match (earlier, later) {
                (Some(a), Some(b)) => Some(if node.0 - a.0 <= b.0 - node.0 { a } else { b }),
                (a, b) => a.or(b),
            };
            let Some(&(_, map_from_new)) = nearest.and_then(|n| before.get(n)) else {
                continue;
            };
            if let Some(&new) = nearest {
                *node_from_robot = map_from_new
                    .inverse()
                    .compose(&map_from_node.compose(node_from_robot));
                *node = new;
                moved += 1;
            }
        }
        moved
    }

    /// `map_from_robot` of every scan from the graph's current poses (`None` for scans whose
    /// node is not in the graph).
    pub fn trajectory(&self, graph: &PoseGraph<Se2, 3>) -> Vec<Option<Se2>> {
        self.anchors
            .iter()
            .map(|(node, node_from_robot)| {
                graph.vertex(*node).map(|v| v.pose.compose(node_from_robot))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapmerge_posegraph::{PoseGraph2, Vertex};

    #[test]
    fn scans_follow_their_node() {
        let mut graph = PoseGraph2::new();
        let _ = graph.add_vertex(NodeId(3), Vertex::new(Se2::new(1.0, 0.0, 0.0)));
        let mut anchors = ScanAnchors::new();
        anchors.push(NodeId(3), Se2::identity());
        anchors.push(NodeId(3), Se2::new(0.5, 0.0, 0.0));
        anchors.push(NodeId(9), Se2::identity());
        let before = anchors.trajectory(&graph);
        assert_eq!(before[1].map(|p| p.x_m), Some(1.5));
        assert_eq!(before[2], None);
        // Moving the node moves its scans.
        if let Some(v) = graph.vertex_mut(NodeId(3)) {
            v.pose = Se2::new(0.0, 2.0, std::f64::consts::FRAC_PI_2);
        }
        let after = anchors.trajectory(&graph);
        let p = after[1].unwrap_or_else(Se2::identity);
        assert!((p.x_m - 0.0).abs() < 1e-12 && (p.y_m - 2.5).abs() < 1e-12);
    }

    #[test]
    fn scans_of_a_removed_node_hang_on_its_nearest_neighbour_where_they_were() {
        let mut graph = PoseGraph2::new();
        let poses = [
            (NodeId(1), Se2::new(0.0, 0.0, 0.0)),
            (NodeId(2), Se2::new(1.0, 0.0, 0.5)),
            (NodeId(4), Se2::new(2.0, 1.0, 1.0)),
            (NodeId(7), Se2::new(9.0, 9.0, 0.0)),
        ];
        let mut before = NodesBefore::new();
        for (node, pose) in poses {
            let _ = graph.add_vertex(node, Vertex::new(pose));
            // Node 7 is another graph's.
            before.insert(node, (u32::from(node.0 == 7), pose));
        }
        let mut anchors = ScanAnchors::new();
        anchors.push(NodeId(2), Se2::new(0.3, -0.2, 0.1));
        anchors.push(NodeId(4), Se2::identity());
        anchors.push(NodeId(7), Se2::identity());
        let was = anchors.trajectory(&graph);
        let _ = graph.remove_vertex(NodeId(2));
        let _ = graph.remove_vertex(NodeId(7));
        let remains = |n: NodeId| graph.vertex(n).is_some();
        assert_eq!(anchors.reanchor(&before, remains), 1);
        // Scan 0 now hangs on node 1 (nearer in id than 4), where it was; scan 2's graph is
        // gone.
        assert_eq!(anchors.get(0).map(|a| a.0), Some(NodeId(1)));
        let now = anchors.trajectory(&graph);
        let (a, b) = (was[0].unwrap(), now[0].unwrap());
        assert!(a.between(&b).translation().norm() < 1e-12);
        assert!(a.between(&b).theta_rad.abs() < 1e-12);
        assert_eq!(now[2], None);
    }
}
