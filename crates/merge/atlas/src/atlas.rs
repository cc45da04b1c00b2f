//! The atlas: epochs, one active graph, any number of inactive graphs, shared keyframes
//! (Holoch et al., Sec. III).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_params::{Checker, Validate};
use mapmerge_posegraph::{Edge, EdgeId, NodeId, PoseGraph2, Vertex};
use mapmerge_scan::Point2;
use mapmerge_slam::KeyframeInsertion;
use mapmerge_solve::{chi2_quantile_99, OptimizerInfo, OptimizerParams, RobustKernel};
use serde::{Deserialize, Serialize};

use crate::backup::{BackupStore, MemoryBackups};
use crate::constraints::{ConstraintBuilder, LoopClosureParams};
use crate::error::AtlasError;
use crate::events::{AtlasEvent, EpochEndReason};
use crate::ids::{EpochId, MapId, MergeId};
use crate::keyframes::{KeyframeRecord, KeyframeStore};
use crate::merge::MergeParams;
use crate::recognition::{KeyframeParams, RecognitionParams};

/// Parameters of the atlas, one default for every log.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AtlasParams {
    /// Loop closing inside the current epoch (see [`LoopClosureParams`]).
    pub loops: LoopClosureParams,
    /// The place index describes each keyframe's local map (`keyframes`) instead of its own
    /// scan (default: false: single scans, which keeps SLAM's place loops as they were).
    pub index_local_maps: bool,
    /// Re-optimisation after a merge and after an unmerge (default: Levenberg–Marquardt, DCS
    /// with Φ = χ²₃(0.99) on every edge, at most 50 iterations): robust, so one bad loop edge
    /// of a merge bends the map less.
    pub optimizer: OptimizerParams,
    /// How merges join the graphs (see [`MergeParams`]).
    pub merge: MergeParams,
    /// Place recognition between the active and the inactive graphs (see
    /// [`RecognitionParams`]).
    pub recognition: RecognitionParams,
    /// The keyframes place recognition and the overlap search match (see [`KeyframeParams`]).
    pub keyframes: KeyframeParams,
    /// Keeping the lifelong atlas bounded after each session (see
    /// [`crate::MaintenanceParams`]).
    pub maintenance: crate::MaintenanceParams,
}

impl Default for AtlasParams {
    fn default() -> Self {
        Self {
            loops: LoopClosureParams::default(),
            index_local_maps: false,
            optimizer: OptimizerParams {
                robust: RobustKernel::Dcs {
                    phi: chi2_quantile_99(3),
                },
                max_iterations: 50,
                ..OptimizerParams::default()
            },
            merge: MergeParams::default(),
            recognition: RecognitionParams::default(),
            keyframes: KeyframeParams::default(),
            maintenance: crate::MaintenanceParams::default(),
        }
    }
}

/// A merge into the active graph that can still be undone.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AppliedMerge {
    /// The merge (and its backup).
    pub merge: MergeId,
    /// The inactive graph it took in, restored under this id by an unmerge.
    pub map: MapId,
    /// Where it went: the inactive graph's frame in the active graph's, `[x_m, y_m, yaw_rad]`.
    pub active_from_inactive: [f64; 3],
}

/// The lifelong atlas (Holoch et al., Sec. III): the active graph `G_{I*}` the robot is
/// localised in and adds to, the inactive graphs `G_{I_1} … G_{I_{n-1}}`, every vertex's
/// keyframe stored once, the backups that make the merges into the active graph undoable, and
/// the one constraint builder with its place index ([`crate::constraints`]). It is the only
/// owner of every pose graph: the tracker in front of it hands over keyframes
/// ([`Atlas::insert_keyframe`]) and holds no graph.
///
/// Invariants: node ids are unique across every graph and backup (the atlas hands them out);
/// every vertex carries its epoch as [`mapmerge_posegraph::VertexMeta::session`]; the active
/// graph holds only current-epoch vertices plus those of the inactive graphs merged since the
/// epoch began, each of which has a backup.
pub struct Atlas<B: BackupStore = MemoryBackups> {
    pub(crate) params: AtlasParams,
    pub(crate) epoch: EpochId,
    pub(crate) active: PoseGraph2,
    /// The robot's newest vertex (current epoch): its pose never jumps on a merge or unmerge.
    pub(crate) robot: Option<NodeId>,
    pub(crate) merges: Vec<AppliedMerge>,
    pub(crate) inactive: BTreeMap<MapId, PoseGraph2>,
    pub(crate) keyframes: KeyframeStore,
    pub(crate) backups: B,
    /// The tracker's local frame of the current epoch in the active graph's frame, re-derived
    /// from the robot's vertex after every optimisation (Hess et al. 2016: the global pose
    /// of the local trajectory).
    pub(crate) map_from_local: Se2,
    pub(crate) constraints: ConstraintBuilder,
    pub(crate) next_node: u64,
    pub(crate) next_epoch: u32,
    pub(crate) next_map: u32,
    pub(crate) next_merge: u64,
    pub(crate) events: Vec<AtlasEvent>,
    /// Local maps by anchor vertex ([`crate::LocalMapGrid`]).
    pub(crate) local_maps: BTreeMap<NodeId, crate::LocalMapGrid>,
    /// How each view (keyframe) has been used ([`crate::ViewUse`]).
    pub(crate) views: BTreeMap<NodeId, crate::ViewUse>,
    /// Maintenance sessions so far ([`Atlas::maintain`]).
    pub(crate) sessions: u32,
    /// The first vertex of each of the last `stale_after_sessions` sessions, oldest first.
    pub(crate) session_first_nodes: Vec<NodeId>,
}

impl Atlas<MemoryBackups> {
    /// An atlas with backups in RAM; epoch 0 has started. Fails on invalid parameters.
    pub fn new(params: AtlasParams) -> Result<Self, AtlasError> {
        Self::with_backups(params, MemoryBackups::default())
    }
}

impl<B: BackupStore> Atlas<B> {
    /// An atlas with the given backup store (e.g. [`crate::DiskBackups`]); epoch 0 has started.
    pub fn with_backups(params: AtlasParams, backups: B) -> Result<Self, AtlasError> {
        Ok(Self {
            constraints: ConstraintBuilder::new(&params)?,
            map_from_local: Se2::identity(),
            params,
            epoch: EpochId(0),
            active: PoseGraph2::new(),
            robot: None,
            merges: Vec::new(),
            inactive: BTreeMap::new(),
            keyframes: KeyframeStore::default(),
            backups,
            next_node: 0,
            next_epoch: 1,
            next_map: 0,
            next_merge: 0,
            events: vec![AtlasEvent::EpochStarted { epoch: EpochId(0) }],
            local_maps: BTreeMap::new(),
            views: BTreeMap::new(),
            sessions: 0,
            session_first_nodes: Vec::new(),
        })
    }

    /// The parameters.
    pub fn params(&self) -> &AtlasParams {
        &self.params
    }

    /// The current epoch `ι*`.
    pub fn current_epoch(&self) -> EpochId {
        self.epoch
    }

    /// The active graph, in its own (the current epoch's) frame.
    pub fn active(&self) -> &PoseGraph2 {
        &self.active
    }

    /// The robot's newest vertex in the active graph.
    pub fn robot_node(&self) -> Option<NodeId> {
        self.robot
    }

    /// The inactive graphs by id.
    pub fn inactive_maps(&self) -> impl ExactSizeIterator<Item = (MapId, &PoseGraph2)> + '_ {
        self.inactive.iter().map(|(k, g)| (*k, g))
    }

    /// One inactive graph.
    pub fn inactive(&self, map: MapId) -> Option<&PoseGraph2> {
        self.inactive.get(&map)
    }

    /// Every vertex's keyframe.
    pub fn keyframes(&self) -> &KeyframeStore {
        &self.keyframes
    }

    /// The id the next vertex will get.
    pub fn next_node_id(&self) -> NodeId {
        NodeId(self.next_node)
    }

    /// The tracker's local frame of the current epoch in the active graph's frame.
    pub fn map_from_local(&self) -> Se2 {
        self.map_from_local
    }

    /// The pose of `node` in whichever graph holds it (active first).
    pub fn pose_of(&self, node: NodeId) -> Option<Se2> {
        std::iter::once(&self.active)
            .chain(self.inactive.values())
            .find_map(|g| g.vertex(node))
            .map(|v| v.pose)
    }

    /// The local maps by anchor vertex.
    pub fn local_maps(&self) -> &BTreeMap<NodeId, crate::LocalMapGrid> {
        &self.local_maps
    }

    /// The backups.
    pub fn backups(&self) -> &B {
        &self.backups
    }

    /// Every event so far, oldest first (write them with [`crate::EventLogWriter`]).
    pub fn events(&self) -> &[AtlasEvent] {
        &self.events
    }

    /// The merges into the active graph that an unmerge would undo, oldest first.
    pub fn undoable_merges(&self) -> &[AppliedMerge] {
        &self.merges
    }

    /// True while some merge into the active graph can be undone; invalid-merge detection runs
    /// only then (Sec. III-B).
    pub fn is_undoable(&self) -> bool {
        !self.merges.is_empty()
    }

    /// The epochs in the active graph, `I*` (the current one even while the graph is empty).
    pub fn active_epochs(&self) -> BTreeSet<EpochId> {
        let mut epochs = epochs_of(&self.active);
        epochs.insert(self.epoch);
        epochs
    }

    /// True when `node` is in the active graph and belongs to the current epoch, `V_{ι*}`.
    pub fn is_current_epoch(&self, node: NodeId) -> bool {
        self.active
            .vertex(node)
            .is_some_and(|v| EpochId::of(&v.meta) == self.epoch)
    }

    /// The longest of the current epoch's last `steps` keyframe steps (all of them with
    /// `usize::MAX`), in the tracker's travel (m); 0 before the epoch has two keyframes.
    pub fn longest_recent_keyframe_step_m(&self, steps: usize) -> f64 {
        let Some(robot) = self.robot else {
            return 0.0;
        };
        let (mut longest_m, mut later_m) = (0.0f64, None);
        for (_, record) in self
            .keyframes
            .records_up_to(robot)
            .rev()
            .take_while(|(node, _)| self.is_current_epoch(*node))
            .take(steps.saturating_add(1))
        {
            if let Some(later_m) = later_m {
                longest_m = longest_m.max(later_m - record.travel_m);
            }
            later_m = Some(record.travel_m);
        }
        longest_m
    }

    /// The current epoch's vertices of the active graph, oldest first.
    pub fn current_epoch_nodes(&self) -> Vec<NodeId> {
        self.active
            .vertices()
            .filter(|(id, _)| self.is_current_epoch(*id))
            .map(|(id, _)| id)
            .collect()
    }

    /// The epoch of a vertex of any graph.
    pub fn epoch_of(&self, node: NodeId) -> Option<EpochId> {
        std::iter::once(&self.active)
            .chain(self.inactive.values())
            .find_map(|g| g.vertex(node))
            .map(|v| EpochId::of(&v.meta))
    }

    /// Adds a vertex of the current epoch to the active graph and returns its new, globally
    /// unique id. The atlas stamps the epoch into `vertex.meta.session`; pose, fixed flag,
    /// robot and stamp are the caller's. `points_in_robot` are the keyframe's points in the
    /// vertex's frame, stored once. The vertex becomes the robot's current one. (A live
    /// robot's keyframes come through [`Atlas::insert_keyframe`].)
    pub fn add_vertex(
        &mut self,
        mut vertex: Vertex<Se2>,
        points_in_robot: Arc<[Point2]>,
    ) -> NodeId {
        let id = NodeId(self.next_node);
        self.next_node += 1;
        vertex.meta.session = self.epoch.session();
        let travel_m = self.robot.and_then(|r| {
            let previous = self.active.vertex(r)?.pose;
            let record = self.keyframes.record(r)?;
            Some(record.travel_m + (previous.translation() - vertex.pose.translation()).norm())
        });
        let record = KeyframeRecord {
            points_in_robot,
            travel_m: travel_m.unwrap_or(0.0),
            local_from_robot: vertex.pose,
            submap: None,
        };
        // Fresh id: cannot clash.
        let _ = self.active.add_vertex(id, vertex);
        self.keyframes.insert(id, record);
        self.robot = Some(id);
        self.constraints.epoch_keyframes += 1;
        id
    }

    /// Inserts a keyframe the tracker made (Hess et al. 2016's hand-over from the local to
    /// the global side): its vertex at `map_from_local · local_from_robot`, its edges, its
    /// keyframe data; a submap it finished becomes a loop-closure target. Its node must be
    /// [`Atlas::next_node_id`] and its edges must join it to earlier vertices of the active
    /// graph. On error the atlas is unchanged.
    pub fn insert_keyframe(
        &mut self,
        insertion: KeyframeInsertion,
        stamp_secs: Option<f64>,
    ) -> Result<NodeId, AtlasError> {
        let node = insertion.node;
        let bad = |reason: String| AtlasError::BadKeyframe { node, reason };
        if node != self.next_node_id() {
            return Err(bad(format!("expected node id {}", self.next_node_id())));
        }
        if !insertion.local_from_robot.is_finite() {
            return Err(bad("non-finite pose".into()));
        }
        for edge in &insertion.edges {
            let other = if edge.to == node { edge.from } else { edge.to };
            if !(edge.from == node || edge.to == node) || !self.active.contains_vertex(other) {
                return Err(bad(format!(
                    "edge {} -> {} does not join it to the active graph",
                    edge.from, edge.to
                )));
            }
        }
        let mut vertex = Vertex::new(self.map_from_local.compose(&insertion.local_from_robot));
        vertex.meta.stamp_secs = stamp_secs;
        vertex.meta.session = self.epoch.session();
        self.active.add_vertex(node, vertex)?;
        for edge in &insertion.edges {
            // Checked above: both ends exist.
            self.active.add_edge(*edge)?;
        }
        self.next_node += 1;
        // The submap it finished first: its other keyframes join the place index now, this
        // one with its next submap (it is in both).
        if let Some(finished) = insertion.finished_submap {
            self.add_finished_submap(finished);
        }
        self.keyframes.insert(
            node,
            KeyframeRecord {
                points_in_robot: insertion.points_in_robot,
                travel_m: insertion.travel_m,
                local_from_robot: insertion.local_from_robot,
                submap: Some(insertion.submap),
            },
        );
        self.robot = Some(node);
        self.constraints.epoch_keyframes += 1;
        self.constraints.travel_m = insertion.travel_m;
        Ok(node)
    }

    /// Re-derives [`Atlas::map_from_local`] from the robot's vertex (after its pose moved).
    pub(crate) fn update_map_from_local(&mut self) {
        let Some(robot) = self.robot else {
            return;
        };
        if let (Some(vertex), Some(record)) =
            (self.active.vertex(robot), self.keyframes.record(robot))
        {
            let map_from_local = vertex.pose.compose(&record.local_from_robot.inverse());
            if map_from_local.is_finite() {
                self.map_from_local = map_from_local;
            }
        }
    }

    /// Adds an edge between vertices of the active graph (any epochs: a front-end loop
    /// closure into merged data is removed again by an unmerge).
    pub fn add_edge(&mut self, edge: Edge<Se2, 3>) -> Result<EdgeId, AtlasError> {
        Ok(self.active.add_edge(edge)?)
    }

    /// Moves a vertex of the active graph (e.g. after the front-end optimised).
    pub fn set_pose(&mut self, node: NodeId, pose: Se2) -> Result<(), AtlasError> {
        let vertex = self
            .active
            .vertex_mut(node)
            .ok_or(AtlasError::MissingVertex {
                node,
                graph: "active",
            })?;
        vertex.pose = pose;
        Ok(())
    }

    /// Adds a whole graph (e.g. a front-end's) to the current epoch in the active graph's
    /// frame: vertices in id order under new atlas ids, every edge remapped in id order,
    /// `points(old_id)` as each vertex's scan (empty when `None`). Returns new id by old id.
    /// The last vertex becomes the robot's current one.
    pub fn import_graph(
        &mut self,
        graph: &PoseGraph2,
        mut points: impl FnMut(NodeId) -> Option<Arc<[Point2]>>,
    ) -> Result<BTreeMap<NodeId, NodeId>, AtlasError> {
        let mut new_from_old = BTreeMap::new();
        let mut staged = self.active.clone();
        let mut next_node = self.next_node;
        for (old, vertex) in graph.vertices() {
            let id = NodeId(next_node);
            next_node += 1;
            let mut vertex = *vertex;
            vertex.meta.session = self.epoch.session();
            staged.add_vertex(id, vertex)?;
            new_from_old.insert(old, id);
        }
        for (_, edge) in graph.edges() {
            let remap = |old: NodeId| {
                new_from_old
                    .get(&old)
                    .copied()
                    .ok_or(AtlasError::MissingVertex {
                        node: old,
                        graph: "imported",
                    })
            };
            staged.add_edge(Edge {
                from: remap(edge.from)?,
                to: remap(edge.to)?,
                ..*edge
            })?;
        }
        // Commit: nothing below fails.
        self.active = staged;
        self.next_node = next_node;
        let mut travel_m = 0.0;
        let mut previous: Option<Se2> = None;
        for (old, new) in &new_from_old {
            let scan = points(*old).unwrap_or_else(|| Arc::from(Vec::new()));
            let pose = self.active.vertex(*new).map_or(Se2::identity(), |v| v.pose);
            if let Some(previous) = previous {
                travel_m += (pose.translation() - previous.translation()).norm();
            }
            previous = Some(pose);
            self.keyframes.insert(
                *new,
                KeyframeRecord {
                    points_in_robot: scan,
                    travel_m,
                    local_from_robot: pose,
                    submap: None,
                },
            );
        }
        self.constraints.epoch_keyframes += new_from_old.len();
        if let Some(last) = new_from_old.values().next_back() {
            self.robot = Some(*last);
        }
        Ok(new_from_old)
    }

    /// Re-optimises the active graph with the robot's vertex held, so the robot does not jump.
    pub fn optimize_active(&mut self) -> Result<Option<OptimizerInfo>, AtlasError> {
        let info = optimize_holding(&mut self.active, self.robot, &self.params.optimizer)?;
        self.update_map_from_local();
        Ok(info)
    }

    /// Ends the current epoch (kidnap, restart, tracking failure; Sec. III): the active graph
    /// joins the inactive graphs (unless empty), the merges into it become final (their
    /// backups are dropped: "as soon as epoch ι* ends, and we did not find an invalid merge,
    /// we can prune the complete graph"), and a new epoch starts with an empty active graph.
    /// Returns the `EpochEnded` and `EpochStarted` events.
    pub fn end_epoch(&mut self, reason: EpochEndReason) -> Vec<AtlasEvent> {
        let ended = self.epoch;
        // Its keyframes not indexed yet (unfinished submaps) join the place index now.
        self.index_active_graph();
        self.constraints
            .start_epoch(matches!(reason, EpochEndReason::Restart));
        self.map_from_local = Se2::identity();
        let graph = std::mem::take(&mut self.active);
        let map = (graph.num_vertices() > 0).then(|| {
            let map = MapId(self.next_map);
            self.next_map += 1;
            self.inactive.insert(map, graph);
            map
        });
        let finalized: Vec<MergeId> = self.merges.drain(..).map(|m| m.merge).collect();
        for merge in &finalized {
            // A backup that cannot be deleted is only a stale file: merge ids are never
            // reused, so it is never read again.
            let _ = self.backups.remove(*merge);
        }
        self.epoch = EpochId(self.next_epoch);
        self.next_epoch += 1;
        self.robot = None;
        let events = vec![
            AtlasEvent::EpochEnded {
                epoch: ended,
                reason,
                map,
                finalized_merges: finalized,
            },
            AtlasEvent::EpochStarted { epoch: self.epoch },
        ];
        self.events.extend(events.iter().cloned());
        events
    }

    /// Whether pruning may remove `node` (Sec. III-B): while a merge into the active graph can
    /// be undone, only current-epoch vertices of the active graph may go, since the merged
    /// data is restored from backups that pruning would break; vertices of inactive graphs
    /// may. False for unknown vertices.
    pub fn can_prune(&self, node: NodeId) -> bool {
        match self.active.vertex(node) {
            Some(v) => self.merges.is_empty() || EpochId::of(&v.meta) == self.epoch,
            None => self.inactive.values().any(|g| g.contains_vertex(node)),
        }
    }

    /// Prunes a vertex with its edges and scan, refusing what [`Atlas::can_prune`] refuses.
    /// (Pruning policies, e.g. Kretzschmar's information-theoretic one, decide *which*
    /// vertices; they must go through here.)
    pub fn prune_vertex(&mut self, node: NodeId) -> Result<AtlasEvent, AtlasError> {
        let (epoch, map) = if let Some(v) = self.active.vertex(node) {
            let epoch = EpochId::of(&v.meta);
            if !self.can_prune(node) {
                return Err(AtlasError::PruneRefused { node, epoch });
            }
            self.active.remove_vertex(node)?;
            if self.robot == Some(node) {
                self.robot = self
                    .active
                    .vertices()
                    .filter(|(_, v)| EpochId::of(&v.meta) == self.epoch)
                    .map(|(id, _)| id)
                    .last();
            }
            (epoch, None)
        } else {
            let (map, graph) = self
                .inactive
                .iter_mut()
                .find(|(_, g)| g.contains_vertex(node))
                .ok_or(AtlasError::MissingVertex { node, graph: "any" })?;
            let removed = graph.remove_vertex(node)?;
            (EpochId::of(&removed.vertex.meta), Some(*map))
        };
        self.keyframes.remove(node);
        self.local_maps.remove(&node);
        self.views.remove(&node);
        let event = AtlasEvent::Pruned { node, epoch, map };
        self.events.push(event.clone());
        Ok(event)
    }
}

/// The epochs stamped on a graph's vertices.
pub fn epochs_of(graph: &PoseGraph2) -> BTreeSet<EpochId> {
    graph
        .vertices()
        .map(|(_, v)| EpochId::of(&v.meta))
        .collect()
}

/// Optimises `graph` with `hold` held fixed (its pose and flag are as before afterwards), so
/// the robot's pose does not jump (Sec. III-A: keep the active graph's frame). `None` when
/// there is nothing to optimise.
pub(crate) fn optimize_holding(
    graph: &mut PoseGraph2,
    hold: Option<NodeId>,
    params: &OptimizerParams,
) -> Result<Option<OptimizerInfo>, AtlasError> {
    if graph.num_edges() == 0 {
        return Ok(None);
    }
    let held = hold.and_then(|node| {
        graph.vertex_mut(node).map(|v| {
            let before = (v.fixed, v.pose);
            v.fixed = true;
            (node, before)
        })
    });
    let result = mapmerge_solve::optimize(graph, params);
    if let Some((node, (fixed, pose))) = held {
        if let Some(v) = graph.vertex_mut(node) {
            v.fixed = fixed;
            v.pose = pose;
        }
    }
    Ok(Some(result?))
}

impl Validate for AtlasParams {
    fn check(&self, check: &mut Checker) {
        check
            .nested("loops", &self.loops)
            .nested("optimizer", &self.optimizer)
            .nested("merge", &self.merge)
            .nested("recognition", &self.recognition)
            .nested("keyframes", &self.keyframes)
            .nested("maintenance", &self.maintenance);
    }
}
