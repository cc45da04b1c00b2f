//! Every scan of the run in the frame of the map that holds it: each scan hangs on a keyframe
//! ([`ScanAnchors`]) and follows it through optimisation, merges and unmerges; maintenance
//! hangs the scans of removed keyframes on a remaining neighbour.

use std::collections::{BTreeMap, BTreeSet};

use mapmerge_atlas::{map_name, EpochId, MapId};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::NodeId;
use mapmerge_slam::NodesBefore;
use serde::Serialize;

use crate::Engine;

/// One scan of a map's trajectory.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MapScan {
    /// The scan's number in the run (from 0, over every epoch and session).
    pub scan: usize,
    /// The epoch it was taken in.
    pub epoch: u32,
    /// Its stamp as fed (s).
    pub stamp_secs: Option<f64>,
    pub map_from_robot: Se2,
}

/// A graph of the atlas with every scan of this run that hangs on it, in scan order.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MapTrajectory {
    /// `active` or `inactive-K` ([`map_name`]).
    pub map: String,
    /// Every epoch the graph holds (also those of a stored atlas, with no scans of this run).
    pub epochs: BTreeSet<u32>,
    pub scans: Vec<MapScan>,
}

/// Key of the active graph in [`NodesBefore`].
const ACTIVE: u32 = u32::MAX;

impl Engine {
    /// Every graph of the atlas (the active one first, then the inactive ones by id) with the
    /// scans of this run that hang on it, in the graph's frame. A merge still conditional is
    /// not applied. Scans whose graph maintenance dropped are in none.
    pub fn map_trajectories(&self) -> Vec<MapTrajectory> {
        let atlas = self.atlas();
        let graphs: Vec<(Option<MapId>, &mapmerge_posegraph::PoseGraph2)> =
            std::iter::once((None, atlas.active()))
                .chain(atlas.inactive_maps().map(|(id, g)| (Some(id), g)))
                .collect();
        let mut graph_of_node: BTreeMap<NodeId, usize> = BTreeMap::new();
        for (k, (_, graph)) in graphs.iter().enumerate() {
            graph_of_node.extend(graph.vertices().map(|(node, _)| (node, k)));
        }
        let mut trajectories: Vec<MapTrajectory> = graphs
            .iter()
            .map(|(id, graph)| MapTrajectory {
                map: map_name(*id),
                epochs: mapmerge_atlas::epochs_of(graph)
                    .into_iter()
                    .map(|e| e.0)
                    .collect(),
                scans: Vec::new(),
            })
            .collect();
        for (scan, (node, node_from_robot)) in self.anchors.iter().enumerate() {
            let Some(&k) = graph_of_node.get(&node) else {
                continue;
            };
            let Some(vertex) = graphs[k].1.vertex(node) else {
                continue;
            };
            trajectories[k].scans.push(MapScan {
                scan,
                epoch: EpochId::of(&vertex.meta).0,
                stamp_secs: self.stamps.get(scan).copied().flatten(),
                map_from_robot: vertex.pose.compose(&node_from_robot),
            });
        }
        trajectories.retain(|t| !t.epochs.is_empty());
        trajectories
    }

    /// Every node of the atlas with its graph and pose (before maintenance removes some).
    pub(crate) fn nodes_before(&self) -> NodesBefore {
        let atlas = self.atlas();
        std::iter::once((ACTIVE, atlas.active()))
            .chain(atlas.inactive_maps().map(|(id, g)| (id.0, g)))
            .flat_map(|(key, graph)| graph.vertices().map(move |(n, v)| (n, (key, v.pose))))
            .collect()
    }
}
