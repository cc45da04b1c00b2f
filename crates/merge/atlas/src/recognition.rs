//! Place recognition between the active graph and every inactive graph (never between
//! inactive graphs; Holoch et al., Sec. III-A), on keyframes made from the stored scans.

use std::collections::BTreeMap;
use std::sync::Arc;

use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_place::{
    EvidenceParams, GeometricVerifier, Keyframe, PlaceDatabase, PlaceParams, ScanMatchVerifier,
};
use mapmerge_posegraph::{NodeId, PoseGraph2};
use mapmerge_scan::{transform_points, voxel_downsample, Point2};
use mapmerge_scanmatch::{ScanMatchError, ScanMatchParams, SearchWindow};
use serde::{Deserialize, Serialize};

use crate::atlas::Atlas;
use crate::backup::BackupStore;
use crate::error::AtlasError;
use crate::events::{MergeEvent, MergeReason};
use crate::ids::{EpochId, MapId};
use crate::merge::{information_from_covariance, LoopEdge, MergeRequest};
use crate::scans::ScanStore;

/// The keyframes place recognition and the overlap search match: a vertex's scan plus the
/// scans of the same epoch's preceding vertices within some travel, in the vertex's frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct KeyframeParams {
    /// Scans of the preceding vertices of the same epoch within this path length (m) join
    /// the keyframe (default: 6; 0 = the vertex's scan alone). Local maps see more structure
    /// than one scan, which place recognition across sessions needs (`mapmerge-place`'s
    /// benchmark uses 6 m).
    pub local_map_m: f64,
    /// A local map is thinned to one point per cell of this size (m) (default: 0.1).
    pub voxel_m: f64,
}

impl Default for KeyframeParams {
    fn default() -> Self {
        Self {
            local_map_m: 6.0,
            voxel_m: 0.1,
        }
    }
}

/// Place recognition between the active graph and the inactive graphs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RecognitionParams {
    /// Retrieval and verification (default: the 10 best Scan Context candidates within
    /// distance 0.6, accepted from score 0.85 — `mapmerge-place`'s benchmark setting for the
    /// evidence score of [`default_verifier`], without a false loop on the 13 public logs).
    pub place: PlaceParams,
    /// A loop also needs this confidence (gap to the best rival place) (default: 0.2):
    /// look-alike places are refused.
    pub min_confidence: f64,
    /// Only the newest this many current-epoch vertices query (default: 0 = every vertex of
    /// the active graph). A live robot querying after each keyframe sets a few.
    pub recent_queries: usize,
    /// Loops agree on the merge when the transforms they imply are within this (m) ...
    /// (default: 0.5)
    pub agreement_m: f64,
    /// ... and this (rad) (default: 5°).
    pub agreement_rad: f64,
    /// A merge needs at least this many agreeing loops (default: 1; the verifier's evidence
    /// and the confidence already refuse look-alikes, and a wrong merge can be undone).
    pub min_loops: usize,
}

impl Default for RecognitionParams {
    fn default() -> Self {
        Self {
            place: PlaceParams {
                candidates_per_query: 10,
                max_descriptor_distance: 0.6,
                min_score: 0.85,
                ..PlaceParams::default()
            },
            min_confidence: 0.2,
            recent_queries: 0,
            agreement_m: 0.5,
            agreement_rad: 5f64.to_radians(),
            min_loops: 1,
        }
    }
}

/// The verifier the atlas's defaults are tuned for: the correlative matcher with ICP in a
/// ±2 m, ±15° window, scored by its evidence (`mapmerge-place`'s benchmark configuration).
pub fn default_verifier() -> Result<ScanMatchVerifier, ScanMatchError> {
    Ok(ScanMatchVerifier::new(
        ScanMatchParams::default(),
        SearchWindow::new(2.0, 15f64.to_radians()),
    )?
    .with_evidence(EvidenceParams::default()))
}

/// A verified match of the active graph in an inactive graph.
#[derive(Clone, Debug, PartialEq)]
pub struct MergeProposal {
    /// The inactive graph.
    pub map: MapId,
    /// Where it goes in the active graph's frame (implied by the best loop).
    pub active_from_inactive: Se2,
    /// The agreeing loops, best first.
    pub loops: Vec<LoopEdge>,
    /// The best loop's verification score.
    pub score: f64,
    /// The best loop's confidence.
    pub confidence: f64,
}

impl MergeProposal {
    /// The request that merges it.
    pub fn into_request(self) -> MergeRequest {
        MergeRequest {
            map: self.map,
            active_from_inactive: Some(self.active_from_inactive),
            reason: MergeReason::PlaceRecognition {
                loops: self.loops.len(),
                score: self.score,
                confidence: self.confidence,
            },
            loops: self.loops,
        }
    }
}

/// Keyframes of `nodes` of `graph` as local maps (see [`KeyframeParams`]), keyed by node
/// (the keyframe id is the node id; node ids are unique in the atlas). Nodes without a
/// vertex are skipped; vertices without a scan count as empty.
pub(crate) fn local_map_keyframes(
    graph: &PoseGraph2,
    scans: &ScanStore,
    params: &KeyframeParams,
    nodes: &[NodeId],
) -> BTreeMap<NodeId, Keyframe> {
    let order: Vec<(NodeId, Se2, EpochId)> = graph
        .vertices()
        .map(|(id, v)| (id, v.pose, EpochId::of(&v.meta)))
        .collect();
    let scan = |id: NodeId| scans.get(id).map(|s| &s[..]).unwrap_or(&[]);
    let mut keyframes = BTreeMap::new();
    for node in nodes {
        let Ok(i) = order.binary_search_by(|(id, _, _)| id.cmp(node)) else {
            continue;
        };
        let (_, map_from_node, epoch) = order[i];
        let mut points: Vec<Point2> = scan(*node).to_vec();
        let mut travel_m = 0.0;
        // Node ids grow with time within an epoch: the preceding ids are the path so far.
        for j in (0..i).rev() {
            let (id, pose, e) = order[j];
            if e != epoch {
                break;
            }
            travel_m += (order[j + 1].1.translation() - pose.translation()).norm();
            if travel_m > params.local_map_m {
                break;
            }
            points.extend(transform_points(&map_from_node.between(&pose), scan(id)));
        }
        if params.local_map_m > 0.0 {
            points = voxel_downsample(&points, params.voxel_m);
        }
        keyframes.insert(*node, Keyframe::new(node.0, points));
    }
    keyframes
}

/// An inactive graph's keyframes, described and indexed once (`Atlas::place_database`).
pub(crate) struct CachedDatabase {
    /// Vertex count, edge count and next edge id of the graph it was built from: any edit
    /// (pruning, a new epoch's graph under a reused id) changes it.
    fingerprint: (usize, usize, u64),
    database: Arc<PlaceDatabase<'static>>,
}

impl<B: BackupStore> Atlas<B> {
    /// The place database of inactive graph `map`: its vertices' local-map keyframes with
    /// their poses, built on first use and kept while the graph is unchanged (a live robot
    /// queries the same inactive maps after every few keyframes).
    fn place_database(&self, map: MapId, graph: &PoseGraph2) -> Arc<PlaceDatabase<'static>> {
        let fingerprint = (
            graph.num_vertices(),
            graph.num_edges(),
            graph.next_edge_id().0,
        );
        let mut cache = self
            .place_cache
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(cached) = cache.get(&map).filter(|c| c.fingerprint == fingerprint) {
            return Arc::clone(&cached.database);
        }
        let ids: Vec<NodeId> = graph.vertices().map(|(id, _)| id).collect();
        let by_node = local_map_keyframes(graph, &self.scans, &self.params.keyframes, &ids);
        let map_from_b: Vec<Se2> = by_node
            .keys()
            .filter_map(|id| graph.vertex(*id).map(|v| v.pose))
            .collect();
        let keyframes_b: Vec<Keyframe> = by_node.into_values().collect();
        let place = &self.params.recognition.place;
        let database = Arc::new(PlaceDatabase::new(
            &place.descriptor,
            keyframes_b.into(),
            Some(map_from_b.into()),
            place,
        ));
        cache.insert(
            map,
            CachedDatabase {
                fingerprint,
                database: Arc::clone(&database),
            },
        );
        database
    }

    /// Place recognition between the active graph and every inactive graph (Sec. III-A):
    /// keyframes of the active graph query each inactive graph (`find_loop_candidates_with_
    /// poses`, B's poses telling repeated visits apart), loops below the confidence are
    /// dropped, and the loops that agree on one transform (the largest such set) make a
    /// proposal. One proposal per matched inactive graph, most loops (then best score) first.
    pub fn find_merges(&self, verifier: &impl GeometricVerifier) -> Vec<MergeProposal> {
        let p = &self.params.recognition;
        let mut queries: Vec<NodeId> = self.active.vertices().map(|(id, _)| id).collect();
        if p.recent_queries > 0 {
            queries.retain(|id| self.is_current_epoch(*id));
            let skip = queries.len().saturating_sub(p.recent_queries);
            queries.drain(..skip);
        }
        if queries.is_empty() {
            return Vec::new();
        }
        let keyframes_a: Vec<Keyframe> =
            local_map_keyframes(&self.active, &self.scans, &self.params.keyframes, &queries)
                .into_values()
                .collect();
        let mut proposals = Vec::new();
        for (map, graph) in &self.inactive {
            let database = self.place_database(*map, graph);
            let found = database.search(&p.place.descriptor, &keyframes_a, verifier, &p.place);
            // Each loop with the transform it implies.
            let mut implied: Vec<(LoopEdge, Se2, f64, f64)> = found
                .into_iter()
                .filter(|l| l.confidence >= p.min_confidence)
                .filter_map(|l| {
                    let (a, b) = (NodeId(l.a.0), NodeId(l.b.0));
                    let pose_a = self.active.vertex(a)?.pose;
                    let pose_b = graph.vertex(b)?.pose;
                    let active_from_inactive = pose_a
                        .compose(&l.b_from_a.inverse())
                        .compose(&pose_b.inverse());
                    let edge = LoopEdge {
                        active: a,
                        inactive: b,
                        inactive_from_active: l.b_from_a,
                        information: information_from_covariance(
                            &l.covariance,
                            self.params.merge.loop_min_sigma,
                        ),
                    };
                    Some((edge, active_from_inactive, l.score, l.confidence))
                })
                .collect();
            implied.sort_by(|x, y| y.2.total_cmp(&x.2));
            let agree = |x: &Se2, y: &Se2| {
                (x.translation() - y.translation()).norm() <= p.agreement_m
                    && wrap_angle_rad(x.theta_rad - y.theta_rad).abs() <= p.agreement_rad
            };
            // The largest set of loops agreeing with one loop's transform (best score wins ties).
            let best = implied
                .iter()
                .map(|(_, t, _, _)| implied.iter().filter(|(_, u, _, _)| agree(t, u)).count())
                .enumerate()
                .max_by(|x, y| x.1.cmp(&y.1).then(y.0.cmp(&x.0)));
            let Some((i, count)) = best else {
                continue;
            };
            if count < p.min_loops.max(1) {
                continue;
            }
            let (_, t, score, confidence) = implied[i];
            let loops: Vec<LoopEdge> = implied
                .iter()
                .filter(|(_, u, _, _)| agree(&t, u))
                .map(|(l, _, _, _)| *l)
                .collect();
            proposals.push(MergeProposal {
                map: *map,
                active_from_inactive: t,
                loops,
                score,
                confidence,
            });
        }
        proposals.sort_by(|x, y| {
            y.loops
                .len()
                .cmp(&x.loops.len())
                .then(y.score.total_cmp(&x.score))
        });
        proposals
    }

    /// Finds merges ([`Atlas::find_merges`]) and performs the best one, with the overlap search
    /// by the same verifier. `None` when nothing matched. Call again for further merges: the
    /// merged graph is part of the active graph then.
    pub fn merge_by_recognition<V: GeometricVerifier>(
        &mut self,
        verifier: &V,
    ) -> Result<Option<MergeEvent>, AtlasError> {
        let Some(best) = self.find_merges(verifier).into_iter().next() else {
            return Ok(None);
        };
        self.merge(best.into_request(), Some(verifier)).map(Some)
    }
}
