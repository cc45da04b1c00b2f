//! Every keyframe of the atlas, stored once.

use std::collections::BTreeMap;
use std::sync::Arc;

use mapmerge_geometry::Se2;
use mapmerge_posegraph::NodeId;
use mapmerge_scan::Point2;

/// One keyframe's data besides its vertex.
#[derive(Clone, Debug, PartialEq)]
pub struct KeyframeRecord {
    /// Points in the vertex's robot frame, shared (`Arc`) with whoever reads them.
    pub points_in_robot: Arc<[Point2]>,
    /// Robot travel within its epoch up to this keyframe (m, tracker estimate; for imported
    /// graphs the path length along the vertices in id order).
    pub travel_m: f64,
    /// Its pose in the tracker's local frame of its epoch (imported graphs: the vertex pose).
    pub local_from_robot: Se2,
    /// The anchor of the tracker's submap it was first inserted into (none for keyframes
    /// that did not come from the tracker).
    pub submap: Option<NodeId>,
}

/// The keyframes of every vertex of the atlas (active graph, inactive graphs and the
/// vertices only a backup holds), keyed by the globally unique [`NodeId`].
///
/// Keyframes are never modified, so backups hold only graph structure (Holoch et al., Sec.
/// III-B: "it is sufficient to only backup the graph structure without duplicating the
/// scans"). A keyframe leaves the store only when its vertex is pruned.
#[derive(Clone, Debug, Default)]
pub struct KeyframeStore {
    keyframes: BTreeMap<NodeId, KeyframeRecord>,
}

impl KeyframeStore {
    /// The points of `node` in its robot frame.
    pub fn get(&self, node: NodeId) -> Option<&Arc<[Point2]>> {
        self.keyframes.get(&node).map(|k| &k.points_in_robot)
    }

    /// Everything stored of `node`.
    pub fn record(&self, node: NodeId) -> Option<&KeyframeRecord> {
        self.keyframes.get(&node)
    }

    /// Number of keyframes stored.
    pub fn len(&self) -> usize {
        self.keyframes.len()
    }

    /// True when no keyframe is stored.
    pub fn is_empty(&self) -> bool {
        self.keyframes.is_empty()
    }

    /// Points over all keyframes (memory: 16 bytes each).
    pub fn total_points(&self) -> usize {
        self.keyframes
            .values()
            .map(|k| k.points_in_robot.len())
            .sum()
    }

    /// Every keyframe's points in id order.
    pub fn iter(&self) -> impl Iterator<Item = (NodeId, &Arc<[Point2]>)> + '_ {
        self.keyframes.iter().map(|(k, v)| (*k, &v.points_in_robot))
    }

    /// Every keyframe's record in id order.
    pub fn records(&self) -> impl Iterator<Item = (NodeId, &KeyframeRecord)> + '_ {
        self.keyframes.iter().map(|(k, v)| (*k, v))
    }

    /// The records of `node` and every keyframe before it, in id order (newest last).
    pub fn records_up_to(
        &self,
        node: NodeId,
    ) -> impl DoubleEndedIterator<Item = (NodeId, &KeyframeRecord)> + '_ {
        self.keyframes.range(..=node).map(|(k, v)| (*k, v))
    }

    pub(crate) fn insert(&mut self, node: NodeId, record: KeyframeRecord) {
        self.keyframes.insert(node, record);
    }

    pub(crate) fn remove(&mut self, node: NodeId) -> Option<KeyframeRecord> {
        self.keyframes.remove(&node)
    }
}
