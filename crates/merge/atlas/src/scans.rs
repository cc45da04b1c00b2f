//! Per-vertex scan data, stored once for the whole atlas.

use std::collections::BTreeMap;
use std::sync::Arc;

use mapmerge_posegraph::NodeId;
use mapmerge_scan::Point2;

/// The keyframe points of every vertex of the atlas (active graph, inactive graphs and the
/// vertices only a backup holds), in the vertex's robot frame, keyed by the globally unique
/// [`NodeId`].
///
/// Scans are never modified, so backups hold only graph structure (Holoch et al., Sec. III-B:
/// "it is sufficient to only backup the graph structure without duplicating the scans"). A
/// scan is shared (`Arc`) with whoever reads it and leaves the store only when its vertex is
/// pruned.
#[derive(Clone, Debug, Default)]
pub struct ScanStore {
    scans: BTreeMap<NodeId, Arc<[Point2]>>,
}

impl ScanStore {
    /// The points of `node` in its robot frame.
    pub fn get(&self, node: NodeId) -> Option<&Arc<[Point2]>> {
        self.scans.get(&node)
    }

    /// Number of scans stored.
    pub fn len(&self) -> usize {
        self.scans.len()
    }

    /// True when no scan is stored.
    pub fn is_empty(&self) -> bool {
        self.scans.is_empty()
    }

    /// Points over all scans (memory: 16 bytes each).
    pub fn total_points(&self) -> usize {
        self.scans.values().map(|s| s.len()).sum()
    }

    /// Every scan in id order.
    pub fn iter(&self) -> impl Iterator<Item = (NodeId, &Arc<[Point2]>)> + '_ {
        self.scans.iter().map(|(k, v)| (*k, v))
    }

    pub(crate) fn insert(&mut self, node: NodeId, points_in_robot: Arc<[Point2]>) {
        self.scans.insert(node, points_in_robot);
    }

    pub(crate) fn remove(&mut self, node: NodeId) -> Option<Arc<[Point2]>> {
        self.scans.remove(&node)
    }
}
