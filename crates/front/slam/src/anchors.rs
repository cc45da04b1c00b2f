//! Every scan of a log anchored to a keyframe node, so its pose follows the optimised graph.

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::{NodeId, PoseGraph};
use serde::{Deserialize, Serialize};

/// For each scan, in log order: the keyframe node it hangs on and its pose in that node's
/// frame (`node_from_robot`). A keyframe's own scan hangs on its node at the identity.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ScanAnchors {
    anchors: Vec<(NodeId, Se2)>,
}

impl ScanAnchors {
    /// No scans yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Anchors the next scan to `node` at `node_from_robot`.
    pub fn push(&mut self, node: NodeId, node_from_robot: Se2) {
        self.anchors.push((node, node_from_robot));
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
}
