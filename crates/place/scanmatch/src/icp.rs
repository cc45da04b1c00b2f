//! Point-to-line ICP (Censi, "An ICP variant using a point-to-line metric", ICRA 2008), solved
//! by Gauss–Newton on SE(2) with a Huber kernel.

use mapmerge_geometry::{LieGroup, Se2};
use std::collections::HashSet;

use mapmerge_scan::{estimate_normals, voxel_downsample, Point2, PointNormal};
use nalgebra::{Matrix2, Matrix3, SymmetricEigen, Vector3};
use serde::Serialize;

use crate::params::IcpParams;

/// Target points with normals and a bucket grid for nearest-neighbour queries. Build once per
/// target ([`IcpTarget::new`]) or grow it scan by scan ([`IcpTarget::insert`]).
#[derive(Clone, Debug)]
pub struct IcpTarget {
    points: Vec<PointNormal>,
    buckets: BucketGrid,
    /// Voxels (of `voxel_m`) already holding a point, for [`IcpTarget::insert`].
    occupied: HashSet<(i64, i64)>,
    voxel_m: f64,
}

/// Point indices in square buckets of `cell_m`, over a box that grows to cover the points.
#[derive(Clone, Debug)]
struct BucketGrid {
    cell_m: f64,
    min_m: Point2,
    width: i64,
    height: i64,
    buckets: Vec<Vec<u32>>,
}

/// At most this many buckets; a huge, sparse target gets larger cells.
const MAX_BUCKETS: f64 = 4e6;

impl BucketGrid {
    fn new(cell_m: f64) -> Self {
        Self {
            cell_m,
            min_m: Point2::zeros(),
            width: 0,
            height: 0,
            buckets: Vec::new(),
        }
    }

    /// Adds `points[first..]`, growing the box (with a margin of a few cells) and
    /// re-bucketing everything when one falls outside it.
    fn extend(&mut self, points: &[PointNormal], first: usize) {
        let Some(new_points) = points.get(first..) else {
            return;
        };
        if new_points.is_empty() {
            return;
        }
        let inside = new_points.iter().all(|p| {
            let (i, j) = self.cell_of(&p.point);
            i >= 0 && j >= 0 && i < self.width && j < self.height
        });
        if !inside || self.buckets.is_empty() {
            self.rebuild(points);
            return;
        }
        for (index, p) in new_points.iter().enumerate() {
            let (i, j) = self.cell_of(&p.point);
            if let Some(bucket) = self.bucket_mut(i, j) {
                bucket.push((first + index) as u32);
            }
        }
    }

    fn rebuild(&mut self, points: &[PointNormal]) {
        let bound = |f: fn(&PointNormal) -> f64, min: bool| {
            points.iter().map(f).fold(
                if min {
                    f64::INFINITY
                } else {
                    f64::NEG_INFINITY
                },
                |a, b| {
                    if min {
                        a.min(b)
                    } else {
                        a.max(b)
                    }
                },
            )
        };
        if points.is_empty() {
            return;
        }
        // A margin of 8 cells, so a map built scan by scan is rarely re-bucketed.
        let margin = 8.0 * self.cell_m;
        let min_m = Point2::new(bound(|p| p.point.x, true), bound(|p| p.point.y, true))
            - Point2::new(margin, margin);
        let max_m = Point2::new(bound(|p| p.point.x, false), bound(|p| p.point.y, false))
            + Point2::new(margin, margin);
        let span = (max_m - min_m) / self.cell_m;
        let scale = ((span.x + 1.0) * (span.y + 1.0) / MAX_BUCKETS)
            .sqrt()
            .max(1.0);
        self.cell_m *= scale;
        self.min_m = min_m;
        self.width = ((max_m.x - min_m.x) / self.cell_m).floor() as i64 + 1;
        self.height = ((max_m.y - min_m.y) / self.cell_m).floor() as i64 + 1;
        self.buckets = vec![Vec::new(); (self.width * self.height).max(0) as usize];
        for (index, p) in points.iter().enumerate() {
            let (i, j) = self.cell_of(&p.point);
            if let Some(bucket) = self.bucket_mut(i, j) {
                bucket.push(index as u32);
            }
        }
    }

    fn cell_of(&self, p: &Point2) -> (i64, i64) {
        const FAR: f64 = 1e15;
        let clamp = |v: f64| if v.is_nan() { FAR } else { v.clamp(-FAR, FAR) };
        (
            clamp(((p.x - self.min_m.x) / self.cell_m).floor()) as i64,
            clamp(((p.y - self.min_m.y) / self.cell_m).floor()) as i64,
        )
    }

    fn bucket(&self, i: i64, j: i64) -> Option<&Vec<u32>> {
        if i < 0 || j < 0 || i >= self.width || j >= self.height {
            return None;
        }
        self.buckets.get((j * self.width + i) as usize)
    }

    fn bucket_mut(&mut self, i: i64, j: i64) -> Option<&mut Vec<u32>> {
        if i < 0 || j < 0 || i >= self.width || j >= self.height {
            return None;
        }
        self.buckets.get_mut((j * self.width + i) as usize)
    }
}

impl IcpTarget {
    /// Normals of `points_in_target` by PCA (`mapmerge_scan::estimate_normals`) after
    /// voxel downsampling at `params.target_voxel_m`; points on blobs (planarity below
    /// `params.min_planarity`) are left out.
    pub fn new(points_in_target: &[Point2], params: &IcpParams) -> Self {
        let finite: Vec<Point2> = points_in_target
            .iter()
            .filter(|p| p.x.is_finite() && p.y.is_finite())
            .copied()
            .collect();
        let finite = voxel_downsample(&finite, params.target_voxel_m);
        let points = estimate_normals(&finite, params.normal_radius_m, 3, &Point2::zeros());
        let mut target = Self::empty(params);
        target.insert(&points, params);
        target
    }

    /// A target without points.
    pub fn empty(params: &IcpParams) -> Self {
        let cell_m = if params.max_correspondence_m.is_finite() && params.max_correspondence_m > 0.0
        {
            params.max_correspondence_m
        } else {
            1.0
        };
        Self {
            points: Vec::new(),
            buckets: BucketGrid::new(cell_m),
            occupied: HashSet::new(),
            voxel_m: params.target_voxel_m,
        }
    }

    /// Adds points with normals (e.g. a scan's, from `mapmerge_scan::scan_normals`, moved
    /// into the target frame): finite ones at least `params.min_planarity` line-like, and
    /// only one per `params.target_voxel_m` voxel (the first one; a map built from many
    /// scans repeats each wall many times).
    pub fn insert(&mut self, points_in_target: &[PointNormal], params: &IcpParams) {
        let first = self.points.len();
        let voxel_m = self.voxel_m;
        for p in points_in_target {
            let finite = p.point.iter().chain(p.normal.iter()).all(|v| v.is_finite());
            if !finite || p.planarity < params.min_planarity {
                continue;
            }
            if voxel_m.is_finite() && voxel_m > 0.0 {
                const FAR: f64 = 1e15;
                let key = (
                    (p.point.x / voxel_m).floor().clamp(-FAR, FAR) as i64,
                    (p.point.y / voxel_m).floor().clamp(-FAR, FAR) as i64,
                );
                if !self.occupied.insert(key) {
                    continue;
                }
            }
            self.points.push(*p);
        }
        self.buckets.extend(&self.points, first);
    }

    /// Bytes it holds on the heap: points, buckets and the voxel set (a `HashSet` slot
    /// counted as its key plus a control byte).
    pub fn heap_bytes(&self) -> usize {
        self.points.capacity() * std::mem::size_of::<PointNormal>()
            + self.buckets.buckets.capacity() * std::mem::size_of::<Vec<u32>>()
            + self
                .buckets
                .buckets
                .iter()
                .map(|b| b.capacity() * std::mem::size_of::<u32>())
                .sum::<usize>()
            + self.occupied.capacity() * (std::mem::size_of::<(i64, i64)>() + 1)
    }

    /// Number of target points that have a normal.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when no target point has a normal.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The nearest target point within `cell_m` of `p` (searching the 3 × 3 buckets).
    fn nearest(&self, p: &Point2) -> Option<(&PointNormal, f64)> {
        let (cx, cy) = self.buckets.cell_of(p);
        let mut best: Option<(&PointNormal, f64)> = None;
        for dx in -1..=1 {
            for dy in -1..=1 {
                let Some(bucket) = self.buckets.bucket(cx + dx, cy + dy) else {
                    continue;
                };
                for q in bucket.iter().filter_map(|&i| self.points.get(i as usize)) {
                    let d2 = (q.point - p).norm_squared();
                    if best.is_none_or(|(_, b)| d2 < b) {
                        best = Some((q, d2));
                    }
                }
            }
        }
        best
    }
}

/// What ICP did.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct IcpInfo {
    /// The refined pose of the query frame in the target frame.
    pub target_from_query: Se2,
    /// `(JᵀWJ)⁻¹ σ²` at the solution, in the right tangent `(v_x, v_y, ω)`; σ² is the
    /// weighted residual variance with 3 degrees of freedom removed. Directions the geometry
    /// does not constrain (a corridor's axis) get a large variance.
    pub covariance: Matrix3<f64>,
    /// Root mean square point-to-line distance of the inliers (m).
    pub rmse_m: f64,
    /// Fraction of query points with a correspondence within `max_correspondence_m`.
    pub inlier_fraction: f64,
    /// Gauss–Newton iterations run.
    pub iterations: usize,
    /// True when the last step was below the tolerances.
    pub converged: bool,
}

/// Refines `initial_target_from_query` by point-to-line ICP. `None` when the inputs leave
/// fewer than 3 correspondences or are non-finite.
pub fn refine_icp(
    target: &IcpTarget,
    query_points: &[Point2],
    initial_target_from_query: &Se2,
    params: &IcpParams,
) -> Option<IcpInfo> {
    if !initial_target_from_query.is_finite() {
        return None;
    }
    let query: Vec<&Point2> = query_points
        .iter()
        .filter(|p| p.x.is_finite() && p.y.is_finite())
        .collect();
    if query.len() < 3 || target.len() < 3 {
        return None;
    }
    let max_d2 = params.max_correspondence_m * params.max_correspondence_m;
    let huber = params.huber_m.max(f64::MIN_POSITIVE);
    let mut pose = *initial_target_from_query;
    let mut converged = false;
    let mut iterations = 0;
    let mut last = None;
    let skew = Matrix2::new(0.0, -1.0, 1.0, 0.0);
    for iteration in 0..=params.max_iterations {
        let rotation = pose.rotation_matrix();
        let translation = pose.translation();
        let mut hessian = Matrix3::zeros();
        let mut gradient = Vector3::zeros();
        let mut weighted_sq = 0.0;
        let mut sq_sum = 0.0;
        let mut inliers = 0usize;
        for q in &query {
            let p = rotation * *q + translation;
            let Some((nearest, d2)) = target.nearest(&p) else {
                continue;
            };
            if d2 > max_d2 {
                continue;
            }
            inliers += 1;
            // Censi 2008, Sec. II: residual along the target line's normal.
            let residual = nearest.normal.dot(&(p - nearest.point));
            // ∂p/∂(v, ω) for T·Exp(ξ): [R, R·J·q].
            let dv = rotation.transpose() * nearest.normal;
            let dw = nearest.normal.dot(&(rotation * skew * *q));
            let row = Vector3::new(dv.x, dv.y, dw);
            let weight = if residual.abs() <= huber {
                1.0
            } else {
                huber / residual.abs()
            };
            hessian += row * row.transpose() * weight;
            gradient += row * (weight * residual);
            weighted_sq += weight * residual * residual;
            sq_sum += residual * residual;
        }
        if inliers < 3 {
            return last;
        }
        let dof = (inliers as f64 - 3.0).max(1.0);
        let sigma_sq = (weighted_sq / dof).max(1e-8);
        let (inverse, step) = solve_spd(&hessian, &gradient);
        let info = IcpInfo {
            target_from_query: pose,
            covariance: inverse * sigma_sq,
            rmse_m: (sq_sum / inliers as f64).sqrt(),
            inlier_fraction: inliers as f64 / query.len() as f64,
            iterations,
            converged,
        };
        last = Some(info);
        if converged || iteration == params.max_iterations {
            break;
        }
        let delta = -step;
        pose = pose.retract(&delta);
        iterations += 1;
        converged = delta.xy().norm() < params.translation_tolerance_m
            && delta.z.abs() < params.rotation_tolerance_rad;
    }
    last
}

/// `(H⁺, H⁺ g)` with eigenvalues floored at 1e-9 · λ_max, so a degenerate direction (a
/// corridor) neither moves nor breaks the solve and gets a large variance.
fn solve_spd(hessian: &Matrix3<f64>, gradient: &Vector3<f64>) -> (Matrix3<f64>, Vector3<f64>) {
    let eigen = SymmetricEigen::new(*hessian);
    let largest = eigen.eigenvalues.max().max(f64::MIN_POSITIVE);
    let floor = largest * 1e-9;
    let inverse_values = eigen.eigenvalues.map(|l| 1.0 / l.max(floor));
    let inverse = eigen.eigenvectors
        * Matrix3::from_diagonal(&inverse_values)
        * eigen.eigenvectors.transpose();
    let inverse = (inverse + inverse.transpose()) * 0.5;
    (inverse, inverse * gradient)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn room() -> Vec<Point2> {
        let mut points = Vec::new();
        for k in 0..=100 {
            let t = k as f64 * 0.05;
            points.push(Point2::new(t, 0.0));
            points.push(Point2::new(t, 3.0));
            if t <= 3.0 {
                points.push(Point2::new(0.0, t));
                points.push(Point2::new(5.0, t));
            }
            if t <= 1.0 {
                points.push(Point2::new(2.0 + t, 1.5));
            }
        }
        points
    }

    #[test]
    fn icp_converges_from_small_perturbation_with_positive_definite_covariance() {
        let target_points = room();
        let truth = Se2::new(0.3, -0.2, 0.1);
        let query: Vec<Point2> = target_points
            .iter()
            .map(|p| truth.inverse().transform_point(p))
            .collect();
        let target = IcpTarget::new(&target_points, &IcpParams::default());
        let start = truth.compose(&Se2::new(0.08, -0.06, 0.04));
        let info = refine_icp(&target, &query, &start, &IcpParams::default()).unwrap();
        assert!(info.converged, "{info:?}");
        let error = truth.between(&info.target_from_query);
        assert!(
            error.translation().norm() < 0.005 && error.theta_rad.abs() < 0.002,
            "{error:?}"
        );
        assert!(info.inlier_fraction > 0.9);
        let eigen = SymmetricEigen::new(info.covariance);
        assert!(eigen.eigenvalues.min() > 0.0, "{:?}", info.covariance);
    }

    #[test]
    fn icp_refuses_empty_and_nan() {
        let target = IcpTarget::new(&room(), &IcpParams::default());
        assert!(refine_icp(&target, &[], &Se2::identity(), &IcpParams::default()).is_none());
        let nan = Se2 {
            x_m: f64::NAN,
            y_m: 0.0,
            theta_rad: 0.0,
        };
        assert!(refine_icp(&target, &room(), &nan, &IcpParams::default()).is_none());
        let empty = IcpTarget::new(&[], &IcpParams::default());
        assert!(refine_icp(&empty, &room(), &Se2::identity(), &IcpParams::default()).is_none());
    }
}
