//! Helpers shared by the integration tests: a brute-force verifier (not a production scan
//! matcher) and keyframes from the simulator.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_place::{GeometricVerifier, Keyframe, Verification};
use mapmerge_scan::{voxel_downsample, BeamFilter, LaserScan, Point2};
use nalgebra::Matrix3;

/// Points of a scan in the robot frame.
pub fn scan_points(scan: &LaserScan) -> Vec<Point2> {
    scan.points_in_robot(&BeamFilter::default())
}

/// Brute-force alignment: a grid over yaw (around the guess) and translation, scored by the
/// fraction of query points with a candidate point within `inlier_m` (k-d tree), coarse then
/// fine.
pub struct BruteForceVerifier {
    /// Half-width of the translation search (m).
    pub search_m: f64,
    /// Half-width of the yaw search around the guess (rad).
    pub search_yaw_rad: f64,
    /// Inlier distance (m).
    pub inlier_m: f64,
    /// Only points within this range of the query origin count (m).
    pub max_range_m: f64,
}

impl Default for BruteForceVerifier {
    fn default() -> Self {
        Self {
            search_m: 1.2,
            search_yaw_rad: 12f64.to_radians(),
            inlier_m: 0.15,
            max_range_m: 10.0,
        }
    }
}

impl BruteForceVerifier {
    fn score(
        &self,
        tree: &ImmutableKdTree<f64, 2>,
        query: &[Point2],
        pose: &Se2,
        inlier_m: f64,
    ) -> f64 {
        if query.is_empty() {
            return 0.0;
        }
        let limit = inlier_m * inlier_m;
        let inliers = query
            .iter()
            .filter(|p| {
                let q = pose.transform_point(p);
                let nearest = tree
                    .query(&[q.x, q.y])
                    .nearest_one::<SquaredEuclidean<f64>>()
                    .execute();
                nearest.distance <= limit
            })
            .count();
        inliers as f64 / query.len() as f64
    }

    #[allow(clippy::too_many_arguments)]
    fn search(
        &self,
        tree: &ImmutableKdTree<f64, 2>,
        query: &[Point2],
        centre: &Se2,
        half_m: f64,
        step_m: f64,
        half_rad: f64,
        step_rad: f64,
        inlier_m: f64,
    ) -> (f64, Se2) {
        let nt = (half_m / step_m).round() as i32;
        let nr = (half_rad / step_rad).round() as i32;
        let mut best = (f64::NEG_INFINITY, *centre);
        for ir in -nr..=nr {
            for ix in -nt..=nt {
                for iy in -nt..=nt {
                    let pose = Se2::new(
                        centre.x_m + f64::from(ix) * step_m,
                        centre.y_m + f64::from(iy) * step_m,
                        centre.theta_rad + f64::from(ir) * step_rad,
                    );
                    let s = self.score(tree, query, &pose, inlier_m);
                    if s > best.0 {
                        best = (s, pose);
                    }
                }
            }
        }
        best
    }
}

impl GeometricVerifier for BruteForceVerifier {
    fn verify(&self, query: &Keyframe, candidate: &Keyframe, guess: &Se2) -> Option<Verification> {
        let within =
            |p: &&Point2| p.x.is_finite() && p.y.is_finite() && p.norm() < self.max_range_m;
        let target: Vec<[f64; 2]> = voxel_downsample(
            &candidate
                .points_in_keyframe
                .iter()
                .filter(within)
                .copied()
                .collect::<Vec<_>>(),
            0.05,
        )
        .iter()
        .map(|p| [p.x, p.y])
        .collect();
        if target.is_empty() {
            return None;
        }
        let tree = ImmutableKdTree::<f64, 2>::new_from_slice(&target).ok()?;
        let source = voxel_downsample(
            &query
                .points_in_keyframe
                .iter()
                .filter(within)
                .copied()
                .collect::<Vec<_>>(),
            0.25,
        );
        let (_, coarse) = self.search(
            &tree,
            &source,
            guess,
            self.search_m,
            0.2,
            self.search_yaw_rad,
            3f64.to_radians(),
            self.inlier_m,
        );
        let (score, fine) = self.search(
            &tree,
            &source,
            &coarse,
            0.2,
            0.05,
            3f64.to_radians(),
            1f64.to_radians(),
            self.inlier_m,
        );
        // Polish the pose with a tighter inlier distance (the score keeps `inlier_m`).
        let (_, polished) = self.search(
            &tree,
            &source,
            &fine,
            0.06,
            0.02,
            1f64.to_radians(),
            0.5f64.to_radians(),
            0.4 * self.inlier_m,
        );
        Some(Verification {
            candidate_from_query: polished,
            score,
            covariance: Matrix3::from_diagonal(&nalgebra::Vector3::new(
                0.05f64.powi(2),
                0.05f64.powi(2),
                0.02f64.powi(2),
            )),
        })
    }
}

/// `a⁻¹ · b`.
pub fn between(a: &Se2, b: &Se2) -> Se2 {
    a.inverse().compose(b)
}

/// Descriptor parameters, overridable for experiments (`PLACE_RINGS`, `PLACE_SECTORS`,
/// `PLACE_RADIUS_M`, `PLACE_HARD=1`).
pub fn descriptor_params() -> mapmerge_place::ScanContextParams {
    let mut p = mapmerge_place::ScanContextParams::default();
    let var = |name: &str| std::env::var(name).ok().and_then(|v| v.parse::<f64>().ok());
    if let Some(v) = var("PLACE_RINGS") {
        p.ring_count = v as usize;
    }
    if let Some(v) = var("PLACE_SECTORS") {
        p.sector_count = v as usize;
    }
    if let Some(v) = var("PLACE_RADIUS_M") {
        p.max_radius_m = v;
    }
    if var("PLACE_HARD").is_some() {
        p.soft_binning = false;
    }
    p
}

/// Index parameters, overridable for experiments (`PLACE_NEIGHBOURS`).
pub fn index_params() -> mapmerge_place::IndexParams {
    let mut p = mapmerge_place::IndexParams::default();
    if let Some(v) = std::env::var("PLACE_NEIGHBOURS")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        p.ring_key_neighbours = v;
    }
    p
}
