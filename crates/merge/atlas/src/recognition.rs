//! Place recognition between the active graph and every inactive graph (never between
//! inactive graphs; Holoch et al., Sec. III-A): its parameters, the local-map keyframes it
//! verifies, and the proposals it makes (the search itself is the constraint builder's,
//! `crate::constraints`).

use std::collections::BTreeMap;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{ClassThresholds, FreeSpace};
use mapmerge_params::{Checker, Real, Validate};
use mapmerge_place::{
    GeometricVerifier, Keyframe, PlaceParams, PlaceVerifierParams, ScanMatchVerifier,
};
use mapmerge_posegraph::{NodeId, PoseGraph2};
use mapmerge_scan::{transform_points, voxel_downsample, Point2};
use mapmerge_scanmatch::ScanMatchError;
use serde::{Deserialize, Serialize};

use crate::atlas::Atlas;
use crate::backup::BackupStore;
use crate::error::AtlasError;
use crate::events::{MergeEvent, MergeReason};
use crate::ids::{EpochId, MapId};
use crate::keyframes::KeyframeStore;
use crate::local_maps::LocalMapGrid;
use crate::merge::{LoopEdge, MergeRequest};

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
    /// Cell size (m) of the free space a keyframe keeps, the cells its scans' beams crossed
    /// (from each vertex's origin), so that verification compares two local maps over their
    /// whole overlap ([`mapmerge_place::Evidence::agreement`], a score on its own scale:
    /// `RecognitionParams::place.min_score` and `MergeParams::overlap.min_score` are set on
    /// it); 0 keeps none and scores by the scan-level evidence instead (default: 0.1; on the
    /// simulator's held-out seeds it cut wrong merges from 51 to 13).
    pub free_space_m: f64,
}

impl Default for KeyframeParams {
    fn default() -> Self {
        Self {
            local_map_m: 6.0,
            voxel_m: 0.1,
            free_space_m: 0.1,
        }
    }
}

/// Place recognition between the active graph and the inactive graphs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RecognitionParams {
    /// Verification and acceptance (default: the 3 best Scan Context candidates within
    /// distance 0.6 of the newest keyframe, verified as local maps by
    /// [`default_verifier`] and accepted from score 0.975, a whole-map agreement since the
    /// local maps carry their free space (`KeyframeParams::free_space_m`; chosen on the
    /// simulator's tuning seeds 1–10, where 0.95 let 2 wrong merges through; without free
    /// space the old evidence score was accepted from 0.7)). Retrieval uses the atlas's one
    /// place index, whose descriptor is `loops.place.descriptor`; `descriptor` and `index`
    /// here are not used.
    pub place: PlaceParams,
    /// A match also needs this confidence (gap to the best rival place of the same graph)
    /// (default: 0.05: look-alike places score alike and are refused; evidence accumulates
    /// over several matches before a merge).
    pub min_confidence: f64,
    /// The inactive graphs (and, while merged, the merged data) are searched every this
    /// many keyframes (default: 5) ...
    pub every_keyframes: usize,
    /// ... once the current epoch has at least this many keyframes (default: 10): a local
    /// map needs some travel before it is distinctive.
    pub min_epoch_keyframes: usize,
    /// An epoch that a restart began (a new session with a stored map) searches the
    /// inactive graphs at every keyframe from its first until it has travelled this far
    /// (m): a new session first looks for its pose in the stored map (default: 5; 0: as any
    /// epoch).
    pub session_start_search_m: f64,
    /// The geometric verifier of the merge search (default: [`PlaceVerifierParams`]'s).
    pub verifier: PlaceVerifierParams,
    /// The query is also described as if seen from these offsets (m) to the robot's left
    /// (negative: right), and the `place.candidates_per_query` nearest of all those lists
    /// are verified (Kim et al., "Scan Context++", T-RO 2021, Sec. IV-B, lateral
    /// augmentation: a polar descriptor changes quickly with a sideways offset, so a robot
    /// passing 0.5–1 m beside its earlier path ranks the true place low; against a map whose
    /// views are pruned to a budget per m², the nearest view is often that far). Default
    /// ±1 m; empty: the query as seen from the robot only.
    pub lateral_offsets_m: Vec<f64>,
    /// Keep a trace of every merge query against every inactive graph (what was retrieved,
    /// each admitted candidate's verification, what was accepted) for diagnosis
    /// ([`Atlas::merge_trace`]); verifies each admitted candidate once more (default: false).
    pub trace: bool,
}

/// One merge query against one inactive graph (`recognition.trace`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MergeQueryTrace {
    /// The query keyframe and the graph searched.
    pub query: NodeId,
    pub map: MapId,
    /// Retrieved keyframes with their descriptor distance, nearest first, and whether the
    /// distance admitted them to verification.
    pub retrieved: Vec<(NodeId, f64, bool)>,
    /// Each admitted candidate verified: node, `candidate_from_query`, score (none when the
    /// verifier found no alignment).
    pub verified: Vec<(NodeId, Option<(Se2, f64)>)>,
    /// The accepted match: node, `candidate_from_query`, score, confidence.
    pub accepted: Option<(NodeId, Se2, f64, f64)>,
}

impl Default for RecognitionParams {
    fn default() -> Self {
        Self {
            place: PlaceParams {
                candidates_per_query: 3,
                max_descriptor_distance: 0.6,
                min_score: 0.975,
                ..PlaceParams::default()
            },
            min_confidence: 0.05,
            every_keyframes: 5,
            min_epoch_keyframes: 10,
            session_start_search_m: 5.0,
            verifier: PlaceVerifierParams::default().with_flip_by_agreement(),
            lateral_offsets_m: vec![-1.0, 1.0],
            trace: false,
        }
    }
}

/// The verifier the atlas's defaults are tuned for ([`RecognitionParams::verifier`]'s
/// default: the correlative matcher with ICP in a ±2 m, ±15° window, scored by its evidence).
pub fn default_verifier() -> Result<ScanMatchVerifier, ScanMatchError> {
    PlaceVerifierParams::default().verifier()
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
    /// The best loop's covariance (right tangent of its `inactive_from_active`).
    pub covariance: nalgebra::Matrix3<f64>,
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
///
/// With `stored`, the stored local maps anchored in `graph` add their occupied cells (as
/// points) and free cells within `local_map_m` of the vertex: a lifelong map whose views were
/// pruned (iRobot Sec. 4.1) is matched against what it keeps of the place, not against the
/// few scans left. Only for candidates in an older map: a query's keyframe is its own data.
pub(crate) fn local_map_keyframes(
    graph: &PoseGraph2,
    scans: &KeyframeStore,
    params: &KeyframeParams,
    nodes: &[NodeId],
    stored: Option<&BTreeMap<NodeId, LocalMapGrid>>,
) -> BTreeMap<NodeId, Keyframe> {
    let order = vertex_order(graph);
    nodes
        .iter()
        .filter_map(|node| {
            let parts = local_map_parts(&order, scans, params, *node, stored)?;
            Some((*node, parts.into_keyframe(node.0, params)))
        })
        .collect()
}

/// The local maps of `nodes` joined in the first one's frame, as one keyframe with its id:
/// what those views saw together. `None` when the first is not a vertex of `graph`.
pub(crate) fn joint_local_map(
    graph: &PoseGraph2,
    scans: &KeyframeStore,
    params: &KeyframeParams,
    nodes: &[NodeId],
    stored: Option<&BTreeMap<NodeId, LocalMapGrid>>,
) -> Option<Keyframe> {
    let order = vertex_order(graph);
    let first = *nodes.first()?;
    let map_from_first = graph.vertex(first)?.pose;
    let mut joint = LocalMapParts::default();
    for node in nodes {
        let (Some(parts), Some(vertex)) = (
            local_map_parts(&order, scans, params, *node, stored),
            graph.vertex(*node),
        ) else {
            continue;
        };
        let first_from_node = map_from_first.between(&vertex.pose);
        let moved = |p: &Point2| first_from_node.transform_point(p);
        joint.points.extend(parts.points.iter().map(moved));
        joint
            .rays
            .extend(parts.rays.iter().map(|(o, e)| (moved(o), moved(e))));
        joint.free_cells.extend(parts.free_cells.iter().map(moved));
    }
    Some(joint.into_keyframe(first.0, params))
}

/// Every vertex of `graph` in id order, with its pose and epoch.
fn vertex_order(graph: &PoseGraph2) -> Vec<(NodeId, Se2, EpochId)> {
    graph
        .vertices()
        .map(|(id, v)| (id, v.pose, EpochId::of(&v.meta)))
        .collect()
}

/// A local map before it becomes a keyframe (node frame).
#[derive(Default)]
struct LocalMapParts {
    points: Vec<Point2>,
    /// Beams from each vertex's origin to its returns (when free space is kept).
    rays: Vec<(Point2, Point2)>,
    /// Free cells of the stored local maps.
    free_cells: Vec<Point2>,
}

impl LocalMapParts {
    fn into_keyframe(self, id: u64, params: &KeyframeParams) -> Keyframe {
        let points = if params.local_map_m > 0.0 {
            voxel_downsample(&self.points, params.voxel_m)
        } else {
            self.points
        };
        let keyframe = Keyframe::new(id, points);
        if self.free_cells.is_empty() {
            keyframe.with_rays(params.free_space_m, self.rays)
        } else {
            with_free_cells(keyframe, params.free_space_m, self.rays, self.free_cells)
        }
    }
}

/// `node`'s scan, the scans of the same epoch's preceding vertices within
/// `params.local_map_m` of travel, and with `stored` what the stored local maps keep within
/// that distance, in `node`'s frame; `None` when `node` is not in `order`.
fn local_map_parts(
    order: &[(NodeId, Se2, EpochId)],
    scans: &KeyframeStore,
    params: &KeyframeParams,
    node: NodeId,
    stored: Option<&BTreeMap<NodeId, LocalMapGrid>>,
) -> Option<LocalMapParts> {
    let scan = |id: NodeId| scans.get(id).map(|s| &s[..]).unwrap_or(&[]);
    let i = order.binary_search_by(|(id, _, _)| id.cmp(&node)).ok()?;
    let (_, map_from_node, epoch) = order[i];
    let mut points: Vec<Point2> = scan(node).to_vec();
    let keep_rays = params.free_space_m > 0.0;
    let mut rays: Vec<(Point2, Point2)> = Vec::new();
    if keep_rays {
        rays.extend(points.iter().map(|p| (Point2::zeros(), *p)));
    }
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
        let node_from_other = map_from_node.between(&pose);
        let other = transform_points(&node_from_other, scan(id));
        if keep_rays {
            let origin = node_from_other.translation();
            rays.extend(other.iter().map(|p| (origin, *p)));
        }
        points.extend(other);
    }
    let mut free_cells = Vec::new();
    if let Some(grids) = stored.filter(|_| params.local_map_m > 0.0) {
        let anchored = grids.iter().filter_map(|(anchor, grid)| {
            let k = order.binary_search_by(|(id, _, _)| id.cmp(anchor)).ok()?;
            Some((map_from_node.between(&order[k].1), grid))
        });
        for (node_from_anchor, grid) in anchored {
            let node_in_anchor = node_from_anchor.inverse().translation();
            if node_in_anchor.norm() > params.local_map_m + grid.reach_m() {
                continue;
            }
            let (occupied, free) = grid.cells_within(
                &node_in_anchor,
                params.local_map_m,
                &ClassThresholds::default(),
            );
            points.extend(transform_points(&node_from_anchor, &occupied));
            free_cells.extend(transform_points(&node_from_anchor, &free));
        }
    }
    Some(LocalMapParts {
        points,
        rays,
        free_cells,
    })
}

/// `keyframe` with the free space of `rays` and of the stored maps' `free_cells` (keyframe
/// frame) at `resolution_m`, leaving out every cell that holds one of its points (a wall's
/// cell is not free because a finer map saw its other half empty).
fn with_free_cells(
    keyframe: Keyframe,
    resolution_m: f64,
    rays: Vec<(Point2, Point2)>,
    free_cells: Vec<Point2>,
) -> Keyframe {
    // Not positive, or NaN: no cells to rasterise.
    if resolution_m.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return keyframe;
    }
    let cell = |p: &Point2| {
        (
            (p.x / resolution_m).floor() as i64,
            (p.y / resolution_m).floor() as i64,
        )
    };
    let occupied: std::collections::HashSet<(i64, i64)> =
        keyframe.points_in_keyframe.iter().map(cell).collect();
    let free = free_cells
        .into_iter()
        .filter(|p| !occupied.contains(&cell(p)));
    match FreeSpace::from_rays_and_cells(resolution_m, rays, free) {
        Ok(free_space) => keyframe.with_free_space(free_space),
        Err(_) => keyframe,
    }
}

impl<B: BackupStore> Atlas<B> {
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

impl Validate for KeyframeParams {
    fn check(&self, check: &mut Checker) {
        check
            .real("local_map_m", self.local_map_m, Real::within(0.0, 1000.0))
            .real("voxel_m", self.voxel_m, Real::within(0.0, 10.0))
            .real("free_space_m", self.free_space_m, Real::within(0.0, 10.0))
            .rule(
                "free_space_m",
                self.free_space_m,
                self.free_space_m == 0.0 || self.free_space_m >= 0.01,
                "must be 0 (none) or at least 0.01",
            );
    }
}

impl Validate for RecognitionParams {
    fn check(&self, check: &mut Checker) {
        check
            .nested("place", &self.place)
            .real("min_confidence", self.min_confidence, Real::fraction())
            .size("every_keyframes", self.every_keyframes, 1, 1_000_000)
            // A threshold, not a size: a huge one never searches.
            .size("min_epoch_keyframes", self.min_epoch_keyframes, 0, u64::MAX)
            .real(
                "session_start_search_m",
                self.session_start_search_m,
                Real::non_negative(),
            )
            .nested("verifier", &self.verifier)
            .size("lateral_offsets_m.len", self.lateral_offsets_m.len(), 0, 16);
        for (k, offset_m) in self.lateral_offsets_m.iter().enumerate() {
            check.real(
                &format!("lateral_offsets_m[{k}]"),
                *offset_m,
                Real::within(-100.0, 100.0),
            );
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use mapmerge_posegraph::Vertex;

    use super::*;
    use crate::keyframes::KeyframeRecord;

    /// A wall along y = 2 m from x = −2 to 2 m, a return every 0.1 m, in the frame of a robot
    /// at the origin.
    fn wall() -> Vec<Point2> {
        (-20..=20)
            .map(|i| Point2::new(f64::from(i) * 0.1, 2.0))
            .collect()
    }

    /// Two vertices of one graph 3 m apart; the second keeps its (empty) view, the first
    /// anchors a local map of the wall (its view pruned).
    fn pruned_place() -> (PoseGraph2, KeyframeStore, BTreeMap<NodeId, LocalMapGrid>) {
        let mut graph = PoseGraph2::new();
        graph
            .add_vertex(NodeId(1), Vertex::new(Se2::new(0.0, 0.0, 0.0)))
            .unwrap();
        graph
            .add_vertex(
                NodeId(2),
                Vertex::new(Se2::new(3.0, 0.0, std::f64::consts::FRAC_PI_2)),
            )
            .unwrap();
        let mut scans = KeyframeStore::default();
        scans.insert(
            NodeId(2),
            KeyframeRecord {
                points_in_robot: Vec::new().into(),
                travel_m: 3.0,
                local_from_robot: Se2::identity(),
                submap: None,
            },
        );
        let wall = wall();
        // Seen twice: two misses make a cell free.
        let seen = [(Se2::identity(), &wall[..]), (Se2::identity(), &wall[..])];
        let grid = LocalMapGrid::from_keyframes(0.05, seen).unwrap();
        let grids = BTreeMap::from([(NodeId(1), grid)]);
        (graph, scans, grids)
    }

    #[test]
    fn a_pruned_place_is_matched_against_its_stored_local_map() {
        let (graph, scans, grids) = pruned_place();
        let params = KeyframeParams::default();
        let bare = local_map_keyframes(&graph, &scans, &params, &[NodeId(2)], None);
        assert!(
            bare[&NodeId(2)].points_in_keyframe.is_empty(),
            "no scan, no map"
        );
        let stored = local_map_keyframes(&graph, &scans, &params, &[NodeId(2)], Some(&grids));
        let keyframe = &stored[&NodeId(2)];
        // The wall y = 2 (map frame) lies at x = 2 in vertex 2's frame (at (3, 0), facing +y).
        let node_from_map = Se2::new(3.0, 0.0, std::f64::consts::FRAC_PI_2).inverse();
        let points = &keyframe.points_in_keyframe;
        assert!(points.len() > 10, "{} points", points.len());
        for p in points.iter() {
            assert!((p.x - 2.0).abs() < 0.1, "{p:?} off the wall");
            assert!(
                p.norm() <= params.local_map_m + 0.1,
                "{p:?} beyond the radius"
            );
        }
        let free = keyframe.free_space.as_ref().expect("free cells");
        let between = node_from_map.transform_point(&Point2::new(1.0, 1.0));
        assert!(free.is_free(&between), "the beams' cells are free");
        for p in points.iter() {
            assert!(!free.is_free(p), "{p:?} is a return and free");
        }
    }

    #[test]
    fn a_joint_local_map_holds_every_view_in_the_first_ones_frame() {
        let (graph, mut scans, _) = pruned_place();
        let record = |points: Vec<Point2>| KeyframeRecord {
            points_in_robot: points.into(),
            travel_m: 0.0,
            local_from_robot: Se2::identity(),
            submap: None,
        };
        // Vertex 1 sees the wall y = 2; vertex 2 (at (3, 0), facing +y) a post 1 m ahead.
        scans.insert(NodeId(1), record(wall()));
        scans.insert(NodeId(2), record(vec![Point2::new(1.0, 0.0)]));
        let params = KeyframeParams {
            local_map_m: 0.0,
            ..KeyframeParams::default()
        };
        let nodes = [NodeId(1), NodeId(2)];
        let joint = joint_local_map(&graph, &scans, &params, &nodes, None).unwrap();
        assert_eq!(joint.id.0, 1);
        let points = &joint.points_in_keyframe;
        assert_eq!(points.len(), wall().len() + 1);
        // The post at (3, 1) in vertex 1's frame, the map's.
        assert!(points
            .iter()
            .any(|p| (p - Point2::new(3.0, 1.0)).norm() < 1e-9));
        assert!(joint.free_space.is_some(), "both views' beams");
        let reversed = [NodeId(2), NodeId(1)];
        let other_frame = joint_local_map(&graph, &scans, &params, &reversed, None).unwrap();
        assert_eq!(other_frame.id.0, 2);
        assert!(joint_local_map(&graph, &scans, &params, &[NodeId(9)], None).is_none());
    }

    #[test]
    fn stored_maps_of_other_graphs_and_beyond_reach_are_left_out() {
        let (graph, scans, grids) = pruned_place();
        let params = KeyframeParams::default();
        let elsewhere = BTreeMap::from([(NodeId(7), grids[&NodeId(1)].clone())]);
        let other = local_map_keyframes(&graph, &scans, &params, &[NodeId(2)], Some(&elsewhere));
        assert!(other[&NodeId(2)].points_in_keyframe.is_empty());
        let near = KeyframeParams {
            local_map_m: 0.5,
            ..KeyframeParams::default()
        };
        let far = local_map_keyframes(&graph, &scans, &near, &[NodeId(2)], Some(&grids));
        assert!(
            far[&NodeId(2)].points_in_keyframe.is_empty(),
            "the wall is 2 m away"
        );
    }
}
