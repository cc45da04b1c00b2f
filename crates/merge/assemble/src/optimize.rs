//! One pose graph per group (AutoMerge Sec. VI-B, "rough centralized global map
//! optimization"): the submap centres of every segment of the group as vertices, each
//! segment's odometry between consecutive centres, the verified inter-segment loop edges,
//! started from a spanning tree of the pair placements and optimised with a robust kernel
//! (DCS) so a loop edge that slipped through does not bend the map. Every scan's pose follows
//! its nearest submap centre rigidly.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_params::{Checker, Real, Validate};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph2, Vertex};
use mapmerge_solve::{optimize, OptimizerParams, RobustKernel, Termination};
use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

use crate::assembly::Assembler;
use crate::error::AssembleError;

/// Odometry edge noise between consecutive submap centres of one segment.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GroupGraphParams {
    /// Standard deviation of translation per metre travelled, and its floor (m) (default:
    /// 0.02 per m, 0.02 m).
    pub odometry_sigma_per_m: f64,
    pub odometry_sigma_floor_m: f64,
    /// Standard deviation of rotation per metre travelled (deg) and its floor (default: 0.5,
    /// 0.5).
    pub odometry_sigma_deg_per_m: f64,
    pub odometry_sigma_floor_deg: f64,
    /// DCS's Φ for every edge (default: 1).
    pub dcs_phi: f64,
    /// Use DCS at all (default: true). The consistency check of the assembly solves without
    /// it, so a contradiction shows on every pair of the cycle instead of on the one pair DCS
    /// gave up on.
    pub robust: bool,
}

impl Default for GroupGraphParams {
    fn default() -> Self {
        Self {
            odometry_sigma_per_m: 0.02,
            odometry_sigma_floor_m: 0.02,
            odometry_sigma_deg_per_m: 0.5,
            odometry_sigma_floor_deg: 0.5,
            dcs_phi: 1.0,
            robust: true,
        }
    }
}

impl Validate for GroupGraphParams {
    fn check(&self, check: &mut Checker) {
        // Floors ≥ 1e-6 keep the odometry information finite; Φ as `RobustKernel::Dcs`.
        check
            .real(
                "odometry_sigma_per_m",
                self.odometry_sigma_per_m,
                Real::within(0.0, 10.0),
            )
            .real(
                "odometry_sigma_floor_m",
                self.odometry_sigma_floor_m,
                Real::within(1e-6, 1000.0),
            )
            .real(
                "odometry_sigma_deg_per_m",
                self.odometry_sigma_deg_per_m,
                Real::within(0.0, 180.0),
            )
            .real(
                "odometry_sigma_floor_deg",
                self.odometry_sigma_floor_deg,
                Real::within(1e-6, 180.0),
            )
            .real("dcs_phi", self.dcs_phi, Real::positive_up_to(1e9));
    }
}

/// A group assembled into one frame: the frame of its first segment (by name).
#[derive(Clone, Debug, PartialEq)]
pub struct GroupSolution {
    /// The group's segments, sorted.
    pub segments: Vec<String>,
    /// `group_from_robot` of every scan of every segment.
    pub scan_poses: BTreeMap<String, Vec<Se2>>,
    /// `group_from_segment` of every segment's frame after the spanning tree (before the
    /// optimisation).
    pub initial_placements: BTreeMap<String, Se2>,
    /// Vertices, odometry edges and loop edges of the graph.
    pub vertices: usize,
    pub odometry_edges: usize,
    pub loop_edges: usize,
    /// The optimiser's iterations, and whether it failed numerically (the last good state is
    /// kept then).
    pub iterations: usize,
    pub numerical_failure: bool,
    /// Per pair `(a, b)` of the group: the median residual of its loop edges after the
    /// optimisation, translation (m) and rotation (rad). A pair the rest of the group
    /// contradicts keeps a large residual (DCS let it go).
    pub pair_residuals: BTreeMap<(String, String), (f64, f64)>,
    /// Per segment: its largest odometry residual in standard deviations (translation or
    /// rotation, whichever is larger). Loop edges that contradict each other can be met by
    /// folding a segment between its overlaps; this shows it.
    pub odometry_excess: BTreeMap<String, f64>,
}

/// Vertex id of submap `k` of the `s`-th segment of a group.
fn node(s: usize, k: usize) -> NodeId {
    NodeId(((s as u64) << 32) | k as u64)
}

/// Builds and optimises the pose graph of `group` from the assembly's accepted pairs.
pub fn solve_group(
    assembler: &Assembler,
    group: &[String],
    params: &GroupGraphParams,
) -> Result<GroupSolution, AssembleError> {
    solve_group_without(assembler, group, params, assembler.rejected_pairs())
}

/// As [`solve_group`], leaving out the pairs in `excluded`.
pub fn solve_group_without(
    assembler: &Assembler,
    group: &[String],
    params: &GroupGraphParams,
    excluded: &BTreeSet<(String, String)>,
) -> Result<GroupSolution, AssembleError> {
    let mut names: Vec<String> = group.to_vec();
    names.sort();
    names.dedup();
    let index: BTreeMap<&str, usize> = names
        .iter()
        .enumerate()
        .map(|(i, n)| (n.as_str(), i))
        .collect();
    let mut parts = Vec::with_capacity(names.len());
    for name in &names {
        let part = assembler
            .segment(name)
            .ok_or_else(|| AssembleError::InvalidSegment {
                segment: name.clone(),
                reason: "not in the assembly".into(),
            })?;
        parts.push(part);
    }
    // The group's pairs and their placements `a_from_b`.
    let member: BTreeSet<&str> = names.iter().map(String::as_str).collect();
    let pairs: Vec<_> = assembler
        .pairs()
        .values()
        .filter(|p| {
            p.weight > 0.0
                && member.contains(p.a.as_str())
                && member.contains(p.b.as_str())
                && !excluded.contains(&(p.a.clone(), p.b.clone()))
        })
        .collect();
    // Spanning tree from the first segment, strongest pairs first (breadth first).
    let mut placement: BTreeMap<usize, Se2> = BTreeMap::new();
    placement.insert(0, Se2::identity());
    let mut queue = VecDeque::from([0usize]);
    while let Some(s) = queue.pop_front() {
        let mut next: Vec<(f64, usize, Se2)> = Vec::new();
        for p in &pairs {
            let (Some(&ia), Some(&ib), Some(a_from_b)) =
                (index.get(p.a.as_str()), index.get(p.b.as_str()), p.a_from_b)
            else {
                continue;
            };
            let group_from_s = placement[&s];
            if ia == s && !placement.contains_key(&ib) {
                next.push((p.weight, ib, group_from_s.compose(&a_from_b)));
            } else if ib == s && !placement.contains_key(&ia) {
                next.push((p.weight, ia, group_from_s.compose(&a_from_b.inverse())));
            }
        }
        next.sort_by(|x, y| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1)));
        for (_, other, pose) in next {
            if let std::collections::btree_map::Entry::Vacant(e) = placement.entry(other) {
                e.insert(pose);
                queue.push_back(other);
            }
        }
    }
    // Segments the tree did not reach (a group held together by weights alone cannot happen,
    // but stay safe) keep their own frame at the origin.
    let mut graph = PoseGraph2::new();
    let mut odometry_edges = 0;
    let mut odometry = Vec::new();
    for (s, (_, prepared)) in parts.iter().enumerate() {
        let group_from_segment = placement.get(&s).copied().unwrap_or_else(Se2::identity);
        for submap in &prepared.submaps {
            graph
                .add_vertex(
                    node(s, submap.index),
                    Vertex::new(group_from_segment.compose(&submap.segment_from_centre)),
                )
                .map_err(graph_error)?;
        }
        for w in prepared.submaps.windows(2) {
            let (p, q) = (&w[0], &w[1]);
            let travel_m = (q.travel_m - p.travel_m).abs();
            let sigma_m = params.odometry_sigma_floor_m + params.odometry_sigma_per_m * travel_m;
            let sigma_rad = (params.odometry_sigma_floor_deg
                + params.odometry_sigma_deg_per_m * travel_m)
                .to_radians();
            odometry.push((
                s,
                node(s, p.index),
                node(s, q.index),
                p.segment_from_centre.between(&q.segment_from_centre),
                sigma_m,
                sigma_rad,
            ));
            graph
                .add_edge(Edge {
                    from: node(s, p.index),
                    to: node(s, q.index),
                    measurement: p.segment_from_centre.between(&q.segment_from_centre),
                    information: Matrix3::from_diagonal(&nalgebra::Vector3::new(
                        1.0 / (sigma_m * sigma_m),
                        1.0 / (sigma_m * sigma_m),
                        1.0 / (sigma_rad * sigma_rad),
                    )),
                    kind: EdgeKind::Odometry,
                })
                .map_err(graph_error)?;
            odometry_edges += 1;
        }
    }
    let mut loop_edges = 0;
    for p in &pairs {
        let (Some(&ia), Some(&ib)) = (index.get(p.a.as_str()), index.get(p.b.as_str())) else {
            continue;
        };
        for l in &p.loops {
            graph
                .add_edge(Edge {
                    from: node(ia, l.from_submap),
                    to: node(ib, l.to_submap),
                    measurement: l.from_from_to,
                    information: l.information,
                    kind: EdgeKind::Loop,
                })
                .map_err(graph_error)?;
            loop_edges += 1;
        }
    }
    if let Some(v) = graph.vertex_mut(node(0, 0)) {
        v.fixed = true;
    }
    let optimizer = OptimizerParams {
        robust: if params.robust {
            RobustKernel::Dcs {
                phi: params.dcs_phi,
            }
        } else {
            RobustKernel::None
        },
        ..OptimizerParams::default()
    };
    let info = optimize(&mut graph, &optimizer).map_err(|e| AssembleError::Association {
        pair: format!("group of {}", names.join(", ")),
        reason: e.to_string(),
    })?;
    // Each pair's median loop residual.
    let mut pair_residuals = BTreeMap::new();
    for p in &pairs {
        let (Some(&ia), Some(&ib)) = (index.get(p.a.as_str()), index.get(p.b.as_str())) else {
            continue;
        };
        let (mut metres, mut radians): (Vec<f64>, Vec<f64>) = p
            .loops
            .iter()
            .filter_map(|l| {
                let from = graph.vertex(node(ia, l.from_submap))?.pose;
                let to = graph.vertex(node(ib, l.to_submap))?.pose;
                let r = l.from_from_to.between(&from.between(&to));
                Some((r.translation().norm(), r.theta_rad.abs()))
            })
            .unzip();
        if metres.is_empty() {
            continue;
        }
        metres.sort_by(f64::total_cmp);
        radians.sort_by(f64::total_cmp);
        pair_residuals.insert(
            (p.a.clone(), p.b.clone()),
            (metres[metres.len() / 2], radians[radians.len() / 2]),
        );
    }
    let mut odometry_excess: BTreeMap<String, f64> = BTreeMap::new();
    for (s, from, to, measurement, sigma_m, sigma_rad) in odometry {
        let (Some(f), Some(t)) = (graph.vertex(from), graph.vertex(to)) else {
            continue;
        };
        let r = measurement.between(&f.pose.between(&t.pose));
        let excess = (r.translation().norm() / sigma_m).max(r.theta_rad.abs() / sigma_rad);
        let entry = odometry_excess.entry(names[s].clone()).or_insert(0.0);
        *entry = entry.max(excess);
    }
    // Every scan follows its nearest submap centre (by scan index) rigidly.
    let mut scan_poses = BTreeMap::new();
    for (s, (segment, prepared)) in parts.iter().enumerate() {
        let centres: Vec<usize> = prepared.submaps.iter().map(|m| m.centre_scan).collect();
        let mut poses = Vec::with_capacity(segment.poses.len());
        for (scan, segment_from_robot) in segment.poses.iter().enumerate() {
            let nearest = match centres.binary_search(&scan) {
                Ok(k) => k,
                Err(k) => {
                    if k == 0 {
                        0
                    } else if k >= centres.len() {
                        centres.len().saturating_sub(1)
                    } else if scan - centres[k - 1] <= centres[k] - scan {
                        k - 1
                    } else {
                        k
                    }
                }
            };
            let pose = match (
                prepared.submaps.get(nearest),
                prepared
                    .submaps
                    .get(nearest)
                    .and_then(|m| graph.vertex(node(s, m.index))),
            ) {
                (Some(m), Some(v)) => v
                    .pose
                    .compose(&m.segment_from_centre.between(segment_from_robot)),
                _ => placement
                    .get(&s)
                    .copied()
                    .unwrap_or_else(Se2::identity)
                    .compose(segment_from_robot),
            };
            poses.push(pose);
        }
        scan_poses.insert(names[s].clone(), poses);
    }
    Ok(GroupSolution {
        initial_placements: placement
            .iter()
            .map(|(s, p)| (names[*s].clone(), *p))
            .collect(),
        segments: names,
        scan_poses,
        vertices: graph.num_vertices(),
        odometry_edges,
        loop_edges,
        iterations: info.iterations.len(),
        numerical_failure: matches!(info.termination, Termination::NumericalFailure(_)),
        pair_residuals,
        odometry_excess,
    })
}

fn graph_error(e: mapmerge_posegraph::GraphError) -> AssembleError {
    AssembleError::Association {
        pair: "group graph".into(),
        reason: e.to_string(),
    }
}
