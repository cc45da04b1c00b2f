//! Scan-to-map odometry and keyframes: the first half of the front-end (loop closing comes
//! next). Per scan, in order:
//! 1. predict the pose from the wheel odometry increment;
//! 2. match the scan against the local map (the points of the last keyframes) in a window
//!    around the prediction (correlative search + ICP, `mapmerge-scanmatch`);
//! 3. anchor the scan to the current keyframe, or make it a keyframe: a new node, an odometry
//!    edge from the previous keyframe weighted by the match covariance, and a new local map.

use std::collections::{BTreeMap, VecDeque};

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph2, Vertex};
use mapmerge_scan::{BeamFilter, LaserScan, Point2};
use mapmerge_scanmatch::{
    ScanMatchError, ScanMatchParams, ScanMatchTarget, ScanMatcher, SearchWindow,
};
use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

use crate::{KeyframePolicy, ScanAnchors};

/// Why the front-end refused a scan.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FrontEndError {
    /// The odometry pose is NaN or infinite.
    #[error("scan {scan}: non-finite odometry pose")]
    NonFiniteOdometry {
        /// Index of the scan.
        scan: usize,
    },
    /// The matcher's parameters are invalid.
    #[error(transparent)]
    Matcher(#[from] ScanMatchError),
}

/// Parameters of the front-end, one default for every log (no per-log tuning).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct FrontEndParams {
    /// When scans become keyframes.
    pub keyframes: KeyframePolicy,
    /// The scan matcher.
    pub matcher: ScanMatchParams,
    /// Search window around the odometry prediction (m, rad).
    pub odometry_window: SearchWindow,
    /// Keyframes whose points form the local map.
    pub local_map_keyframes: usize,
    /// Returns beyond this range are not used for matching (m): far returns are sparse and
    /// widen the angular search (Hess et al. 2016, Eq. 7).
    pub max_match_range_m: f32,
    /// Smallest standard deviations of a keyframe edge (m, rad), so one lucky match cannot
    /// make an edge overconfident.
    pub min_edge_sigma: (f64, f64),
}

impl Default for FrontEndParams {
    fn default() -> Self {
        Self {
            keyframes: KeyframePolicy::default(),
            matcher: odometry_matcher_params(),
            odometry_window: SearchWindow::new(0.5, 15f64.to_radians()),
            local_map_keyframes: 10,
            max_match_range_m: 20.0,
            min_edge_sigma: (0.01, 0.2f64.to_radians()),
        }
    }
}

/// The scan matcher for scan-to-map odometry: the ±0.5 m window spans 20 cells, so
/// branch-and-bound levels beyond 2^4 = 16 cells only cost time to precompute (they were half
/// of the front-end's time on Intel).
fn odometry_matcher_params() -> ScanMatchParams {
    let mut params = ScanMatchParams::default();
    params.correlative.branch_and_bound_depth = 4;
    params
}

/// What happened to one scan.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ScanStep {
    /// The scan's pose after matching (`map_from_robot`).
    pub map_from_robot: Se2,
    /// Match score, when the scan was matched.
    pub score: Option<f64>,
    /// The node created when the scan became a keyframe.
    pub keyframe: Option<NodeId>,
}

/// Counters over a run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct FrontEndInfo {
    /// Scans seen.
    pub scans: usize,
    /// Scans matched against the local map.
    pub matched: usize,
    /// Scans that fell back on odometry (no local map yet, or no acceptable match).
    pub odometry_only: usize,
    /// Keyframes.
    pub keyframes: usize,
}

/// The front-end's state: pose graph, keyframes with their points, anchors of every scan.
pub struct FrontEnd {
    params: FrontEndParams,
    matcher: ScanMatcher,
    graph: PoseGraph2,
    anchors: ScanAnchors,
    /// Points of each keyframe in its node's frame.
    keyframe_points: BTreeMap<NodeId, Vec<Point2>>,
    /// The last keyframes (for the local map), oldest first.
    recent: VecDeque<NodeId>,
    local_map: Option<ScanMatchTarget>,
    /// `(odom_from_robot, map_from_robot)` of the previous scan.
    previous: Option<(Se2, Se2)>,
    /// The current keyframe, its pose, and scans since it.
    current: Option<(NodeId, Se2, usize)>,
    info: FrontEndInfo,
}

impl FrontEnd {
    /// A front-end with no scans yet.
    pub fn new(params: FrontEndParams) -> Result<Self, FrontEndError> {
        Ok(Self {
            matcher: ScanMatcher::new(params.matcher)?,
            params,
            graph: PoseGraph2::new(),
            anchors: ScanAnchors::new(),
            keyframe_points: BTreeMap::new(),
            recent: VecDeque::new(),
            local_map: None,
            previous: None,
            current: None,
            info: FrontEndInfo::default(),
        })
    }

    /// The pose graph (keyframe nodes and odometry edges).
    pub fn graph(&self) -> &PoseGraph2 {
        &self.graph
    }

    /// Every scan's keyframe and pose in it.
    pub fn anchors(&self) -> &ScanAnchors {
        &self.anchors
    }

    /// Counters.
    pub fn info(&self) -> FrontEndInfo {
        self.info
    }

    /// Points of a keyframe in its node's frame.
    pub fn keyframe_points(&self, node: NodeId) -> Option<&[Point2]> {
        self.keyframe_points.get(&node).map(Vec::as_slice)
    }

    /// Processes the next scan, taken at wheel-odometry pose `odom_from_robot`.
    pub fn add_scan(
        &mut self,
        odom_from_robot: &Se2,
        scan: &LaserScan,
    ) -> Result<ScanStep, FrontEndError> {
        let index = self.info.scans;
        if !odom_from_robot.is_finite() {
            return Err(FrontEndError::NonFiniteOdometry { scan: index });
        }
        self.info.scans += 1;
        // 1. Predict from the odometry increment.
        let predicted = match self.previous {
            Some((odom_previous, map_previous)) => {
                map_previous.compose(&odom_previous.between(odom_from_robot))
            }
            None => Se2::identity(),
        };
        // 2. Match against the local map.
        let filter = BeamFilter {
            max_range_m: self.params.max_match_range_m,
            ..BeamFilter::default()
        };
        let points = scan.points_in_robot(&filter);
        let matched = self.local_map.as_ref().and_then(|target| {
            self.matcher
                .match_scan(target, &points, &predicted, &self.params.odometry_window)
        });
        let (map_from_robot, score, covariance) = match &matched {
            Some(m) => {
                self.info.matched += 1;
                (m.target_from_query, Some(m.score), Some(m.covariance))
            }
            None => {
                self.info.odometry_only += 1;
                (predicted, None, None)
            }
        };
        self.previous = Some((*odom_from_robot, map_from_robot));
        // 3. Keyframe or anchor.
        let make_keyframe = match self.current {
            None => true,
            Some((_, keyframe_pose, since)) => self
                .params
                .keyframes
                .is_keyframe(&keyframe_pose.between(&map_from_robot), since + 1),
        };
        let keyframe = if make_keyframe {
            Some(self.add_keyframe(map_from_robot, points, covariance)?)
        } else {
            if let Some((node, keyframe_pose, since)) = self.current.as_mut() {
                *since += 1;
                self.anchors
                    .push(*node, keyframe_pose.between(&map_from_robot));
            }
            None
        };
        Ok(ScanStep {
            map_from_robot,
            score,
            keyframe,
        })
    }

    /// Adds a keyframe node at `map_from_robot` with its points, an odometry edge from the
    /// previous keyframe, and rebuilds the local map.
    fn add_keyframe(
        &mut self,
        map_from_robot: Se2,
        points_in_robot: Vec<Point2>,
        covariance: Option<Matrix3<f64>>,
    ) -> Result<NodeId, FrontEndError> {
        let node = NodeId(self.info.keyframes as u64);
        self.info.keyframes += 1;
        // Ids are fresh, so adding cannot fail.
        let _ = self.graph.add_vertex(node, Vertex::new(map_from_robot));
        if let Some((previous, previous_pose, _)) = self.current {
            let measurement = previous_pose.between(&map_from_robot);
            let information =
                edge_information(covariance, &measurement, self.params.min_edge_sigma);
            let _ = self.graph.add_edge(Edge {
                from: previous,
                to: node,
                measurement,
                information,
                kind: EdgeKind::Odometry,
            });
        }
        self.anchors.push(node, Se2::identity());
        self.keyframe_points.insert(node, points_in_robot);
        self.current = Some((node, map_from_robot, 0));
        self.recent.push_back(node);
        while self.recent.len() > self.params.local_map_keyframes.max(1) {
            self.recent.pop_front();
        }
        // The local map: the recent keyframes' points in the map frame.
        let mut local_points = Vec::new();
        for id in &self.recent {
            if let (Some(points), Some(vertex)) =
                (self.keyframe_points.get(id), self.graph.vertex(*id))
            {
                local_points.extend(points.iter().map(|p| vertex.pose.transform_point(p)));
            }
        }
        self.local_map = self.matcher.target(&local_points).ok();
        Ok(node)
    }
}

/// Information of a keyframe edge: the inverse of the match covariance with its standard
/// deviations floored; without a match, a loose odometry model (10 % of the motion + 5 cm, 5°).
fn edge_information(
    covariance: Option<Matrix3<f64>>,
    measurement: &Se2,
    min_sigma: (f64, f64),
) -> Matrix3<f64> {
    let floor = Matrix3::from_diagonal(&nalgebra::Vector3::new(
        min_sigma.0 * min_sigma.0,
        min_sigma.0 * min_sigma.0,
        min_sigma.1 * min_sigma.1,
    ));
    let covariance = covariance
        .filter(|c| c.iter().all(|v| v.is_finite()))
        .unwrap_or_else(|| {
            let d = measurement.translation().norm();
            let (st, sr) = (
                0.1 * d + 0.05,
                0.1 * measurement.theta_rad.abs() + 5f64.to_radians(),
            );
            Matrix3::from_diagonal(&nalgebra::Vector3::new(st * st, st * st, sr * sr))
        });
    (covariance + floor)
        .try_inverse()
        .filter(|i| i.iter().all(|v| v.is_finite()))
        .unwrap_or_else(|| floor.try_inverse().unwrap_or_else(Matrix3::identity))
}

/// The result of [`run_front_end`]: every scan's pose and the counters.
#[derive(Clone, Debug)]
pub struct FrontEndRun {
    /// `map_from_robot` of every scan of the log, in log order (from the final graph).
    pub trajectory: Vec<Se2>,
    /// Counters.
    pub info: FrontEndInfo,
    /// Wall time of the front-end alone (s).
    pub seconds: f64,
}

/// Runs the front-end over every scan of `log`, with each scan's `odom_from_robot` as the
/// wheel odometry (scans without one reuse the previous one).
pub fn run_front_end(
    log: &mapmerge_scan::LaserLog,
    params: FrontEndParams,
) -> Result<FrontEndRun, FrontEndError> {
    let mut front_end = FrontEnd::new(params)?;
    let started = std::time::Instant::now();
    let mut odometry = Se2::identity();
    for record in &log.scans {
        odometry = record.odom_from_robot.unwrap_or(odometry);
        front_end.add_scan(&odometry, &record.scan)?;
    }
    let seconds = started.elapsed().as_secs_f64();
    let trajectory = front_end
        .anchors()
        .trajectory(front_end.graph())
        .into_iter()
        .map(|pose| pose.unwrap_or_else(Se2::identity))
        .collect();
    Ok(FrontEndRun {
        trajectory,
        info: front_end.info(),
        seconds,
    })
}
