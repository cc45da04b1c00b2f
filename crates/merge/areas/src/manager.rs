//! The map manager's run over one log (Ehlers et al., Sec. II): door passings split the log
//! into areas, each area is mapped on its own with the configuration its environment calls
//! for, and each passing becomes a link point known in the two maps it joins.
//!
//! The maps overlap at each door: an area's scans run `overlap_m` of travel past the door it
//! leaves by, and start `overlap_m` before the door it enters by, so the crossing's pose is in
//! both maps (Sec. II-A: link points lie "in an area where both maps slightly overlap").

use std::collections::BTreeMap;
use std::f64::consts::FRAC_PI_2;
use std::ops::Range;

use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_place::{GeometricVerifier, Keyframe, Verification};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph2, Vertex};
use mapmerge_scan::{voxel_downsample, BeamFilter, LaserScan};
use mapmerge_solve::{optimize, OptimizerParams};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use crate::door::{DoorDetector, DoorParams, DoorPassingDetection};
use crate::environment::{Environment, Extents};
use crate::error::AreasError;
use crate::hybrid::{Area, HybridMap, LinkPoint};

/// Parameters of the map manager.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ManagerParams {
    /// Door detection.
    pub doors: DoorParams,
    /// How far adjacent maps overlap on each side of a door (m) (default: 1).
    pub overlap_m: f64,
    /// An area with fewer scans joins the one before it: its door passing is not a map
    /// boundary (default: 20).
    pub min_area_scans: usize,
    /// The first area's environment is judged after this many scans (default: 20).
    pub first_environment_scans: usize,
    /// Global tracking and topological loop closure (Sec. II-C, II-D).
    pub tracking: TrackingParams,
}

/// Global tracking across maps (Sec. II-D) and topological loop closure (Sec. II-C).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackingParams {
    /// r_orig of Eq. 3 (m) (default: 1).
    pub base_radius_m: f64,
    /// Growth of the position variance with travel since the last link point: a random walk
    /// of this many m²/m (default: 0.0025, 5 cm after 1 m)…
    pub variance_per_m: f64,
    /// … and of the heading, whose effect on position grows with the cube of the travel
    /// (rad²/m) (default: 1e-4, 1° after 3 m).
    pub heading_variance_per_m: f64,
    /// Local maps compared at link points: scans within this travel of the crossing (m)
    /// (default: 2).
    pub local_map_m: f64,
    /// A re-observed link point is accepted at this verification score (default: 0.95)…
    pub min_score: f64,
    /// … when the verified crossing lies within this of the earlier crossing (two passings of
    /// one door cross it within its width) (m) (default: 1; 1.5 let one neighbouring door
    /// through on the simulator's tuning tours), and within the search radius of where
    /// tracking put it.
    pub same_door_m: f64,
    /// Stop after this many link points were checked at one passing (default: 5).
    pub max_candidates: usize,
}

impl Default for TrackingParams {
    fn default() -> Self {
        Self {
            base_radius_m: 1.0,
            variance_per_m: 0.0025,
            heading_variance_per_m: 1e-4,
            local_map_m: 2.0,
            min_score: 0.95,
            same_door_m: 1.0,
            max_candidates: 5,
        }
    }
}

impl TrackingParams {
    /// Eq. 3: r = r_orig + 2·√(5.991·λ_max), λ_max the largest eigenvalue of the position
    /// covariance after `travel_m` since the last link point (5.991: χ² 95 % with 2 degrees
    /// of freedom), here σ² = q·d + q_θ·d³/3.
    pub fn search_radius_m(&self, travel_m: f64) -> f64 {
        let d = travel_m.max(0.0);
        let lambda = self.variance_per_m * d + self.heading_variance_per_m * d.powi(3) / 3.0;
        self.base_radius_m + 2.0 * (5.991 * lambda).sqrt()
    }
}

impl Default for ManagerParams {
    fn default() -> Self {
        Self {
            doors: DoorParams::default(),
            overlap_m: 1.0,
            min_area_scans: 20,
            first_environment_scans: 20,
            tracking: TrackingParams::default(),
        }
    }
}

/// The scans of one area.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AreaSpan {
    /// Scan indices (into the log), overlap included.
    pub scans: Range<usize>,
    /// Its environment.
    pub environment: Environment,
}

/// A log split at its door passings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Segmentation {
    /// Every passing detected (boundaries or not).
    pub passings: Vec<DoorPassingDetection>,
    /// The areas, in time order.
    pub spans: Vec<AreaSpan>,
    /// For each boundary between span `k` and `k + 1`: the passing (index into `passings`).
    pub boundaries: Vec<usize>,
}

/// Splits a log (`odom_from_robot` and scan of each scan) at its door passings.
pub fn segment<'a>(
    scans: impl IntoIterator<Item = (Se2, &'a LaserScan)>,
    params: &ManagerParams,
) -> Result<Segmentation, AreasError> {
    let mut detector = DoorDetector::new(params.doors.clone())?;
    let mut first_environment = Extents::new(params.doors.environment.clone(), f64::INFINITY);
    let mut environment_of_first = None;
    let mut passings = Vec::new();
    let mut travel = Vec::new();
    let mut previous: Option<Se2> = None;
    for (index, (odom_from_robot, scan)) in scans.into_iter().enumerate() {
        let step = previous.map_or(0.0, |p| {
            (odom_from_robot.translation() - p.translation()).norm()
        });
        travel.push(travel.last().copied().unwrap_or(0.0) + step);
        previous = Some(odom_from_robot);
        if environment_of_first.is_none() {
            first_environment.push(&odom_from_robot, scan, travel[index]);
            if index + 1 >= params.first_environment_scans {
                environment_of_first = Some(first_environment.environment(&odom_from_robot));
            }
        }
        if let Some(found) = detector.push(&odom_from_robot, scan) {
            passings.push(found);
        }
    }
    let n = travel.len();
    let environment_of_first = environment_of_first
        .or_else(|| previous.map(|p| first_environment.environment(&p)))
        .unwrap_or(Environment::Indoor);
    // Boundaries at crossings, each area at least `min_area_scans` long.
    let mut cuts: Vec<(usize, usize)> = Vec::new(); // (crossing scan, passing)
    let mut last_cut = 0usize;
    for (i, passing) in passings.iter().enumerate() {
        let c = passing.crossing_scan;
        if c >= last_cut + params.min_area_scans && c + params.min_area_scans <= n {
            cuts.push((c, i));
            last_cut = c;
        }
    }
    // Scan indices `overlap_m` of travel before and after a crossing.
    let before = |c: usize| {
        let limit = travel[c] - params.overlap_m;
        (0..=c).rev().find(|&k| travel[k] <= limit).unwrap_or(0)
    };
    let after = |c: usize| {
        let limit = travel[c] + params.overlap_m;
        (c..n).find(|&k| travel[k] >= limit).map_or(n, |k| k + 1)
    };
    let mut spans = Vec::with_capacity(cuts.len() + 1);
    let mut start = 0;
    let mut environment = environment_of_first;
    for &(c, i) in &cuts {
        spans.push(AreaSpan {
            scans: start..after(c),
            environment,
        });
        start = before(c);
        environment = passings[i].environment;
    }
    if n > 0 {
        spans.push(AreaSpan {
            scans: start..n,
            environment,
        });
    }
    Ok(Segmentation {
        passings,
        boundaries: cuts.iter().map(|(_, i)| *i).collect(),
        spans,
    })
}

/// A topological loop closure: a passing recognised as the re-observation of an earlier
/// link point (the same door).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Closure {
    /// The boundary whose passing it was.
    pub boundary: usize,
    /// The earlier boundary it re-observed.
    pub earlier: usize,
    /// The verification's score.
    pub score: f64,
}

/// Global tracking at one boundary (Sec. II-D).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrackingStep {
    /// The boundary.
    pub boundary: usize,
    /// Travel since the last link point whose global pose was re-observed (m).
    pub travel_since_closure_m: f64,
    /// Eq. 3's search radius (m).
    pub radius_m: f64,
    /// Earlier boundaries (not themselves re-observations) whose crossing lay within it;
    /// the nearest `max_candidates` were checked.
    pub within_radius: Vec<usize>,
}

/// The map manager's result for one log.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ManagedMap {
    /// The hybrid map: one area per group of spans found to be the same place, one link
    /// point per door.
    pub hybrid: HybridMap,
    /// The area of each span.
    pub span_area: Vec<usize>,
    /// Where each span's frame lies in its area's frame.
    pub area_from_span: Vec<Se2>,
    /// Where each span's frame lies in the first span's frame, after optimisation.
    pub first_from_span: Vec<Se2>,
    /// Each boundary's crossing in the first span's frame, after optimisation.
    pub crossings: Vec<Se2>,
    /// The link point (of `hybrid`) of each boundary: its own, the earlier one it
    /// re-observed, or none when both its sides are one area.
    pub boundary_link: Vec<Option<usize>>,
    /// Topological loop closures.
    pub closures: Vec<Closure>,
    /// Global tracking at each boundary.
    pub tracking: Vec<TrackingStep>,
}

/// Builds the hybrid map of a segmented log from each span's trajectory (`map_from_robot`
/// of each of its scans, in its own map's frame) and the log's scans:
///
/// 1. the link-point graph: a node at the start and at each boundary's crossing, an edge
///    between consecutive nodes measured in the span between them (its variance growing with
///    the travel between them);
/// 2. global tracking (Sec. II-D): each new crossing's pose through the chain, and Eq. 3's
///    radius from the travel since the last re-observed link point;
/// 3. topological loop closure (Sec. II-C): the earlier crossings within the radius are
///    verified by scan matching their local maps (`verifier`, our place recognition's, in
///    place of the paper's images); the best accepted one becomes a loop edge, the graph is
///    optimised (the re-observed link point is the landmark), and the spans on each side of
///    the door are joined into one area;
/// 4. areas, link points (one per door) and edges.
pub fn manage(
    segmentation: &Segmentation,
    trajectories: &[Vec<Se2>],
    scans: &[&LaserScan],
    params: &ManagerParams,
    verifier: &dyn GeometricVerifier,
) -> Result<ManagedMap, AreasError> {
    let spans = &segmentation.spans;
    if trajectories.len() != spans.len() {
        return Err(AreasError::Mapping(format!(
            "{} trajectories for {} areas",
            trajectories.len(),
            spans.len()
        )));
    }
    for (k, (span, trajectory)) in spans.iter().zip(trajectories).enumerate() {
        if trajectory.len() != span.scans.len() || span.scans.end > scans.len() {
            return Err(AreasError::Mapping(format!(
                "area {k}: {} poses for scans {:?} of {}",
                trajectory.len(),
                span.scans,
                scans.len()
            )));
        }
    }
    let crossing = |b: usize| -> Result<usize, AreasError> {
        segmentation
            .boundaries
            .get(b)
            .and_then(|p| segmentation.passings.get(*p))
            .map(|p| p.crossing_scan)
            .ok_or_else(|| AreasError::Mapping(format!("no passing for boundary {b}")))
    };
    let pose_at = |span: usize, scan: usize| -> Result<Se2, AreasError> {
        scan.checked_sub(spans[span].scans.start)
            .and_then(|k| trajectories[span].get(k).copied())
            .ok_or_else(|| AreasError::Mapping(format!("area {span} has no pose for scan {scan}")))
    };
    let travel_between = |span: usize, a: usize, b: usize| -> f64 {
        let start = spans[span].scans.start;
        let t = &trajectories[span];
        (a.max(start)..b)
            .filter_map(|k| {
                Some((t.get(k + 1 - start)?.translation() - t.get(k - start)?.translation()).norm())
            })
            .sum()
    };
    let boundaries = segmentation.boundaries.len();
    // 1. Nodes: 0 the start, b + 1 the crossing of boundary b. Node k's pose in span k
    // (entry) and node k + 1's (exit).
    let mut entry = vec![Se2::identity(); spans.len()];
    let mut exit = Vec::with_capacity(boundaries);
    let mut entry_scan = vec![spans.first().map_or(0, |s| s.scans.start); spans.len()];
    for b in 0..boundaries {
        let c = crossing(b)?;
        exit.push(pose_at(b, c)?);
        entry[b + 1] = pose_at(b + 1, c)?;
        entry_scan[b + 1] = c;
    }
    let tracking = &params.tracking;
    let mut graph = PoseGraph2::new();
    let node = |k: usize| NodeId(k as u64);
    graph
        .add_vertex(
            node(0),
            Vertex {
                pose: Se2::identity(),
                fixed: true,
                meta: Default::default(),
            },
        )
        .map_err(|e| AreasError::Mapping(e.to_string()))?;
    let mut legs_m = Vec::with_capacity(boundaries);
    for b in 0..boundaries {
        let measurement = entry[b].inverse().compose(&exit[b]);
        let c = crossing(b)?;
        let leg_m = travel_between(b, entry_scan[b], c);
        legs_m.push(leg_m);
        let previous = graph
            .vertex(node(b))
            .map(|v| v.pose)
            .unwrap_or_else(Se2::identity);
        graph
            .add_vertex(node(b + 1), Vertex::new(previous.compose(&measurement)))
            .map_err(|e| AreasError::Mapping(e.to_string()))?;
        graph
            .add_edge(Edge {
                from: node(b),
                to: node(b + 1),
                measurement,
                information: leg_information(tracking, leg_m),
                kind: EdgeKind::Odometry,
            })
            .map_err(|e| AreasError::Mapping(e.to_string()))?;
    }
    // 2–3. Tracking and closures, boundary by boundary.
    let mut groups = UnionFind::new(spans.len());
    let mut closures = Vec::new();
    let mut steps = Vec::with_capacity(boundaries);
    let mut since_closure_m = 0.0;
    let mut merged_into: Vec<Option<usize>> = vec![None; boundaries];
    for b in 0..boundaries {
        since_closure_m += legs_m[b];
        let radius_m = tracking.search_radius_m(since_closure_m);
        let here = graph
            .vertex(node(b + 1))
            .map(|v| v.pose)
            .unwrap_or_else(Se2::identity);
        let mut candidates: Vec<(f64, usize)> = (0..b)
            .filter(|j| merged_into[*j].is_none())
            .filter_map(|j| {
                let there = graph.vertex(node(j + 1))?.pose;
                let d = (there.translation() - here.translation()).norm();
                (d <= radius_m).then_some((d, j))
            })
            .collect();
        candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
        steps.push(TrackingStep {
            boundary: b,
            travel_since_closure_m: since_closure_m,
            radius_m,
            within_radius: candidates.iter().map(|(_, j)| *j).collect(),
        });
        candidates.truncate(tracking.max_candidates);
        if candidates.is_empty() {
            continue;
        }
        let query = local_map(
            b,
            crossing(b)?,
            &exit[b],
            spans,
            trajectories,
            scans,
            tracking,
        );
        let mut best: Option<(usize, Verification)> = None;
        for (_, j) in &candidates {
            let there = graph
                .vertex(node(j + 1))
                .map(|v| v.pose)
                .unwrap_or_else(Se2::identity);
            let candidate = local_map(
                *j,
                crossing(*j)?,
                &exit[*j],
                spans,
                trajectories,
                scans,
                tracking,
            );
            let guess = there.inverse().compose(&here);
            if let Some(found) = verifier.verify(&query, &candidate, &guess) {
                let correction_m = guess
                    .between(&found.candidate_from_query)
                    .translation()
                    .norm();
                if found.score >= tracking.min_score
                    && found.candidate_from_query.translation().norm() <= tracking.same_door_m
                    && correction_m <= radius_m
                    && best.as_ref().is_none_or(|(_, v)| found.score > v.score)
                {
                    best = Some((*j, found));
                }
            }
        }
        let Some((j, found)) = best else {
            continue;
        };
        graph
            .add_edge(Edge {
                from: node(j + 1),
                to: node(b + 1),
                measurement: found.candidate_from_query,
                information: closure_information(&found),
                kind: EdgeKind::Loop,
            })
            .map_err(|e| AreasError::Mapping(e.to_string()))?;
        // A numerical failure keeps the last good state, which is the chain: still a map.
        let _ = optimize(&mut graph, &OptimizerParams::default());
        let there = graph
            .vertex(node(j + 1))
            .map(|v| v.pose)
            .unwrap_or_else(Se2::identity);
        let here = graph
            .vertex(node(b + 1))
            .map(|v| v.pose)
            .unwrap_or_else(Se2::identity);
        // Same direction through the door: the same sides; else swapped.
        if wrap_angle_rad(here.theta_rad - there.theta_rad).abs() < FRAC_PI_2 {
            groups.union(b, j);
            groups.union(b + 1, j + 1);
        } else {
            groups.union(b, j + 1);
            groups.union(b + 1, j);
        }
        merged_into[b] = Some(j);
        closures.push(Closure {
            boundary: b,
            earlier: j,
            score: found.score,
        });
        since_closure_m = 0.0;
    }
    // 4. Frames, areas, link points.
    let pose_of = |k: usize| {
        graph
            .vertex(node(k))
            .map(|v| v.pose)
            .unwrap_or_else(Se2::identity)
    };
    let first_from_span: Vec<Se2> = (0..spans.len())
        .map(|k| pose_of(k).compose(&entry[k].inverse()))
        .collect();
    let crossings: Vec<Se2> = (0..boundaries).map(|b| pose_of(b + 1)).collect();
    let mut area_of_root = BTreeMap::new();
    let mut span_area = Vec::with_capacity(spans.len());
    let mut first_span_of_area = Vec::new();
    for k in 0..spans.len() {
        let root = groups.find(k);
        let area = *area_of_root.entry(root).or_insert_with(|| {
            first_span_of_area.push(k);
            first_span_of_area.len() - 1
        });
        span_area.push(area);
    }
    let areas: Vec<Area> = first_span_of_area
        .iter()
        .enumerate()
        .map(|(id, k)| Area {
            id,
            environment: spans[*k].environment,
            first_from_area: first_from_span[*k],
        })
        .collect();
    let area_from_span: Vec<Se2> = (0..spans.len())
        .map(|k| {
            areas[span_area[k]]
                .first_from_area
                .inverse()
                .compose(&first_from_span[k])
        })
        .collect();
    let mut link_points: Vec<LinkPoint> = Vec::new();
    let mut boundary_link = vec![None; boundaries];
    for b in 0..boundaries {
        if let Some(j) = merged_into[b] {
            boundary_link[b] = boundary_link[j];
            continue;
        }
        let (a0, a1) = (span_area[b], span_area[b + 1]);
        if a0 == a1 {
            continue;
        }
        boundary_link[b] = Some(link_points.len());
        link_points.push(LinkPoint {
            id: link_points.len(),
            areas: [a0, a1],
            poses: [
                area_from_span[b].compose(&exit[b]),
                area_from_span[b + 1].compose(&entry[b + 1]),
            ],
        });
    }
    let mut hybrid = HybridMap {
        areas,
        link_points,
        edges: Vec::new(),
    };
    hybrid.connect();
    Ok(ManagedMap {
        hybrid,
        span_area,
        area_from_span,
        first_from_span,
        crossings,
        boundary_link,
        closures,
        tracking: steps,
    })
}

/// Information of the link-point edge over a leg of `leg_m` travel.
fn leg_information(tracking: &TrackingParams, leg_m: f64) -> Matrix3<f64> {
    let d = leg_m.max(0.1);
    let position = tracking.variance_per_m * d + tracking.heading_variance_per_m * d.powi(3) / 3.0;
    let heading = tracking.heading_variance_per_m * d;
    Matrix3::from_diagonal(&Vector3::new(1.0 / position, 1.0 / position, 1.0 / heading))
}

/// Information of a closure: its verification's covariance with 5 cm and 1° floors.
fn closure_information(found: &Verification) -> Matrix3<f64> {
    let floor = Matrix3::from_diagonal(&Vector3::new(
        0.05f64.powi(2),
        0.05f64.powi(2),
        1f64.to_radians().powi(2),
    ));
    (found.covariance + floor)
        .try_inverse()
        .unwrap_or_else(|| floor.try_inverse().unwrap_or_else(Matrix3::identity))
}

/// The local map at a crossing: the scans of `span` within `local_map_m` of travel of scan
/// `c`, in the robot frame at `c` (`map_from_crossing` in the span's frame), with their rays.
fn local_map(
    span: usize,
    c: usize,
    map_from_crossing: &Se2,
    spans: &[AreaSpan],
    trajectories: &[Vec<Se2>],
    scans: &[&LaserScan],
    tracking: &TrackingParams,
) -> Keyframe {
    let range = &spans[span].scans;
    let trajectory = &trajectories[span];
    let crossing_from_map = map_from_crossing.inverse();
    let mut points = Vec::new();
    let mut rays = Vec::new();
    let filter = BeamFilter::default();
    let within = |k: usize| {
        let (Some(a), Some(b)) = (
            trajectory.get(k - range.start),
            trajectory.get(c - range.start),
        ) else {
            return false;
        };
        (a.translation() - b.translation()).norm() <= tracking.local_map_m
    };
    for k in range.clone().filter(|k| within(*k)) {
        let (Some(pose), Some(scan)) = (trajectory.get(k - range.start), scans.get(k)) else {
            continue;
        };
        let crossing_from_robot = crossing_from_map.compose(pose);
        let origin = crossing_from_robot.translation();
        for p in scan.points_in_robot(&filter) {
            let q = crossing_from_robot.transform_point(&p);
            points.push(q);
            rays.push((origin, q));
        }
    }
    let points = voxel_downsample(&points, 0.05);
    Keyframe::new(c as u64, points).with_rays(0.1, rays)
}

/// Union–find over spans.
struct UnionFind {
    parent: Vec<usize>,
}

impl UnionFind {
    fn new(n: usize) -> Self {
        Self {
            parent: (0..n).collect(),
        }
    }

    fn find(&mut self, k: usize) -> usize {
        let mut root = k;
        while let Some(&p) = self.parent.get(root) {
            if p == root {
                break;
            }
            root = p;
        }
        // Path compression.
        let mut k = k;
        while let Some(&p) = self.parent.get(k) {
            if p == root {
                break;
            }
            self.parent[k] = root;
            k = p;
        }
        root
    }

    fn union(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            // The earlier span's root stays, so an area's first span is its root.
            let (keep, other) = if ra < rb { (ra, rb) } else { (rb, ra) };
            self.parent[other] = keep;
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use mapmerge_place::PlaceVerifierParams;
    use mapmerge_sim::{simulate, SimParams};

    use super::*;

    #[test]
    fn a_simulated_session_splits_at_its_doors_and_chains_back_together() {
        let sim = SimParams::default()
            .with_preset_name("office")
            .unwrap()
            .with_sessions(1)
            .with_duration_secs(120.0);
        let data = simulate(&sim, 1).unwrap();
        let session = &data.sessions[0];
        let scans = session
            .log
            .scans
            .iter()
            .map(|r| (r.odom_from_robot.unwrap(), &r.scan));
        let params = ManagerParams::default();
        let split = segment(scans, &params).unwrap();
        assert!(split.spans.len() >= 3, "{} areas", split.spans.len());
        assert_eq!(split.spans.len(), split.boundaries.len() + 1);
        for pair in split.spans.windows(2) {
            assert!(
                pair[1].scans.start < pair[0].scans.end,
                "adjacent maps overlap"
            );
        }
        assert_eq!(split.spans.first().unwrap().scans.start, 0);
        assert_eq!(
            split.spans.last().unwrap().scans.end,
            session.log.scans.len()
        );
        // Each area mapped by the true poses in a frame of its own (its first pose): the chain
        // through the link points must put every area back where the truth has it.
        let trajectories: Vec<Vec<Se2>> = split
            .spans
            .iter()
            .map(|span| {
                let origin = session.truth[span.scans.start].1;
                span.scans
                    .clone()
                    .map(|k| origin.inverse().compose(&session.truth[k].1))
                    .collect()
            })
            .collect();
        let scans: Vec<&LaserScan> = session.log.scans.iter().map(|r| &r.scan).collect();
        let verifier = PlaceVerifierParams::default().verifier().unwrap();
        let managed = manage(&split, &trajectories, &scans, &params, &verifier).unwrap();
        let world_from_first = session.truth[0].1;
        for (k, span) in split.spans.iter().enumerate() {
            let world_from_span = session.truth[span.scans.start].1;
            let error = world_from_first
                .compose(&managed.first_from_span[k])
                .between(&world_from_span);
            assert!(error.translation().norm() < 0.05, "span {k}: {error:?}");
        }
        // Every closure joins two passings of one true door.
        let door_at = |b: usize| {
            let c = split.passings[split.boundaries[b]].crossing_scan;
            let p = session.truth[c].1.translation();
            session
                .world
                .doors
                .iter()
                .min_by(|x, y| (x.center_m - p).norm().total_cmp(&(y.center_m - p).norm()))
                .map(|d| d.id)
        };
        for closure in &managed.closures {
            assert_eq!(
                door_at(closure.boundary),
                door_at(closure.earlier),
                "{closure:?}"
            );
        }
        assert!(managed.hybrid.areas.len() <= split.spans.len());
        assert_eq!(managed.span_area.len(), split.spans.len());
        assert!(manage(&split, &trajectories[1..], &scans, &params, &verifier).is_err());
    }
}
