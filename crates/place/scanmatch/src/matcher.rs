//! The combined matcher: correlative search, then point-to-line ICP refinement.

use std::sync::OnceLock;

use mapmerge_geometry::Se2;
use mapmerge_scan::{scan_normals, transform_points, voxel_downsample, Point2};
use nalgebra::Matrix3;
use serde::Serialize;

use crate::correlative::{match_scan_above, score_at, MatchTarget};
use crate::error::ScanMatchError;
use crate::icp::{refine_icp, IcpInfo, IcpTarget};
use crate::params::{IcpParams, ScanMatchParams, SearchWindow};

/// A target prepared for both stages: correlation grids and normals.
#[derive(Clone, Debug)]
pub struct ScanMatchTarget {
    correlative: MatchTarget,
    /// The ICP target (with `icp_params`): kept up to date by a target built scan by scan;
    /// made from the correlative target's points the first time ICP needs it in a target
    /// built from points, so that a search that finds nothing (most candidates of a place
    /// query) does not pay for normals.
    icp: OnceLock<IcpTarget>,
    icp_params: Option<IcpParams>,
}

/// Margin (cells) by which a target built scan by scan grows, so it is not copied per scan.
const GROWTH_MARGIN_CELLS: usize = 100;

/// Neighbourhood of a scan point's normal: 3 beams on each side within 0.2 m or 6 % of the
/// range (about 3.4° of arc), see `mapmerge_scan::scan_normals`.
const SCAN_NORMAL_HALF_WINDOW: usize = 3;
const SCAN_NORMAL_MIN_GAP_M: f64 = 0.2;
const SCAN_NORMAL_GAP_PER_RANGE: f64 = 0.06;

impl ScanMatchTarget {
    /// The correlative target (grid and levels).
    pub fn correlative(&self) -> &MatchTarget {
        &self.correlative
    }

    /// Bytes it holds on the heap (correlation grids and the ICP target).
    pub fn heap_bytes(&self) -> usize {
        self.correlative.heap_bytes() + self.icp.get().map_or(0, IcpTarget::heap_bytes)
    }

    /// The ICP target, made now from the correlative target's points if it was deferred;
    /// `None` without ICP parameters.
    fn icp_target(&self) -> Option<&IcpTarget> {
        let params = self.icp_params.as_ref()?;
        Some(
            self.icp
                .get_or_init(|| IcpTarget::new(self.correlative.points_in_target(), params)),
        )
    }

    /// Mutable access to the correlative target (e.g. to deepen its levels once a map is
    /// finished and will be searched with large windows).
    pub fn correlative_mut(&mut self) -> &mut MatchTarget {
        &mut self.correlative
    }

    /// Brings the correlative target's coarse levels up to date after insertions (see
    /// [`MatchTarget::prepare`]); call before matching a map that grows.
    pub fn prepare(&mut self) {
        self.correlative.prepare();
    }

    /// Adds one scan, `points_in_robot` in beam order, seen from `target_from_robot`: its
    /// points join the correlation grid and its normals (from neighbouring beams) the ICP
    /// target. The way a map is built scan by scan (Hess et al. 2016's submaps).
    pub fn insert_scan(
        &mut self,
        target_from_robot: &Se2,
        points_in_robot: &[Point2],
    ) -> Result<(), ScanMatchError> {
        let points_in_target = transform_points(target_from_robot, points_in_robot);
        // A deferred ICP target is made first from the points so far, as it would have been.
        let _ = self.icp_target();
        self.correlative
            .insert(&points_in_target, GROWTH_MARGIN_CELLS)?;
        if let (Some(icp), Some(params)) = (self.icp.get_mut(), self.icp_params.as_ref()) {
            let mut normals = scan_normals(
                points_in_robot,
                SCAN_NORMAL_HALF_WINDOW,
                SCAN_NORMAL_MIN_GAP_M,
                SCAN_NORMAL_GAP_PER_RANGE,
                &Point2::zeros(),
            );
            let rotation = target_from_robot.rotation_matrix();
            for n in &mut normals {
                n.point = target_from_robot.transform_point(&n.point);
                n.normal = rotation * n.normal;
            }
            icp.insert(&normals, params);
        }
        Ok(())
    }
}

/// A scan match.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Match {
    /// Pose of the query (robot) frame in the target frame: ICP's when ICP ran and was
    /// accepted, else the correlative search's.
    pub target_from_query: Se2,
    /// Mean likelihood of the query points in the correlation grid at the correlative
    /// optimum, in [0, 1].
    pub score: f64,
    /// Covariance of `target_from_query`, right-perturbation tangent `(v_x, v_y, ω)`: ICP's
    /// when accepted, else the correlative one (Olson 2009, Sec. IV).
    pub covariance: Matrix3<f64>,
    /// Candidates the branch-and-bound scored.
    pub candidates: usize,
    /// The correlative search's own pose (before refinement).
    pub correlative_target_from_query: Se2,
    /// What ICP did, when it ran and was accepted.
    pub icp: Option<IcpInfo>,
}

/// Correlative search followed by ICP refinement, with one set of parameters.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ScanMatcher {
    params: ScanMatchParams,
}

impl ScanMatcher {
    /// A matcher with `params` (checked).
    pub fn new(params: ScanMatchParams) -> Result<Self, ScanMatchError> {
        params.correlative.validate()?;
        Ok(Self { params })
    }

    /// The parameters.
    pub fn params(&self) -> &ScanMatchParams {
        &self.params
    }

    /// Prepares `points_in_target` (a scan or a local map, in the target frame).
    pub fn target(&self, points_in_target: &[Point2]) -> Result<ScanMatchTarget, ScanMatchError> {
        let mut target = self.empty_target()?;
        self.retarget(&mut target, points_in_target)?;
        Ok(target)
    }

    /// Makes `target` (from any matcher) the target of `points_in_target` with this matcher's
    /// parameters (what [`ScanMatcher::target`] builds), reusing its correlation grid's memory
    /// (see [`MatchTarget::rebuild`]).
    pub fn retarget(
        &self,
        target: &mut ScanMatchTarget,
        points_in_target: &[Point2],
    ) -> Result<(), ScanMatchError> {
        target
            .correlative
            .rebuild(points_in_target, &self.params.correlative)?;
        target.icp = OnceLock::new();
        target.icp_params = self.params.icp;
        Ok(())
    }

    /// An empty target to build scan by scan with [`ScanMatchTarget::insert_scan`].
    pub fn empty_target(&self) -> Result<ScanMatchTarget, ScanMatchError> {
        Ok(ScanMatchTarget {
            correlative: MatchTarget::empty(&self.params.correlative)?,
            icp: self.params.icp.map_or_else(OnceLock::new, |params| {
                OnceLock::from(IcpTarget::empty(&params))
            }),
            icp_params: self.params.icp,
        })
    }

    /// ICP alone from `guess_target_from_robot` (no search), scored like
    /// [`ScanMatcher::match_scan`] at the refined pose: the fast path when the guess is
    /// already in the right basin (a good odometry prediction). `None` when ICP is disabled,
    /// finds fewer than 3 correspondences, or the inputs are empty or non-finite.
    pub fn refine(
        &self,
        target: &ScanMatchTarget,
        query_points_in_robot: &[Point2],
        guess_target_from_robot: &Se2,
    ) -> Option<Match> {
        let (Some(icp_params), Some(icp_target)) = (self.params.icp, target.icp_target()) else {
            return None;
        };
        let query = voxel_downsample(query_points_in_robot, self.params.correlative.query_voxel_m);
        let info = refine_icp(icp_target, &query, guess_target_from_robot, &icp_params)?;
        let score = score_at(&target.correlative, &query, &info.target_from_query)?;
        Some(Match {
            target_from_query: info.target_from_query,
            score,
            covariance: info.covariance,
            candidates: 0,
            correlative_target_from_query: *guess_target_from_robot,
            icp: Some(info),
        })
    }

    /// Matches `query_points_in_robot` against `target` within `window` around
    /// `guess_target_from_robot`. `None` when no pose scores `min_score` or the inputs are
    /// empty or non-finite.
    pub fn match_scan(
        &self,
        target: &ScanMatchTarget,
        query_points_in_robot: &[Point2],
        guess_target_from_robot: &Se2,
        window: &SearchWindow,
    ) -> Option<Match> {
        self.match_scan_above(
            target,
            query_points_in_robot,
            guess_target_from_robot,
            window,
            target.correlative.params().min_score,
        )
    }

    /// As [`ScanMatcher::match_scan`], also refusing matches whose (correlative) score is below
    /// `min_score`: the same match when it reaches both floors, `None` otherwise. A caller
    /// that refuses matches below some score finds that out far sooner: the search proves
    /// that nothing reaches the higher floor instead of the lower one.
    pub fn match_scan_above(
        &self,
        target: &ScanMatchTarget,
        query_points_in_robot: &[Point2],
        guess_target_from_robot: &Se2,
        window: &SearchWindow,
        min_score: f64,
    ) -> Option<Match> {
        // 1. Exhaustive-equivalent correlative search.
        let coarse = match_scan_above(
            &target.correlative,
            query_points_in_robot,
            guess_target_from_robot,
            window,
            min_score.max(target.correlative.params().min_score),
        )?;
        let mut result = Match {
            target_from_query: coarse.target_from_query,
            score: coarse.score,
            covariance: coarse.covariance,
            candidates: coarse.candidates,
            correlative_target_from_query: coarse.target_from_query,
            icp: None,
        };
        // 2. Point-to-line ICP from the correlative optimum.
        let (Some(icp_params), Some(icp_target)) = (self.params.icp, target.icp_target()) else {
            return Some(result);
        };
        let query = voxel_downsample(query_points_in_robot, self.params.correlative.query_voxel_m);
        let Some(info) = refine_icp(icp_target, &query, &coarse.target_from_query, &icp_params)
        else {
            return Some(result);
        };
        // 3. Keep ICP only when it agrees with the search (no jump to another basin).
        let shift = coarse.target_from_query.translation() - info.target_from_query.translation();
        let max_shift = self.params.icp_max_shift_cells * self.params.correlative.resolution_m;
        let turn = mapmerge_geometry::wrap_angle_rad(
            coarse.target_from_query.theta_rad - info.target_from_query.theta_rad,
        );
        let max_turn = self.params.icp_max_shift_cells * coarse.angular_step_rad;
        if info.inlier_fraction >= self.params.icp_min_inlier_fraction
            && shift.norm() <= max_shift
            && turn.abs() <= max_turn.max(1e-3)
            && info
                .target_from_query
                .translation()
                .iter()
                .all(|v| v.is_finite())
        {
            result.target_from_query = info.target_from_query;
            result.covariance = info.covariance;
            result.icp = Some(info);
        }
        Some(result)
    }
}
