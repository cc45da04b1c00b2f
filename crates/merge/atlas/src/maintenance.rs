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
//! 4. prunes views by the information each adds (Sec. 4.1), per graph in two passes. First
//!    coverage: from the most useful view down, a view stays when enough of its nearby
//!    returns fall where no kept view saw structure, so every place keeps a view that sees
//!    it, and a session keeps views only where it sees something new. Then a net for
//!    relocalisation, farthest first (views in recent use first among equals), stopped by a
//!    budget of views per m² the graph maps. Views are bound to the mapped area, not to
//!    every place the robot ever drove through (which grows as long as it lives). Views kept
//!    before rank above a session's new ones, so the map does not churn; a view that
//!    anchors a local map comes first, as its vertex stays anyway;
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
use mapmerge_params::{Checker, Real, Validate};
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
    /// Two views of the net lie at least this far apart (m) (default: 0.5; the budget, not
    /// this floor, sets the spacing once a place is covered) …
    pub view_spacing_m: f64,
    /// … unless their headings differ by more than this (rad) (default: π, any heading: a
    /// 360° scan relocalises from any direction; use π/2 for lasers of 180°).
    pub view_heading_rad: f64,
    /// A view covers when at least this fraction of its returns within
    /// `view_structure_range_m` fall in cells (`view_cell_m`) where no kept view of its graph
    /// saw structure: what it adds to the map (default: 0.3; above 1: no view covers, the
    /// net alone).
    pub view_min_new_fraction: f64,
    /// Cell side (m) at which returns count as the same structure (default: 0.2, a few
    /// times the trackers' drift between sessions).
    pub view_cell_m: f64,
    /// Returns farther than this from their view (m) do not count as what it adds
    /// (default: 4, twice the verifier's 2 m window: what a robot near the view sees too).
    pub view_structure_range_m: f64,
    /// The net stops once its graph holds this many views per m² it maps (known cells of
    /// its rendered local maps; at least one view) (default: 0.25, about the density of the
    /// former 0.75 m net on the simulator's tuning seed 3): the store grows with the mapped
    /// area, not with the sessions lived in it.
    pub max_views_per_m2: f64,
    /// Sessions that count as recent for a view's short-term use: views in recent use are
    /// ranked first and make the net (default: 5).
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
            view_spacing_m: 0.5,
            view_heading_rad: std::f64::consts::PI,
            view_min_new_fraction: 0.3,
            view_cell_m: 0.2,
            view_structure_range_m: 4.0,
            max_views_per_m2: 0.25,
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

/// A view's rank in pruning: in recent use, kept before this session, anchors a local map,
/// utility, node, pose.
type Rank = (bool, bool, bool, f64, NodeId, Se2);

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
            // One rendering per graph serves both: pruning views changes no local map.
            let rendered: Vec<Option<RenderedMap>> = self
                .graphs()
                .map(|graph| RenderedMap::render(graph, &self.local_maps, params.resolution_m))
                .collect();
            report.views_pruned = self.prune_views(params, &rendered);
            let (pruned, fraction) = self.prune_local_maps(params, rendered);
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

    /// The active graph and every inactive one, in map order.
    fn graphs(&self) -> impl Iterator<Item = &PoseGraph2> + '_ {
        std::iter::once(&self.active).chain(self.inactive.values())
    }

    /// The active graph and every inactive one, in the order of [`Atlas::graphs`].
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

    /// Sec. 4.1, in two passes per graph. First what each view adds: from the first in rank
    /// down (views in recent use, then those kept before this session, local-map anchors,
    /// the most useful, the newest), a view stays when at least
    /// [`MaintenanceParams::view_min_new_fraction`] of its returns within
    /// `view_structure_range_m` fall where no kept view saw structure, so every place keeps
    /// a view that sees it. Then a net for relocalisation: of the views left, the one
    /// farthest from every kept view (in steps of `view_spacing_m`; the first in rank among
    /// equals) stays, while it is at least `view_spacing_m` away and the graph holds fewer
    /// than `max_views_per_m2` views per m² it maps. Deletes the others' keyframes; returns
    /// how many.
    /// `rendered`: each graph's rendered local maps, in the order of [`Atlas::graphs`].
    fn prune_views(
        &mut self,
        params: &MaintenanceParams,
        rendered: &[Option<RenderedMap>],
    ) -> usize {
        let session = self.sessions;
        let mut deleted = Vec::new();
        for (graph, rendered) in self.graphs().zip(rendered) {
            // (in recent use, kept before this session, anchors a local map, utility, node,
            // pose)
            let mut ranked: Vec<Rank> = graph
                .vertices()
                .filter(|(node, _)| self.keyframes.get(*node).is_some())
                .map(|(node, vertex)| {
                    let view = self.views.get(&node);
                    let utility = view.map_or(1.0, |v| v.utility(session, params.recent_sessions));
                    let recent = view.is_none_or(|v| v.is_recent(session, params.recent_sessions));
                    let older = view.is_some_and(|v| v.created_session < session);
                    let anchor = self.local_maps.contains_key(&node);
                    (recent, older, anchor, utility, node, vertex.pose)
                })
                .collect();
            if ranked.is_empty() {
                continue;
            }
            // Views in recent use first; among them those kept before, so a session's views
            // enter only where they add (the map does not churn); then anchors, the most
            // useful, the newest.
            ranked.sort_by(|a, b| {
                b.0.cmp(&a.0)
                    .then(b.1.cmp(&a.1))
                    .then(b.2.cmp(&a.2))
                    .then(b.3.total_cmp(&a.3))
                    .then(b.4.cmp(&a.4))
            });
            // 1. What each adds.
            let structure = self.structure_cells(params, &ranked);
            let mut seen: HashSet<(i64, i64)> = HashSet::new();
            let mut kept: Vec<Se2> = Vec::new();
            let mut candidates: Vec<(f64, NodeId, Se2)> = Vec::new();
            for ((_, _, _, _, node, pose), cells) in ranked.iter().zip(structure) {
                let new = cells.iter().filter(|c| !seen.contains(c)).count();
                if !cells.is_empty()
                    && new as f64 >= params.view_min_new_fraction * cells.len() as f64
                {
                    seen.extend(cells);
                    kept.push(*pose);
                } else {
                    candidates.push((f64::INFINITY, *node, *pose));
                }
            }
            // 2. The net, farthest first, within the budget.
            let budget = rendered.as_ref().map_or(usize::MAX, |rendered| {
                let area = rendered.known_area_m2(&ClassThresholds::default());
                ((params.max_views_per_m2.max(0.0) * area).floor() as usize).max(1)
            });
            let distance = |a: &Se2, b: &Se2| {
                if wrap_angle_rad(a.theta_rad - b.theta_rad).abs() > params.view_heading_rad {
                    f64::INFINITY
                } else {
                    (a.translation() - b.translation()).norm()
                }
            };
            for candidate in &mut candidates {
                candidate.0 = kept
                    .iter()
                    .map(|k| distance(k, &candidate.2))
                    .fold(f64::INFINITY, f64::min);
            }
            // Distances count in steps of `view_spacing_m`, and candidates are in rank order:
            // of equally far ones the first wins.
            let spacing_m = params.view_spacing_m.max(1e-3);
            let step = |d: f64| (d / spacing_m).floor().min(1e6) as i64;
            let mut taken = vec![false; candidates.len()];
            while kept.len() < budget {
                let farthest = candidates
                    .iter()
                    .enumerate()
                    .filter(|(i, _)| !taken[*i])
                    .fold(None::<(usize, i64)>, |best, (i, c)| match best {
                        Some((_, d)) if d >= step(c.0) => best,
                        _ => Some((i, step(c.0))),
                    });
                let Some((index, far)) = farthest else {
                    break;
                };
                if far < 1 {
                    break;
                }
                taken[index] = true;
                let pose = candidates[index].2;
                kept.push(pose);
                for candidate in &mut candidates {
                    candidate.0 = candidate.0.min(distance(&pose, &candidate.2));
                }
            }
            deleted.extend(
                candidates
                    .iter()
                    .zip(&taken)
                    .filter(|(_, taken)| !**taken)
                    .map(|(c, _)| c.1),
            );
        }
        for node in &deleted {
            self.keyframes.remove(*node);
            self.views.remove(node);
        }
        deleted.len()
    }

    /// The structure cells (`view_cell_m`, map frame) each view's returns within
    /// `view_structure_range_m` fall in.
    fn structure_cells(
        &self,
        params: &MaintenanceParams,
        ranked: &[Rank],
    ) -> Vec<HashSet<(i64, i64)>> {
        let cell_m = params.view_cell_m.max(1e-3);
        let range_m = params.view_structure_range_m.max(0.0);
        ranked
            .iter()
            .map(|(_, _, _, _, node, pose)| {
                self.keyframes
                    .get(*node)
                    .map(|points| {
                        points
                            .iter()
                            .filter(|p| p.norm() <= range_m)
                            .map(|p| {
                                let q = pose.transform_point(p);
                                ((q.x / cell_m).floor() as i64, (q.y / cell_m).floor() as i64)
                            })
                            .collect()
                    })
                    .unwrap_or_default()
            })
            .collect()
    }

    /// Sec. 4.3, Eq. 9, greedily: per graph, most redundant local map first, one goes when
    /// the rendered map without it (and without those gone before) still has at most
    /// `local_map_tolerance` of its known cells in another class. Returns how many went and
    /// the largest fraction reached in a graph. `rendered`: as for [`Atlas::prune_views`].
    fn prune_local_maps(
        &mut self,
        params: &MaintenanceParams,
        rendered: Vec<Option<RenderedMap>>,
    ) -> (usize, f64) {
        let thresholds = ClassThresholds::default();
        let mut pruned = Vec::new();
        let mut worst = 0.0f64;
        for mut rendered in rendered.into_iter().flatten() {
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

impl Validate for MaintenanceParams {
    fn check(&self, check: &mut Checker) {
        check
            .real("resolution_m", self.resolution_m, Real::within(0.01, 10.0))
            .real("view_spacing_m", self.view_spacing_m, Real::non_negative())
            .real(
                "view_heading_rad",
                self.view_heading_rad,
                Real::within(0.0, std::f64::consts::PI),
            )
            .real(
                "view_min_new_fraction",
                self.view_min_new_fraction,
                Real::non_negative(),
            )
            .real("view_cell_m", self.view_cell_m, Real::within(0.01, 10.0))
            .real(
                "view_structure_range_m",
                self.view_structure_range_m,
                Real::non_negative(),
            )
            .real("max_views_per_m2", self.max_views_per_m2, Real::positive())
            .count("recent_sessions", self.recent_sessions, 0, 1_000_000)
            .real(
                "local_map_tolerance",
                self.local_map_tolerance,
                Real::fraction(),
            )
            .real(
                "max_edges_per_vertex",
                self.max_edges_per_vertex,
                Real::at_least(1.0),
            )
            .count(
                "stale_after_sessions",
                self.stale_after_sessions,
                0,
                1_000_000,
            )
            .nested("rejoin", &self.rejoin);
    }
}
