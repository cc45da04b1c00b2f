//! Merging an inactive graph into the active graph and undoing every such merge
//! (Holoch et al., Sec. III-A and III-B).

use std::collections::BTreeSet;

use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_params::{Checker, Real, Validate, SIGMA_M, SIGMA_RAD};
use mapmerge_place::GeometricVerifier;
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph2};
use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

use crate::atlas::{epochs_of, optimize_holding, AppliedMerge, Atlas};
use crate::backup::BackupStore;
use crate::error::AtlasError;
use crate::events::{pose_array, AtlasEvent, MergeEvent, MergeReason, UnmergeEvent, UnmergeReason};
use crate::ids::{EpochId, MapId, MergeId};
use crate::recognition::local_map_keyframes;

/// The current epoch's agreement with the epochs merged into it ([`Atlas::epoch_agreement`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EpochAgreement {
    /// Edges between the current epoch and a merged one that the optimised graph satisfies
    /// within the robust kernel's χ² bound ...
    pub agreeing_edges: usize,
    /// ... and those it does not ...
    pub disagreeing_edges: usize,
    /// ... of which the merges' own (kind `Merge`: the observations, the overlap loops and
    /// the loops into the merged data), as opposed to loops of accepted recovery
    /// hypotheses (kind `Loop`): which side the robust kernel gave way to.
    pub disagreeing_merge_edges: usize,
    /// The largest translation residual (m) of a disagreeing edge (0 when none).
    pub worst_off_m: f64,
}

/// How merges join two graphs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MergeParams {
    /// Smallest standard deviations of a loop edge made from a verified match (m, rad)
    /// (default: 10 cm, 2°, the front-end's loop floor): a scan matcher's covariance is
    /// over-confident across sessions.
    pub loop_min_sigma: (f64, f64),
    /// Standard deviations of the edge a forced merge with a transform only gets, from the
    /// robot's vertex to the nearest merged vertex (m, rad) (default: 10 cm, 2°).
    pub forced_edge_sigma: (f64, f64),
    /// The search for further loop closures in the overlap after a merge (see
    /// [`OverlapParams`]).
    pub overlap: OverlapParams,
}

impl Default for MergeParams {
    fn default() -> Self {
        Self {
            loop_min_sigma: (0.1, 2f64.to_radians()),
            forced_edge_sigma: (0.1, 2f64.to_radians()),
            overlap: OverlapParams::default(),
        }
    }
}

/// "After merging two maps, it makes sense to try to find additional loop closures where the
/// maps overlap" (Sec. III-A): active vertices are paired with the nearest merged vertex under
/// the merge's transform and verified from that guess.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OverlapParams {
    /// Search at all (default: true; it needs a verifier, see [`Atlas::merge`]).
    pub enabled: bool,
    /// A merged vertex within this distance (m) of an active one is its partner (default: 2).
    pub radius_m: f64,
    /// ... and within this heading difference (rad) (default: 60°), where there is one: the
    /// views overlap most.
    pub max_heading_rad: f64,
    /// ... else the nearest at any heading (default: true). The merged side is matched with
    /// its keyframe's stored local map, which also saw what lies behind that keyframe: a
    /// robot driving an old corridor the other way (intel, the second epoch after a kidnap)
    /// found no partner within 60° for 10 m and its conditional merge expired unconfirmed.
    pub any_heading: bool,
    /// Every `stride`-th active vertex is tried, newest first (default: 3).
    pub stride: usize,
    /// At most this many verifications per merge (default: 40; each builds a match target,
    /// tens of ms).
    pub max_verifications: usize,
    /// At most this many overlap edges per merge (default: 20).
    pub max_loops: usize,
    /// A verification is accepted from this score in the verifier's units (default: 0.95,
    /// the whole-map agreement of [`crate::default_verifier`] on local maps with their free
    /// space; 0.9 merged the same on the simulator's tuning seeds. Without free space the
    /// evidence score was accepted from 0.85).
    pub min_score: f64,
    /// ... and when it corrects the guess by at most this (m) (default: 0.5) ...
    pub gate_m: f64,
    /// ... and this (rad) (default: 5°): the merge's transform is known now, so a match far
    /// from it is a look-alike.
    pub gate_rad: f64,
    /// Loops into merged data after a merge are verified as the epoch's own loops are: the
    /// epoch's loop matcher searched within the gate only, accepted from `loops.min_score`
    /// (default: true; false verifies them by the merge search's verifier and `min_score`). The
    /// merge already fixes where the robot is to within the gate; the place verifier asks for a
    /// place unique within ±2 m and at 180°, which no corridor is (infinite corridor's right
    /// merges score 0.02–0.95 there), so the tracker drifts along it unchecked. On by default:
    /// on two draws of forced merges it raised the tuning logs' best single detector AUC under
    /// both odometry settings, and its public-log time is within noise.
    pub local_loops: bool,
    /// With `local_loops`: the tried vertices the local matcher did not join are verified again
    /// by the merge search's verifier and `min_score` (default: false). The local matcher
    /// refuses a loop under `loops.min_score` even when it measures the drift well (fhw's later
    /// loops score 0.40–0.55), which the place verifier accepts where the place is unique. Off
    /// by default: it raised the detectors' AUC by only 0.0005 and cost 1.09× the public-log
    /// time.
    pub place_verifier_too: bool,
}

impl Default for OverlapParams {
    fn default() -> Self {
        Self {
            enabled: true,
            radius_m: 2.0,
            max_heading_rad: 60f64.to_radians(),
            any_heading: true,
            stride: 3,
            max_verifications: 40,
            max_loops: 20,
            min_score: 0.95,
            gate_m: 0.5,
            gate_rad: 5f64.to_radians(),
            local_loops: true,
            place_verifier_too: false,
        }
    }
}

/// A verifier and the score from which its matches are accepted.
#[derive(Clone, Copy)]
struct GatedVerifier<'a> {
    verifier: &'a dyn GeometricVerifier,
    min_score: f64,
}

impl<'a> GatedVerifier<'a> {
    fn new(verifier: &'a dyn GeometricVerifier, min_score: f64) -> Self {
        Self {
            verifier,
            min_score,
        }
    }
}

/// A loop closure between the active graph and an inactive graph.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LoopEdge {
    /// The vertex of the active graph.
    pub active: NodeId,
    /// The vertex of the inactive graph.
    pub inactive: NodeId,
    /// The active vertex's pose in the inactive vertex's frame (what a verifier returns as
    /// `candidate_from_query` with the active keyframe as the query).
    pub inactive_from_active: Se2,
    /// Information of `inactive_from_active` in its right tangent `(vx, vy, ω)`.
    pub information: Matrix3<f64>,
}

impl LoopEdge {
    /// The pose-graph edge: `from` the inactive vertex `to` the active one, kind `Merge`.
    pub fn edge(&self) -> Edge<Se2, 3> {
        Edge {
            from: self.inactive,
            to: self.active,
            measurement: self.inactive_from_active,
            information: self.information,
            kind: EdgeKind::Merge,
        }
    }
}

/// The active graph a merge would make ([`Atlas::preview_merge`]).
#[derive(Clone, Debug, PartialEq)]
pub struct MergePreview {
    /// The merged graph, re-optimised with the robot held.
    pub graph: PoseGraph2,
    /// Where the inactive graph went.
    pub active_from_inactive: Se2,
    /// Loop edges that join the graphs (given, or the one a transform alone gets).
    pub loop_edges: usize,
    /// Further loop edges found in the overlap.
    pub overlap_edges: usize,
    /// Chi2 of the active graph before, and of the merged graph after re-optimisation.
    pub chi2: [f64; 2],
}

/// What to merge and how: the inactive graph, where it goes, the loop edges that join it.
/// Built by place recognition ([`crate::MergeProposal::into_request`]) or by a caller that
/// forces a merge ([`MergeRequest::forced`], the evaluation's "merge at a given time with a
/// given transform").
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MergeRequest {
    /// The inactive graph.
    pub map: MapId,
    /// The inactive graph's frame in the active graph's frame; `None` = implied by the first
    /// loop edge and the current poses.
    pub active_from_inactive: Option<Se2>,
    /// Loop edges; with none, the merge adds one from the robot's vertex to the merged vertex
    /// nearest to it, consistent with the transform.
    pub loops: Vec<LoopEdge>,
    /// Why.
    pub reason: MergeReason,
}

impl MergeRequest {
    /// A forced merge with a transform only.
    pub fn forced(map: MapId, active_from_inactive: Se2, note: impl Into<String>) -> Self {
        Self {
            map,
            active_from_inactive: Some(active_from_inactive),
            loops: Vec::new(),
            reason: MergeReason::Forced { note: note.into() },
        }
    }
}

pub(crate) use mapmerge_geometry::planar_information_from_covariance as information_from_covariance;

impl<B: BackupStore> Atlas<B> {
    /// Merges inactive graph `request.map` into the active graph (Sec. III-A):
    /// 1. back up the inactive graph as it is (graph structure only; scans stay shared);
    /// 2. to 5. as [`Atlas::preview_merge`]: move it into the active frame, union with the
    ///    loop edges, overlap loops, re-optimise with the robot held;
    ///
    /// then commit the merged graph as the active one.
    ///
    /// Merges stack: each later one is undone with the earlier ones by
    /// [`Atlas::unmerge_all`]. On error the atlas is unchanged.
    pub fn merge(
        &mut self,
        request: MergeRequest,
        verifier: Option<&dyn GeometricVerifier>,
    ) -> Result<MergeEvent, AtlasError> {
        let preview = self.preview_merge(&request, verifier)?;
        let map = request.map;
        let inactive = self.inactive.get(&map).ok_or(AtlasError::MissingMap(map))?;
        // 1. Back up before anything changes (the only fallible step left), then commit.
        let merged_epochs: Vec<EpochId> = epochs_of(inactive).into_iter().collect();
        let merged_vertices = inactive.num_vertices();
        let merge = MergeId(self.next_merge);
        self.backups.store(merge, inactive)?;
        self.next_merge += 1;
        self.inactive.remove(&map);
        self.active = preview.graph;
        let active_from_inactive = pose_array(&preview.active_from_inactive);
        self.merges.push(AppliedMerge {
            merge,
            map,
            active_from_inactive,
        });
        let event = MergeEvent {
            merge,
            active_epoch: self.epoch,
            map,
            merged_epochs,
            merged_vertices,
            loop_edges: preview.loop_edges,
            overlap_edges: preview.overlap_edges,
            active_from_inactive,
            reason: request.reason,
            chi2: preview.chi2,
        };
        self.events.push(AtlasEvent::Merged(event.clone()));
        Ok(event)
    }

    /// The active graph as [`Atlas::merge`] would make it, without changing the atlas (a
    /// conditional merge's graph copy G', Banerjee et al., Sec. 5.2):
    /// 2. the inactive graph moved into the active graph's frame by `active_from_inactive`
    ///    (the robot's pose must not jump), its vertices no longer fixed;
    /// 3. both graphs united with the loop edges (kind `Merge`; a transform alone gets one
    ///    consistent edge);
    /// 4. with a `verifier`, further loop closures searched in the overlap;
    /// 5. re-optimised with the robot's vertex held.
    pub fn preview_merge(
        &self,
        request: &MergeRequest,
        verifier: Option<&dyn GeometricVerifier>,
    ) -> Result<MergePreview, AtlasError> {
        let map = request.map;
        let robot = self.robot.ok_or(AtlasError::EmptyActive(self.epoch))?;
        let inactive = self.inactive.get(&map).ok_or(AtlasError::MissingMap(map))?;
        let bad = |reason: String| AtlasError::BadMerge { map, reason };
        for l in &request.loops {
            if !self.active.contains_vertex(l.active) || !inactive.contains_vertex(l.inactive) {
                return Err(bad(format!(
                    "loop {} -> {} must join the active graph to the inactive one",
                    l.active, l.inactive
                )));
            }
            if !(l.inactive_from_active.is_finite() && l.information.iter().all(|v| v.is_finite()))
            {
                return Err(bad(format!(
                    "loop {} -> {} is not finite",
                    l.active, l.inactive
                )));
            }
        }

        // 2. Where the inactive graph goes: given, or implied by the first loop (a active,
        // b inactive): active_from_b = active_from_a · b_from_a⁻¹, and
        // active_from_inactive = active_from_b · inactive_from_b⁻¹.
        let active_from_inactive = match (request.active_from_inactive, request.loops.first()) {
            (Some(t), _) => t,
            (None, Some(l)) => {
                let (Some(a), Some(b)) =
                    (self.active.vertex(l.active), inactive.vertex(l.inactive))
                else {
                    return Err(bad("loop vertices vanished".into()));
                };
                a.pose
                    .compose(&l.inactive_from_active.inverse())
                    .compose(&b.pose.inverse())
            }
            (None, None) => return Err(bad("neither a transform nor loop edges".into())),
        };
        if !active_from_inactive.is_finite() {
            return Err(bad("non-finite transform".into()));
        }
        if inactive.num_vertices() == 0 {
            return Err(bad("the inactive graph is empty".into()));
        }
        let mut moved = inactive.clone();
        moved.reanchor(&active_from_inactive);
        for (_, v) in moved.vertices_mut() {
            v.fixed = false;
        }

        // 3. Union with the loop edges; a transform alone gets one consistent edge.
        let mut connecting: Vec<Edge<Se2, 3>> = request.loops.iter().map(LoopEdge::edge).collect();
        if connecting.is_empty() {
            connecting.push(self.forced_edge(robot, &moved)?);
        }
        let chi2_before = self.active.chi2();
        let active_before: Vec<NodeId> = self.active.vertices().map(|(id, _)| id).collect();
        let mut merged = self.active.clone();
        merged.union(&moved, &connecting)?;

        // 4. Further loops in the overlap, from the now-known poses.
        let overlap = match verifier {
            Some(verifier) if self.params.merge.overlap.enabled => {
                let joined: BTreeSet<NodeId> = request.loops.iter().map(|l| l.active).collect();
                self.overlap_loops(
                    &merged,
                    &active_before,
                    &moved,
                    &joined,
                    GatedVerifier::new(verifier, self.params.merge.overlap.min_score),
                    None,
                )
            }
            _ => Vec::new(),
        };
        for l in &overlap {
            merged.add_edge(l.edge())?;
        }

        // 5. Re-optimise, the robot held.
        optimize_holding(&mut merged, Some(robot), &self.params.optimizer)?;
        let chi2_after = merged.chi2();

        Ok(MergePreview {
            graph: merged,
            active_from_inactive,
            loop_edges: connecting.len(),
            overlap_edges: overlap.len(),
            chi2: [chi2_before, chi2_after],
        })
    }

    /// The edge a forced merge without loops gets: from the merged vertex nearest to the
    /// robot to the robot, measuring exactly what the transform implies.
    fn forced_edge(&self, robot: NodeId, moved: &PoseGraph2) -> Result<Edge<Se2, 3>, AtlasError> {
        let robot_pose = self
            .active
            .vertex(robot)
            .ok_or(AtlasError::MissingVertex {
                node: robot,
                graph: "active",
            })?
            .pose;
        let nearest = moved
            .vertices()
            .min_by(|x, y| {
                let dx = (x.1.pose.translation() - robot_pose.translation()).norm();
                let dy = (y.1.pose.translation() - robot_pose.translation()).norm();
                dx.total_cmp(&dy)
            })
            .map(|(id, v)| (id, v.pose))
            .ok_or(AtlasError::EmptyActive(self.epoch))?;
        let sigma = self.params.merge.forced_edge_sigma;
        Ok(Edge {
            from: nearest.0,
            to: robot,
            measurement: nearest.1.between(&robot_pose),
            information: information_from_covariance(&Matrix3::zeros(), sigma),
            kind: EdgeKind::Merge,
        })
    }

    /// Sec. III-A's search for more loops where the maps overlap: each tried active vertex
    /// (newest first, every `stride`-th) is verified against the nearest merged vertex from
    /// the guess the merge implies; matches that agree with the guess become loop edges.
    ///
    /// A pair that `first` does not join (or every pair, once `first` has `max_loops`) is
    /// verified by `then` when given; `first`'s loops come first in the result.
    fn overlap_loops(
        &self,
        merged: &PoseGraph2,
        active_nodes: &[NodeId],
        moved: &PoseGraph2,
        already_joined: &BTreeSet<NodeId>,
        first: GatedVerifier<'_>,
        then: Option<GatedVerifier<'_>>,
    ) -> Vec<LoopEdge> {
        let p = &self.params.merge.overlap;
        let mut pairs = Vec::new();
        for a in active_nodes.iter().rev().step_by(p.stride.max(1)) {
            if pairs.len() >= p.max_verifications {
                break;
            }
            if already_joined.contains(a) {
                continue;
            }
            let Some(pose_a) = merged.vertex(*a).map(|v| v.pose) else {
                continue;
            };
            // The nearest within the radius, one within the heading preferred.
            let nearest = moved
                .vertices()
                .map(|(id, v)| {
                    let turned = wrap_angle_rad(v.pose.theta_rad - pose_a.theta_rad).abs()
                        > p.max_heading_rad;
                    (
                        id,
                        turned,
                        (v.pose.translation() - pose_a.translation()).norm(),
                    )
                })
                .filter(|(_, turned, d)| *d <= p.radius_m && (p.any_heading || !turned))
                .min_by(|x, y| x.1.cmp(&y.1).then(x.2.total_cmp(&y.2)))
                .map(|(id, _, d)| (id, d));
            if let Some((b, _)) = nearest {
                pairs.push((*a, b));
            }
        }
        if pairs.is_empty() {
            return Vec::new();
        }
        // The active side from its scans alone; the moved map's side also from its stored
        // local maps.
        let (active_side, moved_side): (Vec<NodeId>, Vec<NodeId>) = pairs.iter().copied().unzip();
        let keyframe_params = &self.params.keyframes;
        let mut keyframes =
            local_map_keyframes(merged, &self.keyframes, keyframe_params, &active_side, None);
        keyframes.extend(local_map_keyframes(
            merged,
            &self.keyframes,
            keyframe_params,
            &moved_side,
            Some(&self.local_maps),
        ));
        // Each verification's loops, capped at `max_loops` each.
        let mut loops = Vec::new();
        let mut then_loops = Vec::new();
        for (a, b) in pairs {
            let first_full = loops.len() >= p.max_loops;
            if first_full && (then.is_none() || then_loops.len() >= p.max_loops) {
                break;
            }
            let (Some(ka), Some(kb)) = (keyframes.get(&a), keyframes.get(&b)) else {
                continue;
            };
            let (Some(va), Some(vb)) = (merged.vertex(a), merged.vertex(b)) else {
                continue;
            };
            let guess_b_from_a = vb.pose.between(&va.pose);
            let gated = |by: GatedVerifier<'_>| {
                let found = by.verifier.verify(ka, kb, &guess_b_from_a)?;
                let correction = guess_b_from_a.between(&found.candidate_from_query);
                (found.score >= by.min_score
                    && correction.translation().norm() <= p.gate_m
                    && wrap_angle_rad(correction.theta_rad).abs() <= p.gate_rad)
                    .then(|| LoopEdge {
                        active: a,
                        inactive: b,
                        inactive_from_active: found.candidate_from_query,
                        information: information_from_covariance(
                            &found.covariance,
                            self.params.merge.loop_min_sigma,
                        ),
                    })
            };
            if let Some(edge) = (!first_full).then(|| gated(first)).flatten() {
                loops.push(edge);
            } else if let Some(then) = then.filter(|_| then_loops.len() < p.max_loops) {
                then_loops.extend(gated(then));
            }
        }
        loops.append(&mut then_loops);
        loops
    }

    /// After a merge the robot keeps closing loops into the merged epochs' data, as its
    /// front-end does within its own epoch: the newest `newest` current-epoch vertices (every
    /// `overlap.stride`-th) are verified against the nearest other-epoch vertex of the active
    /// graph from the current estimate, and matches within the overlap gate become loop edges
    /// (kind `Merge`, so an unmerge removes them); then the active graph is re-optimised with
    /// the robot held. Without this the tracker's drift away from the merge point reads as
    /// contradictions to the invalid-merge detectors. Returns the edges added.
    pub fn close_loops_into_merged(
        &mut self,
        newest: usize,
        verifier: &dyn GeometricVerifier,
    ) -> Result<Vec<LoopEdge>, AtlasError> {
        if self.merges.is_empty() {
            return Ok(Vec::new());
        }
        let current = self.current_epoch_nodes();
        let tried = current
            .get(current.len().saturating_sub(newest)..)
            .unwrap_or(&[]);
        let other: BTreeSet<NodeId> = self
            .active
            .vertices()
            .filter(|(id, _)| !self.is_current_epoch(*id))
            .map(|(id, _)| id)
            .collect();
        let others = self.active.subgraph(&other);
        let overlap = &self.params.merge.overlap;
        let place = GatedVerifier::new(verifier, overlap.min_score);
        let (first, then) = match &self.constraints.merged_loop_verifier {
            None => (place, None),
            Some(local) => (
                GatedVerifier::new(local, self.params.loops.min_score),
                overlap.place_verifier_too.then_some(place),
            ),
        };
        let loops = self.overlap_loops(&self.active, tried, &others, &BTreeSet::new(), first, then);
        if loops.is_empty() {
            return Ok(loops);
        }
        for l in &loops {
            self.active.add_edge(l.edge())?;
        }
        self.optimize_active()?;
        Ok(loops)
    }

    /// How well the current epoch agrees with the epochs merged into it (issue 64, part 4):
    /// every edge between a current-epoch vertex and another epoch's (merge edges, overlap
    /// loops, loops into merged data, recovered loops) is tested at the optimised poses by
    /// the χ² test of the optimiser's robust kernel (DCS's Φ, else χ²₃(0.99)): within it the
    /// edge agrees; beyond it the kernel has down-weighted it, so the graph could not satisfy
    /// it. Zero counts when nothing is merged.
    pub fn epoch_agreement(&self) -> EpochAgreement {
        let mut agreement = EpochAgreement::default();
        if self.merges.is_empty() {
            return agreement;
        }
        let phi = match self.params.optimizer.robust {
            mapmerge_solve::RobustKernel::Dcs { phi } if phi.is_finite() && phi > 0.0 => phi,
            _ => mapmerge_solve::chi2_quantile_99(3),
        };
        for (_, edge) in self.active.edges() {
            if edge.is_prior() || self.is_current_epoch(edge.from) == self.is_current_epoch(edge.to)
            {
                continue;
            }
            let (Some(chi2), Some(residual)) =
                (self.active.edge_chi2(edge), self.active.edge_residual(edge))
            else {
                continue;
            };
            let off_m = residual.fixed_rows::<2>(0).norm();
            if chi2 <= phi {
                agreement.agreeing_edges += 1;
            } else {
                agreement.disagreeing_edges += 1;
                if edge.kind == EdgeKind::Merge {
                    agreement.disagreeing_merge_edges += 1;
                }
                agreement.worst_off_m = agreement.worst_off_m.max(off_m);
            }
        }
        agreement
    }

    /// While a merge of inactive graph `map` is conditional: the keyframes `nodes` (oldest
    /// first) verified against the nearest vertices of `map` in the conditionally merged
    /// graph `preview` (G', from [`Atlas::preview_merge`]), as the overlap search does after
    /// a merge (newest first, every `overlap.stride`-th when there are several, within its
    /// limits). Matches within the overlap gate are loop edges that confirm the merge; none
    /// are added.
    pub fn confirm_in_preview(
        &self,
        preview: &PoseGraph2,
        map: MapId,
        nodes: &[NodeId],
        verifier: &dyn GeometricVerifier,
    ) -> Vec<LoopEdge> {
        let Some(inactive) = self.inactive.get(&map) else {
            return Vec::new();
        };
        let ids: BTreeSet<NodeId> = inactive.vertices().map(|(id, _)| id).collect();
        let moved = preview.subgraph(&ids);
        self.overlap_loops(
            preview,
            nodes,
            &moved,
            &BTreeSet::new(),
            GatedVerifier::new(verifier, self.params.merge.overlap.min_score),
            None,
        )
    }

    /// The keyframes `nodes` of the active graph verified against the nearest vertices of
    /// inactive graph `map` placed at `active_from_inactive` (a merge hypothesis's estimate),
    /// as [`Atlas::confirm_in_preview`] verifies them in G': matches within the overlap gate
    /// are loop edges; none are added.
    pub fn confirm_at(
        &self,
        map: MapId,
        active_from_inactive: &Se2,
        nodes: &[NodeId],
        verifier: &dyn GeometricVerifier,
    ) -> Vec<LoopEdge> {
        let Some(inactive) = self.inactive.get(&map) else {
            return Vec::new();
        };
        let mut moved = PoseGraph2::new();
        for (id, vertex) in inactive.vertices() {
            let mut vertex = *vertex;
            vertex.pose = active_from_inactive.compose(&vertex.pose);
            let _ = moved.add_vertex(id, vertex);
        }
        // Both sides' vertices in one graph: local maps are built along each epoch's vertices.
        let mut placed = moved.clone();
        for (id, vertex) in self.active.vertices() {
            let _ = placed.add_vertex(id, *vertex);
        }
        self.overlap_loops(
            &placed,
            nodes,
            &moved,
            &BTreeSet::new(),
            GatedVerifier::new(verifier, self.params.merge.overlap.min_score),
            None,
        )
    }

    /// Undoes *all* merges into the active graph (Sec. III-B, on an invalid-merge detection):
    /// every merged inactive graph comes back from its backup exactly (poses, edges and their
    /// ids, metadata) under its old id; every other-epoch vertex leaves the active graph with
    /// its edges, while current-epoch vertices and the edges between them stay (also those
    /// added after the merge); then the active graph is re-optimised with the robot's vertex
    /// held. `None` when nothing is merged. On error the atlas is unchanged.
    pub fn unmerge_all(
        &mut self,
        reason: UnmergeReason,
    ) -> Result<Option<UnmergeEvent>, AtlasError> {
        if self.merges.is_empty() {
            return Ok(None);
        }
        let mut restored = Vec::with_capacity(self.merges.len());
        for applied in &self.merges {
            restored.push((*applied, self.backups.load(applied.merge)?));
        }
        let keep: BTreeSet<NodeId> = self
            .active
            .vertices()
            .filter(|(_, v)| EpochId::of(&v.meta) == self.epoch)
            .map(|(id, _)| id)
            .collect();
        let mut graph = self.active.subgraph(&keep);
        let removed_vertices = self.active.num_vertices() - graph.num_vertices();
        let removed_edges = self.active.num_edges() - graph.num_edges();
        optimize_holding(&mut graph, self.robot, &self.params.optimizer)?;

        // Commit.
        self.active = graph;
        let mut merges = Vec::with_capacity(restored.len());
        let mut restored_maps = Vec::with_capacity(restored.len());
        let mut undone_transforms = Vec::with_capacity(restored.len());
        for (applied, backup) in restored {
            undone_transforms.push(applied.active_from_inactive);
            self.inactive.insert(applied.map, backup);
            // A backup that cannot be deleted is only a stale file (merge ids are not reused).
            let _ = self.backups.remove(applied.merge);
            merges.push(applied.merge);
            restored_maps.push(applied.map);
        }
        self.merges.clear();
        let event = UnmergeEvent {
            active_epoch: self.epoch,
            merges,
            restored_maps,
            undone_transforms,
            removed_vertices,
            removed_edges,
            reason,
        };
        self.events.push(AtlasEvent::Unmerged(event.clone()));
        Ok(Some(event))
    }
}

impl Validate for MergeParams {
    fn check(&self, check: &mut Checker) {
        check
            .reals(
                "loop_min_sigma",
                &[
                    (self.loop_min_sigma.0, SIGMA_M),
                    (self.loop_min_sigma.1, SIGMA_RAD),
                ],
            )
            .reals(
                "forced_edge_sigma",
                &[
                    (self.forced_edge_sigma.0, SIGMA_M),
                    (self.forced_edge_sigma.1, SIGMA_RAD),
                ],
            )
            .nested("overlap", &self.overlap);
    }
}

impl Validate for OverlapParams {
    fn check(&self, check: &mut Checker) {
        check
            .real("radius_m", self.radius_m, Real::non_negative())
            .real(
                "max_heading_rad",
                self.max_heading_rad,
                Real::within(0.0, std::f64::consts::PI),
            )
            .size("stride", self.stride, 1, 100_000)
            .size("max_verifications", self.max_verifications, 0, 100_000)
            .size("max_loops", self.max_loops, 0, 100_000)
            .real("min_score", self.min_score, Real::fraction())
            .real("gate_m", self.gate_m, Real::non_negative())
            .real(
                "gate_rad",
                self.gate_rad,
                Real::within(0.0, std::f64::consts::PI),
            );
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use mapmerge_place::{Keyframe, Verification};
    use mapmerge_posegraph::Vertex;

    use super::*;
    use crate::events::EpochEndReason;
    use crate::AtlasParams;

    /// A gently curving path of `n` vertices from `start`, 0.5 m apart, with odometry edges.
    fn path(atlas: &mut Atlas, start: Se2, n: usize) -> Vec<NodeId> {
        path_with(atlas, start, n, Se2::new(0.5, 0.0, 0.05))
    }

    /// `n` vertices from `start`, each `step` after the one before, with odometry edges.
    fn path_with(atlas: &mut Atlas, start: Se2, n: usize, step: Se2) -> Vec<NodeId> {
        let mut pose = start;
        let mut nodes: Vec<NodeId> = Vec::new();
        for _ in 0..n {
            let id = atlas.add_vertex(Vertex::new(pose), Arc::from(vec![Point2::new(1.0, 0.0)]));
            if let Some(prev) = nodes.last() {
                atlas
                    .add_edge(Edge {
                        from: *prev,
                        to: id,
                        measurement: step,
                        information: Matrix3::identity() * 100.0,
                        kind: EdgeKind::Odometry,
                    })
                    .unwrap();
            }
            nodes.push(id);
            pose = pose.compose(&step);
        }
        nodes
    }

    use mapmerge_scan::Point2;

    fn close(x: &Se2, y: &Se2, tol: f64) -> bool {
        let d = x.between(y);
        d.translation().norm() < tol && d.theta_rad.abs() < tol
    }

    #[test]
    fn a_loop_edge_alone_places_the_inactive_graph() {
        let mut atlas = Atlas::new(AtlasParams::default()).unwrap();
        let old = path(&mut atlas, Se2::identity(), 10);
        let old_poses: Vec<Se2> = old
            .iter()
            .map(|id| atlas.active().vertex(*id).unwrap().pose)
            .collect();
        atlas.end_epoch(EpochEndReason::Kidnap);
        let new = path(&mut atlas, Se2::identity(), 6);
        // The truth: the inactive frame sits here in the active frame.
        let active_from_inactive = Se2::new(-1.0, 2.0, 0.7);
        let (a, b) = (new[3], old[5]);
        let pose_a = atlas.active().vertex(a).unwrap().pose;
        let pose_b_in_active = active_from_inactive.compose(&old_poses[5]);
        let request = MergeRequest {
            map: MapId(0),
            active_from_inactive: None,
            loops: vec![LoopEdge {
                active: a,
                inactive: b,
                inactive_from_active: pose_b_in_active.between(&pose_a),
                information: Matrix3::identity() * 100.0,
            }],
            reason: MergeReason::Forced { note: "t".into() },
        };
        let event = atlas.merge(request, None).unwrap();
        let applied = Se2::new(
            event.active_from_inactive[0],
            event.active_from_inactive[1],
            event.active_from_inactive[2],
        );
        assert!(close(&applied, &active_from_inactive, 1e-9), "{applied:?}");
        assert!(event.chi2[1] < 1e-12, "consistent data: {:?}", event.chi2);
        for (id, pose) in old.iter().zip(&old_poses) {
            let merged = atlas.active().vertex(*id).unwrap().pose;
            assert!(close(&merged, &active_from_inactive.compose(pose), 1e-6));
        }
        assert_eq!(event.merged_epochs, vec![EpochId(0)]);
    }

    #[test]
    fn epochs_agree_until_a_cross_epoch_edge_says_otherwise() {
        let mut atlas = Atlas::new(AtlasParams::default()).unwrap();
        assert_eq!(atlas.epoch_agreement(), EpochAgreement::default());
        let old = path(&mut atlas, Se2::identity(), 10);
        atlas.end_epoch(EpochEndReason::Kidnap);
        let new = path(&mut atlas, Se2::identity(), 10);
        let information = Matrix3::identity() * 100.0;
        let edge = |active: NodeId, inactive: NodeId, inactive_from_active: Se2| LoopEdge {
            active,
            inactive,
            inactive_from_active,
            information,
        };
        // Both epochs on one path: vertex k of the new epoch is vertex k of the old.
        let request = MergeRequest {
            map: MapId(0),
            active_from_inactive: None,
            loops: vec![
                edge(new[2], old[2], Se2::identity()),
                edge(new[7], old[7], Se2::identity()),
            ],
            reason: MergeReason::Forced { note: "t".into() },
        };
        atlas.merge(request, None).unwrap();
        let agreed = atlas.epoch_agreement();
        assert_eq!((agreed.agreeing_edges, agreed.disagreeing_edges), (2, 0));
        // A third match puts the old epoch 3 m to the side where the new one is: the robust
        // kernel gives way to the two that agree, so the graph cannot satisfy it.
        atlas
            .add_edge(edge(new[5], old[5], Se2::new(0.0, 3.0, 0.0)).edge())
            .unwrap();
        atlas.optimize_active().unwrap();
        let split = atlas.epoch_agreement();
        assert_eq!(
            (split.agreeing_edges, split.disagreeing_edges),
            (2, 1),
            "{split:?}"
        );
        assert_eq!(split.disagreeing_merge_edges, 1, "{split:?}");
        assert!(split.worst_off_m > 2.0, "{split:?}");
        // Odometry inside an epoch is not judged; a final merge is not judged at all.
        atlas.end_epoch(EpochEndReason::Kidnap);
        assert_eq!(atlas.epoch_agreement(), EpochAgreement::default());
    }

    /// Confirms every guess, moved by `offset`.
    struct Fake {
        offset: Se2,
    }

    impl GeometricVerifier for Fake {
        fn verify(&self, _: &Keyframe, _: &Keyframe, guess: &Se2) -> Option<Verification> {
            Some(Verification {
                candidate_from_query: guess.compose(&self.offset),
                score: 1.0,
                covariance: Matrix3::identity() * 1e-4,
            })
        }
    }

    fn overlapping() -> Atlas {
        let mut atlas = Atlas::new(AtlasParams::default()).unwrap();
        path(&mut atlas, Se2::identity(), 12);
        atlas.end_epoch(EpochEndReason::Kidnap);
        path(&mut atlas, Se2::identity(), 12);
        atlas
    }

    #[test]
    fn the_overlap_search_adds_loops_that_agree_with_the_merge() {
        let mut atlas = overlapping();
        let fake = Fake {
            offset: Se2::new(0.05, 0.0, 0.01),
        };
        let request = MergeRequest::forced(MapId(0), Se2::new(0.2, 0.1, 0.0), "t");
        let event = atlas.merge(request, Some(&fake)).unwrap();
        let p = OverlapParams::default();
        assert!(event.overlap_edges > 0 && event.overlap_edges <= p.max_loops);
        assert_eq!(
            atlas
                .active()
                .edges()
                .filter(|(_, e)| e.kind == EdgeKind::Merge)
                .count(),
            1 + event.overlap_edges
        );
    }

    #[test]
    fn the_overlap_search_refuses_matches_far_from_the_merge() {
        let mut atlas = overlapping();
        let fake = Fake {
            offset: Se2::new(1.5, 0.0, 0.0),
        };
        let request = MergeRequest::forced(MapId(0), Se2::new(0.2, 0.1, 0.0), "t");
        let event = atlas.merge(request, Some(&fake)).unwrap();
        assert_eq!(event.overlap_edges, 0);
    }

    /// A robot driving the old path the other way: no old vertex within 60° of its heading,
    /// so only `any_heading` finds it partners.
    #[test]
    fn the_overlap_search_pairs_a_robot_driving_the_other_way() {
        let step = Se2::new(0.5, 0.0, 0.05);
        let turn = Se2::new(0.0, 0.0, std::f64::consts::PI);
        let backwards = turn.inverse().compose(&step.inverse()).compose(&turn);
        let edges = |any_heading: bool| {
            let mut params = AtlasParams::default();
            params.merge.overlap.any_heading = any_heading;
            let mut atlas = Atlas::new(params).unwrap();
            let old = path(&mut atlas, Se2::identity(), 12);
            let end = atlas.active().vertex(old[11]).unwrap().pose;
            atlas.end_epoch(EpochEndReason::Kidnap);
            path_with(&mut atlas, end.compose(&turn), 12, backwards);
            let fake = Fake {
                offset: Se2::new(0.05, 0.0, 0.01),
            };
            let request = MergeRequest::forced(MapId(0), Se2::identity(), "t");
            atlas.merge(request, Some(&fake)).unwrap().overlap_edges
        };
        assert!(edges(true) > 0);
        assert_eq!(edges(false), 0);
    }

    #[test]
    fn information_is_floored_and_finite() {
        let info = information_from_covariance(&Matrix3::zeros(), (0.1, 0.02));
        assert!((info[(0, 0)] - 100.0).abs() < 1e-9);
        let nan = information_from_covariance(&Matrix3::from_element(f64::NAN), (0.1, 0.02));
        assert!(nan.iter().all(|v| v.is_finite()));
    }
}
