//! The atlas as a value, to persist it between runs (the lifelong store, iRobot Sec. 4) and
//! to bring it back.
//!
//! A snapshot holds what the atlas owns for good: every graph, every keyframe, the backups
//! that keep merges into the active graph undoable, and the counters that keep ids unique.
//! The place index is not in it: [`Atlas::restore`] rebuilds it from the keyframes. Per-run
//! bookkeeping (the current epoch's finished submaps, loop statistics, the event list) is not
//! either: a restored atlas continues with a new epoch in practice, which starts all of it
//! afresh.

use std::collections::BTreeMap;
use std::sync::Arc;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::{NodeId, PoseGraph2};
use serde::{Deserialize, Serialize};

use crate::atlas::{AppliedMerge, Atlas, AtlasParams};
use crate::backup::BackupStore;
use crate::constraints::ConstraintBuilder;
use crate::error::AtlasError;
use crate::ids::{EpochId, MapId, MergeId};
use crate::keyframes::{KeyframeRecord, KeyframeStore};
use crate::local_maps::{LocalMapGrid, RenderedMap};
use crate::maintenance::ViewUse;

/// The atlas's bookkeeping besides its graphs, keyframes and backups (small: stored whole
/// with every version).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AtlasCounters {
    /// The current epoch.
    pub epoch: EpochId,
    /// The id the next vertex, epoch, inactive graph and merge will get.
    pub next_node: u64,
    /// …
    pub next_epoch: u32,
    /// …
    pub next_map: u32,
    /// …
    pub next_merge: u64,
    /// The robot's newest vertex in the active graph.
    pub robot: Option<NodeId>,
    /// The merges into the active graph that can still be undone, oldest first.
    pub merges: Vec<AppliedMerge>,
    /// The tracker's local frame of the current epoch in the active graph's frame.
    pub map_from_local: Se2,
    /// Maintenance sessions so far.
    pub sessions: u32,
    /// How each view has been used.
    pub views: BTreeMap<NodeId, ViewUse>,
    /// The first vertex of each recent session, oldest first.
    pub session_first_nodes: Vec<NodeId>,
}

/// Everything the atlas owns for good (see the module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct AtlasSnapshot {
    /// Ids and the undoable merges.
    pub counters: AtlasCounters,
    /// The active graph.
    pub active: PoseGraph2,
    /// The inactive graphs.
    pub inactive: BTreeMap<MapId, PoseGraph2>,
    /// Every keyframe (of every graph and of the vertices only a backup holds).
    pub keyframes: BTreeMap<NodeId, KeyframeRecord>,
    /// The backup of every undoable merge.
    pub backups: BTreeMap<MergeId, PoseGraph2>,
    /// Local maps by anchor vertex.
    pub local_maps: BTreeMap<NodeId, LocalMapGrid>,
}

impl AtlasSnapshot {
    /// Vertices over the active and the inactive graphs.
    pub fn num_vertices(&self) -> usize {
        self.graphs().map(PoseGraph2::num_vertices).sum()
    }

    /// Edges over the active and the inactive graphs.
    pub fn num_edges(&self) -> usize {
        self.graphs().map(PoseGraph2::num_edges).sum()
    }

    /// The active graph, then the inactive ones in id order.
    pub fn graphs(&self) -> impl Iterator<Item = &PoseGraph2> + '_ {
        std::iter::once(&self.active).chain(self.inactive.values())
    }

    /// Local maps.
    pub fn num_local_maps(&self) -> usize {
        self.local_maps.len()
    }

    /// The site map: the largest graph (most vertices), where a lifelong robot's sessions
    /// join; `None` without vertices.
    pub fn site_graph(&self) -> Option<&PoseGraph2> {
        self.graphs()
            .filter(|g| g.num_vertices() > 0)
            .max_by_key(|g| g.num_vertices())
    }

    /// The area the atlas has mapped (m²), summed over its graphs (separate graphs may cover
    /// the same place): the known cells of each graph's rendered local maps, or, for a graph
    /// without local maps, the cells its keyframes' beams crossed.
    pub fn mapped_area_m2(&self, resolution_m: f64) -> f64 {
        self.graphs()
            .map(|graph| self.graph_area_m2(graph, resolution_m))
            .sum()
    }

    /// The area one graph has mapped (m²): the known cells of its rendered local maps, or,
    /// without local maps, the cells its keyframes' beams crossed.
    pub fn graph_area_m2(&self, graph: &PoseGraph2, resolution_m: f64) -> f64 {
        let thresholds = mapmerge_grid::ClassThresholds::default();
        if let Some(rendered) = RenderedMap::render(graph, &self.local_maps, resolution_m) {
            return rendered.known_area_m2(&thresholds);
        }
        let rays: Vec<_> = graph
            .vertices()
            .filter_map(|(node, vertex)| Some((vertex.pose, self.keyframes.get(&node)?)))
            .flat_map(|(pose, keyframe)| {
                let origin = pose.translation();
                keyframe
                    .points_in_robot
                    .iter()
                    .map(move |p| (origin, pose.transform_point(p)))
                    .collect::<Vec<_>>()
            })
            .collect();
        // Coarser cells for a site too large for the grid.
        let mut resolution = resolution_m;
        loop {
            match mapmerge_grid::FreeSpace::from_rays(resolution, rays.iter().copied()) {
                Ok(free) => break free.free_cells() as f64 * resolution * resolution,
                Err(_) if resolution < 100.0 => resolution *= 2.0,
                Err(_) => break 0.0,
            }
        }
    }

    /// Checks what [`Atlas::restore`] relies on: ids below the counters, no vertex in two
    /// graphs, the robot in the active graph, a backup for every undoable merge, finite
    /// local maps of the right size. The reason names the first violation. (A vertex may lack
    /// a keyframe: maintenance keeps vertices that anchor only a local map.)
    pub fn validate(&self) -> Result<(), String> {
        let c = &self.counters;
        let mut seen: BTreeMap<NodeId, &'static str> = BTreeMap::new();
        let graphs = std::iter::once(("active", &self.active))
            .chain(self.inactive.values().map(|g| ("inactive", g)));
        for (name, graph) in graphs {
            for (node, _) in graph.vertices() {
                if node.0 >= c.next_node {
                    return Err(format!(
                        "vertex {node} is not below the next id {}",
                        c.next_node
                    ));
                }
                if seen.insert(node, name).is_some() {
                    return Err(format!("vertex {node} is in two graphs"));
                }
            }
        }
        if let Some(node) = self.keyframes.keys().find(|n| n.0 >= c.next_node) {
            return Err(format!(
                "keyframe {node} is not below the next id {}",
                c.next_node
            ));
        }
        if let Some(map) = self.inactive.keys().find(|m| m.0 >= c.next_map) {
            return Err(format!("{map} is not below the next id {}", c.next_map));
        }
        if let Some(robot) = c.robot {
            if !self.active.contains_vertex(robot) {
                return Err(format!(
                    "the robot's vertex {robot} is not in the active graph"
                ));
            }
        }
        if c.epoch.0 >= c.next_epoch {
            return Err(format!(
                "{} is not below the next id {}",
                c.epoch, c.next_epoch
            ));
        }
        for merge in &c.merges {
            if merge.merge.0 >= c.next_merge {
                return Err(format!(
                    "{} is not below the next id {}",
                    merge.merge, c.next_merge
                ));
            }
            if !self.backups.contains_key(&merge.merge) {
                return Err(format!("{} has no backup", merge.merge));
            }
        }
        if !c.map_from_local.is_finite() {
            return Err("the tracker's frame is not finite".into());
        }
        for (anchor, map) in &self.local_maps {
            let cells = map.width as usize * map.height as usize;
            if map.cells.len() != cells
                || !(map.resolution_m.is_finite() && map.resolution_m > 0.0)
                || !map.origin_m.iter().all(|x| x.is_finite())
            {
                return Err(format!("the local map at {anchor} is malformed"));
            }
        }
        Ok(())
    }
}

impl<B: BackupStore> Atlas<B> {
    /// The atlas as a value (graphs cloned, keyframe points shared). Fails only when a backup
    /// cannot be read.
    pub fn snapshot(&self) -> Result<AtlasSnapshot, AtlasError> {
        let backups = self
            .merges
            .iter()
            .map(|m| Ok((m.merge, self.backups.load(m.merge)?)))
            .collect::<Result<_, AtlasError>>()?;
        Ok(AtlasSnapshot {
            counters: AtlasCounters {
                epoch: self.epoch,
                next_node: self.next_node,
                next_epoch: self.next_epoch,
                next_map: self.next_map,
                next_merge: self.next_merge,
                robot: self.robot,
                merges: self.merges.clone(),
                map_from_local: self.map_from_local,
                sessions: self.sessions,
                views: self.views.clone(),
                session_first_nodes: self.session_first_nodes.clone(),
            },
            active: self.active.clone(),
            inactive: self.inactive.clone(),
            keyframes: self
                .keyframes
                .records()
                .map(|(node, record)| (node, record.clone()))
                .collect(),
            backups,
            local_maps: self.local_maps.clone(),
        })
    }

    /// The atlas a snapshot describes, with `params` and the backups in `backups` (the
    /// snapshot's are stored into it). The place index is rebuilt from the keyframes: every
    /// vertex of every graph is indexed, without a submap. Fails on an inconsistent snapshot
    /// ([`AtlasSnapshot::validate`]), bad parameters or a backup that cannot be written.
    pub fn restore(
        params: AtlasParams,
        mut backups: B,
        snapshot: AtlasSnapshot,
    ) -> Result<Self, AtlasError> {
        snapshot.validate().map_err(AtlasError::BadSnapshot)?;
        for (merge, graph) in &snapshot.backups {
            backups.store(*merge, graph)?;
        }
        let c = snapshot.counters;
        let mut keyframes = KeyframeStore::default();
        for (node, record) in snapshot.keyframes {
            keyframes.insert(node, record);
        }
        let epoch = c.epoch;
        let mut atlas = Self {
            constraints: ConstraintBuilder::new(&params)?,
            map_from_local: c.map_from_local,
            params,
            epoch,
            active: snapshot.active,
            robot: c.robot,
            merges: c.merges,
            inactive: snapshot.inactive,
            keyframes,
            backups,
            next_node: c.next_node,
            next_epoch: c.next_epoch,
            next_map: c.next_map,
            next_merge: c.next_merge,
            events: Vec::new(),
            local_maps: snapshot.local_maps,
            views: c.views,
            sessions: c.sessions,
            session_first_nodes: c.session_first_nodes,
        };
        let maps: Vec<MapId> = atlas.inactive.keys().copied().collect();
        for map in maps {
            let nodes: Vec<NodeId> = atlas.inactive[&map].vertices().map(|(n, _)| n).collect();
            atlas.index_nodes_of(Some(map), &nodes, None);
        }
        let nodes: Vec<NodeId> = atlas.active.vertices().map(|(n, _)| n).collect();
        atlas.index_nodes_of(None, &nodes, None);
        atlas.constraints.epoch_keyframes = atlas
            .active
            .vertices()
            .filter(|(_, v)| EpochId::of(&v.meta) == epoch)
            .count();
        // A snapshot between sessions (the store's) resumes at a new session's start.
        atlas.constraints.session_start = atlas.constraints.epoch_keyframes == 0;
        atlas.constraints.travel_m = c
            .robot
            .and_then(|r| atlas.keyframes.record(r))
            .map_or(0.0, |k| k.travel_m);
        Ok(atlas)
    }
}

/// Keyframe points as raw little-endian `f64` pairs `x_m, y_m` (16 bytes a point): the
/// store's encoding (docs/formats.md).
pub fn points_to_le_bytes(points: &[mapmerge_scan::Point2]) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(points.len() * 16);
    for p in points {
        bytes.extend_from_slice(&p.x.to_le_bytes());
        bytes.extend_from_slice(&p.y.to_le_bytes());
    }
    bytes
}

/// The inverse of [`points_to_le_bytes`]; `None` when the length is not a multiple of 16.
pub fn points_from_le_bytes(bytes: &[u8]) -> Option<Arc<[mapmerge_scan::Point2]>> {
    if bytes.len() % 16 != 0 {
        return None;
    }
    let value = |b: &[u8]| -> Option<f64> { Some(f64::from_le_bytes(b.try_into().ok()?)) };
    bytes
        .chunks_exact(16)
        .map(|c| {
            Some(mapmerge_scan::Point2::new(
                value(c.get(..8)?)?,
                value(c.get(8..)?)?,
            ))
        })
        .collect()
}
