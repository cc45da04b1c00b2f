//! Keeping a lifelong atlas bounded (iRobot, Sec. 4): after each session, when no merge can be
//! undone any more, the atlas
//!
//! 1. builds a local map for each of the session's tracker submaps from its keyframes
//!    ([`crate::LocalMapGrid`]);
//! 2. drops fragments: inactive graphs, other than the largest, that no session of the last
//!    `stale_after_sessions` added to (epochs place recognition never joined to the site's
//!    map; iRobot keeps one map per robot);
//! 3. counts which older views (keyframes) the session re-observed: a loop or merge edge
//!    between one of its vertices and the older vertex (Sec. 4.1's observation statistics);
//! 4. prunes views by the information each adds (Sec. 4.1): from the most useful down, a view
//!    is kept when no kept view of its graph lies within `view_radius_m` (a view in recent
//!    use) or `stale_view_radius_m` (any other) and `view_heading_rad`, so every region keeps
//!    a view to relocalise from; or when it is in recent use and at least
//!    `view_min_new_fraction` of its returns fall where no kept view saw structure. Once a
//!    place is covered, a session's views replace, not add;
//! 5. prunes local maps greedily, oldest first, while the rendered map's class changes stay
//!    within `local_map_tolerance` of its known cells (Sec. 4.3, Eq. 9, with q = the
//!    fraction of cells whose class changes);
//! 6. marginalises every vertex that anchors neither a view nor a local map by a Chow–Liu
//!    tree ([`mapmerge_posegraph::PoseGraph::marginalize_vertex`], Sec. 4.2);
//! 7. prunes edges to `max_edges_per_vertex · |V|` ([`mapmerge_posegraph::PoseGraph::prune_edges`]).

use std::collections::{BTreeMap, BTreeSet, HashSet};
use std::time::Instant;

use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_grid::{CellClass, ClassThresholds};
use mapmerge_posegraph::{EdgeKind, NodeId, PoseGraph2};
use serde::{Deserialize, Serialize};

use crate::atlas::Atlas;
use crate::backup::BackupStore;
use crate::error::AtlasError;
use crate::ids::MapId;
use crate::local_maps::{LocalMapGrid, RenderedMap};

/// Parameters of [`Atlas::maintain`], one default for every site.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MaintenanceParams {
    /// Prune views, local maps, vertices and edges (default: true). Without, only local maps
    /// are built and views counted (the unpruned baseline).
    pub prune: bool,
    /// Cell side of local maps and of the rendered map (m) (default: 0.05).
    pub resolution_m: f64,
    /// A view may be redundant when a kept view of its graph lies within this distance (m)
    /// (default: 0.75, chosen on the simulator's tuning seed 3: over 22 sessions 16 of 34
    /// epochs merged, against 10 at 1.5 m and 24 of 32 unpruned)…
    pub view_radius_m: f64,
    /// … and heading (rad) (default: π, any heading: a 360° scan relocalises from any
    /// direction; use π/2 for lasers of 180°) …
    pub view_heading_rad: f64,
    /// A view not in recent use (neither made nor re-observed in the last `recent_sessions`)
    /// is redundant when a kept view lies within this larger distance (m) (default: 2, the
    /// verifier's window): where sessions no longer drive, the map keeps a sparser net of
    /// views and the net of the paths driven lately stays fine, so the views stop filling in
    /// as sessions pass (iRobot Sec. 4.1: outdated views go where others remain) …
    pub stale_view_radius_m: f64,
    /// … and a view is redundant unless it is in recent use (and [`ViewUse::utility`] ≥ 1) and
    /// at least this fraction of its returns fall in cells (`view_cell_m`) where no kept view of
    /// its graph saw structure: what it adds to the map (default: 0.3; above 1: by distance
    /// alone, a fixed net).
    pub view_min_new_fraction: f64,
    /// Cell side (m) at which returns count as the same structure (default: 0.2, a few
    /// times the trackers' drift between sessions).
    pub view_cell_m: f64,
    /// Sessions that count as recent for a view's short-term use (default: 5).
    pub recent_sessions: u32,
    /// ε_q of Eq. 9: the largest fraction of the rendered map's known cells whose class
    /// local-map pruning may change (default: 0.01).
    pub local_map_tolerance: f64,
    /// `c` of `|E| ≤ c·|V|` (default: 2).
    pub max_edges_per_vertex: f64,
    /// An inactive graph that no session of the last this many added to, and that is not the
    /// largest, is dropped: a fragment place recognition never joined to the site's map
    /// (default: 5; 0 keeps every graph).
    pub stale_after_sessions: u32,
    /// Fragments searched for in the site map before maintenance, and joined to it when
    /// found ([`Atlas::rejoin_fragments`]).
    pub rejoin: crate::RejoinParams,
}

impl Default for MaintenanceParams {
    fn default() -> Self {
        Self {
            prune: true,
            resolution_m: 0.05,
            view_radius_m: 0.75,
            view_heading_rad: std::f64::consts::PI,
            stale_view_radius_m: 2.0,
            view_min_new_fraction: 0.3,
            view_cell_m: 0.2,
            recent_sessions: 5,
            local_map_tolerance: 0.01,
            max_edges_per_vertex: 2.0,
            stale_after_sessions: 5,
            rejoin: crate::RejoinParams::default(),
        }
    }
}

/// How a view has been used: Sec. 4.1's short- and long-term observation statistics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ViewUse {
    /// The maintenance session that saw it first.
    pub created_session: u32,
    /// Sessions that re-observed it.
    pub observations: u32,
    /// The last session that did.
    pub last_observed_session: Option<u32>,
}

impl ViewUse {
    /// Usefulness at `session`: re-observed recently (short term) counts most, then how
    /// often it was re-observed per session of its life (long term); a view of this session
    /// has not had its chance yet and counts as recent.
    pub fn utility(&self, session: u32, recent_sessions: u32) -> f64 {
        let age = f64::from(session.saturating_sub(self.created_session) + 1);
        let recent = match self.last_observed_session {
            Some(last) => session.saturating_sub(last) < recent_sessions,
            None => self.created_session == session,
        };
        f64::from(u8::from(recent)) + f64::from(self.observations) / age
    }

    /// Made or re-observed in the last `recent_sessions` sessions before `session`.
    pub fn is_recent(&self, session: u32, recent_sessions: u32) -> bool {
        let last = self
            .last_observed_session
            .unwrap_or(0)
            .max(self.created_session);
        session.saturating_sub(last) < recent_sessions
    }
}

/// What [`Atlas::maintain`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MaintenanceReport {
    /// The maintenance session's number (from 0).
    pub session: u32,
    /// Local maps built from the session's submaps.
    pub local_maps_built: usize,
    /// Older views the session re-observed.
    pub views_observed: usize,
    /// Views (keyframes) deleted.
    pub views_pruned: usize,
    /// Local maps deleted, and the fraction of the rendered map's known cells whose class
    /// that changed (≤ ε_q).
    pub local_maps_pruned: usize,
    pub class_change_fraction: f64,
    /// Vertices marginalised, and edges pruned afterwards.
    pub vertices_marginalized: usize,
    pub edges_pruned: usize,
    /// Stale fragments dropped, with their vertices.
    pub maps_dropped: usize,
    pub vertices_dropped: usize,
    /// Time taken (s).
    pub seconds: f64,
}

impl<B: BackupStore> Atlas<B> {
    /// Maintains the atlas after a session (see the module documentation). The session's
    /// vertices are those from `first_node` on. Refused while a merge into the active graph
    /// can be undone (pruning would break its backup; Holoch et al., Sec. III-B): call it
    /// after [`Atlas::end_epoch`]. On an error the atlas may have been partly maintained but
    /// is consistent.
    pub fn maintain(
        &mut self,
        params: &MaintenanceParams,
        first_node: NodeId,
    ) -> Result<MaintenanceReport, AtlasError> {
        let started = Instant::now();
        if self.is_undoable() {
            return Err(AtlasError::Config(
                "maintenance waits until no merge can be undone (end the epoch first)".into(),
            ));
        }
        let session = self.sessions;
        let mut report = MaintenanceReport {
            session,
            ..MaintenanceReport::default()
        };
        // 1. Local maps of the session's submaps (keyframes without a submap: their own).
        report.local_maps_built = self.build_local_maps(params, first_node)?;
        // 2. Views: new ones enter, re-observed ones count.
        for (node, _) in self.keyframes.records() {
            self.views.entry(node).or_insert(ViewUse {
                created_session: session,
                ..ViewUse::default()
            });
        }
        let observed = self.reobserved_views(first_node);
        report.views_observed = observed.len();
        for node in observed {
            if let Some(view) = self.views.get_mut(&node) {
                view.observations += 1;
                view.last_observed_session = Some(session);
            }
        }
        self.session_first_nodes.push(first_node);
        let keep = params.stale_after_sessions as usize;
        if self.session_first_nodes.len() > keep {
            let excess = self.session_first_nodes.len() - keep;
            self.session_first_nodes.drain(..excess);
        }
        if params.prune {
            (report.maps_dropped, report.vertices_dropped) = self.drop_stale_maps(params);
            report.views_pruned = self.prune_views(params);
            let (pruned, fraction) = self.prune_local_maps(params);
            report.local_maps_pruned = pruned;
            report.class_change_fraction = fraction;
            report.vertices_marginalized = self.marginalize_bare_vertices()?;
            for graph in self.graphs_mut() {
                report.edges_pruned += graph.prune_edges(params.max_edges_per_vertex).len();
            }
        }
        self.sessions += 1;
        report.seconds = started.elapsed().as_secs_f64();
        Ok(report)
    }

    /// Drops every inactive graph but the largest to which none of the last
    /// `stale_after_sessions` sessions added a vertex, with its keyframes, local maps and
    /// views. Returns the graphs and vertices dropped.
    fn drop_stale_maps(&mut self, params: &MaintenanceParams) -> (usize, usize) {
        let keep = params.stale_after_sessions as usize;
        if keep == 0 || self.session_first_nodes.len() < keep {
            return (0, 0);
        }
        let Some(oldest_recent) = self.session_first_nodes.first().copied() else {
            return (0, 0);
        };
        let largest = self.site_map();
        let stale: Vec<MapId> = self
            .inactive
            .iter()
            .filter(|(m, g)| {
                Some(**m) != largest
                    && g.vertices()
                        .map(|(n, _)| n)
                        .max()
                        .is_none_or(|n| n < oldest_recent)
            })
            .map(|(m, _)| *m)
            .collect();
        let mut vertices = 0;
        for map in &stale {
            if let Some(graph) = self.inactive.remove(map) {
                for (node, _) in graph.vertices() {
                    self.keyframes.remove(node);
                    self.local_maps.remove(&node);
                    self.views.remove(&node);
                    vertices += 1;
                }
            }
        }
        (stale.len(), vertices)
    }

    /// The active graph and every inactive one.
    fn graphs_mut(&mut self) -> impl Iterator<Item = &mut PoseGraph2> + '_ {
        std::iter::once(&mut self.active).chain(self.inactive.values_mut())
    }

    /// The graph holding `node`, by map (`None`: the active graph).
    fn graph_of(&self, node: NodeId) -> Option<(Option<MapId>, &PoseGraph2)> {
        if self.active.contains_vertex(node) {
            return Some((None, &self.active));
        }
        self.inactive
            .iter()
            .find(|(_, g)| g.contains_vertex(node))
            .map(|(m, g)| (Some(*m), g))
    }

    fn build_local_maps(
        &mut self,
        params: &MaintenanceParams,
        first_node: NodeId,
    ) -> Result<usize, AtlasError> {
        let mut members: BTreeMap<NodeId, Vec<NodeId>> = BTreeMap::new();
        for (node, record) in self.keyframes.records() {
            if node >= first_node {
                members
                    .entry(record.submap.unwrap_or(node))
                    .or_default()
                    .push(node);
            }
        }
        let mut built = 0;
        for (anchor, nodes) in members {
            if self.local_maps.contains_key(&anchor) {
                continue;
            }
            let Some((_, graph)) = self.graph_of(anchor) else {
                continue;
            };
            let Some(anchor_pose) = graph.vertex(anchor).map(|v| v.pose) else {
                continue;
            };
            let keyframes: Vec<(Se2, &[mapmerge_scan::Point2])> = nodes
                .iter()
                .filter_map(|n| {
                    let pose = graph.vertex(*n)?.pose;
                    let points = self.keyframes.get(*n)?;
                    Some((anchor_pose.between(&pose), &points[..]))
                })
                .collect();
            let map = LocalMapGrid::from_keyframes(params.resolution_m, keyframes)?;
            self.local_maps.insert(anchor, map);
            built += 1;
        }
        Ok(built)
    }

    /// Older vertices (before `first_node`) joined to one of the session's by a loop or
    /// merge edge.
    fn reobserved_views(&self, first_node: NodeId) -> BTreeSet<NodeId> {
        let mut observed = BTreeSet::new();
        for graph in std::iter::once(&self.active).chain(self.inactive.values()) {
            for (_, edge) in graph.edges() {
                if !matches!(edge.kind, EdgeKind::Loop | EdgeKind::Merge) {
                    continue;
                }
                let (a, b) = (edge.from, edge.to);
                if a >= first_node && b < first_node {
                    observed.insert(b);
                } else if b >= first_node && a < first_node {
                    observed.insert(a);
                }
            }
        }
        observed
    }

    /// Sec. 4.1: keeps, from the most useful view down, every view with no kept view of its
    /// graph nearby, and every view in recent use that adds structure no kept view saw
    /// (see [`MaintenanceParams::view_min_new_fraction`]); deletes the others' keyframes.
    /// Returns how many were deleted.
    fn prune_views(&mut self, params: &MaintenanceParams) -> usize {
        let session = self.sessions;
        // (utility, node, graph, pose, in recent use)
        let mut ranked: Vec<(f64, NodeId, Option<MapId>, Se2, bool)> = self
            .keyframes
            .records()
            .filter_map(|(node, _)| {
                let (map, graph) = self.graph_of(node)?;
                let pose = graph.vertex(node)?.pose;
                let view = self.views.get(&node);
                let utility = view.map_or(1.0, |v| v.utility(session, params.recent_sessions));
                let recent = view.is_none_or(|v| v.is_recent(session, params.recent_sessions));
                Some((utility, node, map, pose, recent))
            })
            .collect();
        // Most useful first; among equals the newest (its scan is the most up to date).
        ranked.sort_by(|a, b| b.0.total_cmp(&a.0).then(b.1.cmp(&a.1)));
        // Kept views by graph and grid cell (side: the larger radius); the structure cells
        // the kept views saw, by graph.
        let radius = params.view_radius_m.max(1e-3);
        let stale_radius = params.stale_view_radius_m.max(radius);
        let structure_cell = params.view_cell_m.max(1e-3);
        let mut kept: BTreeMap<(Option<MapId>, i64, i64), Vec<Se2>> = BTreeMap::new();
        let mut seen: BTreeMap<Option<MapId>, HashSet<(i64, i64)>> = BTreeMap::new();
        let mut deleted = Vec::new();
        for (utility, node, map, pose, recent) in ranked {
            let reach = if recent { radius } else { stale_radius };
            let (cx, cy) = (
                (pose.x_m / stale_radius).floor() as i64,
                (pose.y_m / stale_radius).floor() as i64,
            );
            let near = (cx - 1..=cx + 1).any(|x| {
                (cy - 1..=cy + 1).any(|y| {
                    kept.get(&(map, x, y)).is_some_and(|poses| {
                        poses.iter().any(|other| {
                            (other.translation() - pose.translation()).norm() <= reach
                                && wrap_angle_rad(other.theta_rad - pose.theta_rad).abs()
                                    <= params.view_heading_rad
                        })
                    })
                })
            });
            if near && !recent {
                deleted.push(node);
                continue;
            }
            // The structure cells its returns fall in (map frame).
            let cells: HashSet<(i64, i64)> = self
                .keyframes
                .get(node)
                .map(|points| {
                    points
                        .iter()
                        .map(|p| {
                            let q = pose.transform_point(p);
                            (
                                (q.x / structure_cell).floor() as i64,
                                (q.y / structure_cell).floor() as i64,
                            )
                        })
                        .collect()
                })
                .unwrap_or_default();
            let seen_here = seen.entry(map).or_default();
            let adds = || {
                let new = cells.iter().filter(|c| !seen_here.contains(c)).count();
                utility >= 1.0
                    && !cells.is_empty()
                    && new as f64 >= params.view_min_new_fraction * cells.len() as f64
            };
            if near && !adds() {
                deleted.push(node);
            } else {
                kept.entry((map, cx, cy)).or_default().push(pose);
                seen_here.extend(cells);
            }
        }
        for node in &deleted {
            self.keyframes.remove(*node);
            self.views.remove(node);
        }
        deleted.len()
    }

    /// Sec. 4.3, Eq. 9, greedily: per graph, most redundant local map first, one goes when
    /// the rendered map without it (and without those gone before) still has at most
    /// `local_map_tolerance` of its known cells in another class. Returns how many went and
    /// the largest fraction reached in a graph.
    fn prune_local_maps(&mut self, params: &MaintenanceParams) -> (usize, f64) {
        let thresholds = ClassThresholds::default();
        let mut pruned = Vec::new();
        let mut worst = 0.0f64;
        for graph in std::iter::once(&self.active).chain(self.inactive.values()) {
            let Some(mut rendered) =
                RenderedMap::render(graph, &self.local_maps, params.resolution_m)
            else {
                continue;
            };
            let reference = rendered.classes(&thresholds);
            let known = reference
                .iter()
                .filter(|c| **c != CellClass::Unknown)
                .count();
            let budget = (params.local_map_tolerance * known as f64).floor() as usize;
            let mut changed = vec![false; reference.len()];
            let mut changed_count = 0usize;
            // The heuristic order: the local maps whose removal alone changes the fewest
            // cells first (the most redundant), older first among equals.
            let mut anchors: Vec<(usize, NodeId)> = rendered
                .contributions
                .iter()
                .map(|(anchor, contribution)| {
                    let cost = contribution
                        .iter()
                        .filter(|(index, l)| {
                            let i = *index as usize;
                            match (rendered.sums.get(i), reference.get(i)) {
                                (Some(sum), Some(class)) => thresholds.classify(sum - l) != *class,
                                _ => false,
                            }
                        })
                        .count();
                    (cost, *anchor)
                })
                .collect();
            anchors.sort();
            for (_, anchor) in anchors {
                let Some(contribution) = rendered.contributions.get(&anchor) else {
                    continue;
                };
                // Take it out; count cells whose class differs from the reference anew.
                let mut newly = Vec::new();
                let mut restored = Vec::new();
                for (index, l) in contribution {
                    let i = *index as usize;
                    let (Some(sum), Some(class)) = (rendered.sums.get_mut(i), reference.get(i))
                    else {
                        continue;
                    };
                    *sum -= l;
                    let differs = thresholds.classify(*sum) != *class;
                    match (differs, changed.get(i).copied().unwrap_or(false)) {
                        (true, false) => newly.push(i),
                        (false, true) => restored.push(i),
                        _ => {}
                    }
                }
                let total = changed_count + newly.len() - restored.len();
                if total <= budget {
                    for i in &newly {
                        changed[*i] = true;
                    }
                    for i in &restored {
                        changed[*i] = false;
                    }
                    changed_count = total;
                    rendered.contributions.remove(&anchor);
                    pruned.push(anchor);
                } else {
                    for (index, l) in contribution {
                        if let Some(sum) = rendered.sums.get_mut(*index as usize) {
                            *sum += l;
                        }
                    }
                }
            }
            if known > 0 {
                worst = worst.max(changed_count as f64 / known as f64);
            }
        }
        for anchor in &pruned {
            self.local_maps.remove(anchor);
        }
        (pruned.len(), worst)
    }

    /// Sec. 4.2: every vertex of every graph that anchors neither a keyframe nor a local map
    /// (and is not the robot's) is marginalised. Returns how many.
    fn marginalize_bare_vertices(&mut self) -> Result<usize, AtlasError> {
        let robot = self.robot;
        let bare = |graph: &PoseGraph2,
                    keyframes: &crate::KeyframeStore,
                    local_maps: &BTreeMap<NodeId, LocalMapGrid>| {
            graph
                .vertices()
                .map(|(n, _)| n)
                .filter(|n| {
                    keyframes.get(*n).is_none() && !local_maps.contains_key(n) && Some(*n) != robot
                })
                .collect::<Vec<_>>()
        };
        let mut count = 0;
        let keyframes = &self.keyframes;
        let local_maps = &self.local_maps;
        for graph in std::iter::once(&mut self.active).chain(self.inactive.values_mut()) {
            for node in bare(graph, keyframes, local_maps) {
                // A vertex that cannot be marginalised (a prior, a fixed or singular one)
                // stays.
                if graph.marginalize_vertex(node).is_ok() {
                    count += 1;
                }
            }
        }
        Ok(count)
    }
}
