//! Submaps every `spacing_m` metres along a segment (Yin et al., AutoMerge, Sec. V-A: "each
//! T_i has point cloud submaps separated by a constant distance"; Sec. IV-A: scans are
//! accumulated into local dense maps so that an observation does not depend on the exact
//! viewpoint).
//!
//! A submap is centred on one scan: the points of every scan whose travel along the trajectory
//! lies within `window_m` of the centre's, expressed in the centre scan's robot frame, limited
//! to `radius_m` (horizontal range) and voxel-downsampled. Accumulating scans from before and
//! after the centre gives a planar front laser a full 360° view, which is what makes a place
//! look the same when it is driven in the opposite direction. Travel is measured by
//! translation only, so turning on the spot starts no new submap.

use std::sync::Arc;

use mapmerge_params::{Checker, Real, Validate};
use mapmerge_place::FreeSpace;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::AssembleError;
use crate::segment::{Point3, SegmentPoints};
use mapmerge_scan::Point2;

/// How submaps are cut from a segment.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SubmapParams {
    /// Travel between consecutive submap centres (m) (default: 1.0, indoors; the paper uses
    /// 5 m outdoors, [`SubmapParams::outdoor`]). Shorter spacing gives more submaps, hence
    /// finer loop edges and longer sequences for sequence matching, at a quadratic cost in the
    /// difference matrices.
    pub spacing_m: f64,
    /// Points farther than this from the centre (horizontal range, m) are dropped (default:
    /// 10). Should match the descriptor's radius. Larger sees more of the surroundings (more
    /// distinctive) but lets occlusion and odometry drift change more of the picture.
    pub radius_m: f64,
    /// Scans whose travel differs from the centre's by at most this (m) are accumulated
    /// (default: 4). Larger windows fill the rear view and occlusion shadows; odometry drift
    /// inside the window blurs the submap.
    pub window_m: f64,
    /// Voxel (cell) side of the downsampling (m) (default: 0.1); 0 keeps every point.
    pub voxel_m: f64,
    /// Cell side (m) of the free space a 2D submap keeps, the cells its scans' beams crossed
    /// (from each scan's sensor), so that verification compares two submaps over their whole
    /// overlap (`mapmerge_place::Evidence::agreement`); 0 keeps none (default: 0.1; the
    /// outdoor preset keeps none).
    pub free_space_m: f64,
}

impl Default for SubmapParams {
    fn default() -> Self {
        Self {
            spacing_m: 1.0,
            radius_m: 10.0,
            window_m: 4.0,
            voxel_m: 0.1,
            free_space_m: 0.1,
        }
    }
}

impl SubmapParams {
    /// Outdoor defaults, as the paper's city-scale data: 5 m spacing, 50 m radius, a 25 m
    /// window each way and 0.5 m voxels.
    pub fn outdoor() -> Self {
        Self {
            spacing_m: 5.0,
            radius_m: 50.0,
            window_m: 25.0,
            voxel_m: 0.5,
            free_space_m: 0.0,
        }
    }

    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), AssembleError> {
        Ok(Validate::validate(self)?)
    }
}

impl Validate for SubmapParams {
    fn check(&self, check: &mut Checker) {
        check
            .real("spacing_m", self.spacing_m, Real::within(0.01, 1000.0))
            .real("radius_m", self.radius_m, Real::positive_up_to(1000.0))
            .real("window_m", self.window_m, Real::within(0.0, 1000.0))
            .real("voxel_m", self.voxel_m, Real::within(0.0, 10.0))
            .real("free_space_m", self.free_space_m, Real::within(0.0, 10.0));
    }
}

/// A point type submaps can hold: planar ([`Point2`]) or spatial ([`Point3`]).
pub trait SubmapPoint: Copy + Send + Sync + std::fmt::Debug + 'static {
    /// The origin.
    fn zero() -> Self;
    /// `self + other`.
    fn add(&self, other: &Self) -> Self;
    /// `self · factor`.
    fn scaled(&self, factor: f64) -> Self;
    /// Distance from the frame's z axis (m): the polar radius descriptors bin by.
    fn horizontal_range_m(&self) -> f64;
    /// Integer voxel coordinates for cells of `cell_m` (`z` cell 0 in 2D).
    fn voxel_key(&self, cell_m: f64) -> [i64; 3];
    /// The point in the ground plane (m).
    fn planar(&self) -> Point2;
}

impl SubmapPoint for Point2 {
    fn zero() -> Self {
        Point2::zeros()
    }
    fn add(&self, other: &Self) -> Self {
        self + other
    }
    fn scaled(&self, factor: f64) -> Self {
        self * factor
    }
    fn horizontal_range_m(&self) -> f64 {
        self.norm()
    }
    fn voxel_key(&self, cell_m: f64) -> [i64; 3] {
        // `as` saturates for huge values, which only merges far-away points.
        [
            (self.x / cell_m).floor() as i64,
            (self.y / cell_m).floor() as i64,
            0,
        ]
    }
    fn planar(&self) -> Point2 {
        *self
    }
}

impl SubmapPoint for Point3 {
    fn zero() -> Self {
        Point3::zeros()
    }
    fn add(&self, other: &Self) -> Self {
        self + other
    }
    fn scaled(&self, factor: f64) -> Self {
        self * factor
    }
    fn horizontal_range_m(&self) -> f64 {
        self.x.hypot(self.y)
    }
    fn voxel_key(&self, cell_m: f64) -> [i64; 3] {
        [
            (self.x / cell_m).floor() as i64,
            (self.y / cell_m).floor() as i64,
            (self.z / cell_m).floor() as i64,
        ]
    }
    fn planar(&self) -> Point2 {
        Point2::new(self.x, self.y)
    }
}

/// One submap of a segment.
#[derive(Clone, Debug, PartialEq)]
pub struct SegmentSubmap<P, G> {
    /// Position in the segment's submap list (0, 1, …).
    pub index: usize,
    /// The scan the submap is centred on (its frame is that scan's robot frame).
    pub centre_scan: usize,
    /// First and last scan (inclusive) accumulated into it.
    pub scan_range: (usize, usize),
    /// `segment_from_centre`: the centre scan's robot pose in the segment frame.
    pub segment_from_centre: G,
    /// Travel along the trajectory from the segment's start to the centre scan (m).
    pub travel_m: f64,
    /// The points in the centre scan's robot frame, voxel-downsampled (voxel key order).
    pub points_in_centre: Vec<P>,
    /// The free space the accumulated scans' beams crossed, in the same frame (2D segments
    /// with `SubmapParams::free_space_m > 0`).
    pub free_space: Option<Arc<FreeSpace>>,
}

/// The submaps of a segment of type `S`.
pub type SubmapsOf<S> = Vec<SegmentSubmap<<S as SegmentPoints>::Point, <S as SegmentPoints>::Pose>>;

/// A submap of a 2D segment.
pub type Submap2 = SegmentSubmap<Point2, mapmerge_geometry::Se2>;
/// A submap of a 3D segment.
pub type Submap3 = SegmentSubmap<Point3, mapmerge_geometry::Se3>;

/// The centre scans: the first scan, then every scan whose travel since the previous centre
/// reaches `spacing_m` (so consecutive centres are at least `spacing_m` apart along the
/// trajectory, and less than `spacing_m` plus one scan step).
pub fn submap_centres(travel_m: &[f64], spacing_m: f64) -> Vec<usize> {
    let mut centres = Vec::with_capacity(
        travel_m
            .last()
            .map_or(0, |total| (total / spacing_m.max(1e-9)) as usize + 1)
            .min(travel_m.len()),
    );
    let mut last_m = f64::NEG_INFINITY;
    for (scan, &t) in travel_m.iter().enumerate() {
        if t - last_m >= spacing_m {
            centres.push(scan);
            last_m = t;
        }
    }
    centres
}

/// Cuts `segment` into submaps (module doc), in parallel over submaps.
pub fn build_submaps<S: SegmentPoints>(
    segment: &S,
    params: &SubmapParams,
) -> Result<SubmapsOf<S>, AssembleError> {
    params.validate()?;
    let travel_m = segment.travel_m();
    let centres = submap_centres(&travel_m, params.spacing_m);
    let submaps = centres
        .par_iter()
        .enumerate()
        .filter_map(|(index, &centre)| {
            let centre_travel_m = *travel_m.get(centre)?;
            let segment_from_centre = segment.pose(centre)?;
            // Travel is non-decreasing, so the window is one contiguous run of scans.
            let first = travel_m.partition_point(|&t| t < centre_travel_m - params.window_m);
            let end = travel_m.partition_point(|&t| t <= centre_travel_m + params.window_m);
            let last = end.saturating_sub(1).max(first);
            let mut points = Vec::new();
            // Beams (centre frame) from each scan's sensor to its returns.
            let keep_rays = params.free_space_m > 0.0;
            let mut rays: Vec<(Point2, Point2)> = Vec::new();
            for scan in first..end {
                let before = points.len();
                segment.push_points_in_centre(centre, scan, params.radius_m, &mut points);
                if let (true, Some(origin), Some(new)) = (
                    keep_rays,
                    segment.sensor_in_centre(centre, scan),
                    points.get(before..),
                ) {
                    rays.extend(new.iter().map(|p| (origin, p.planar())));
                }
            }
            let free_space = if rays.is_empty() {
                None
            } else {
                FreeSpace::from_rays(params.free_space_m, rays)
                    .ok()
                    .map(Arc::new)
            };
            Some(SegmentSubmap {
                index,
                centre_scan: centre,
                scan_range: (first, last),
                segment_from_centre,
                travel_m: centre_travel_m,
                points_in_centre: voxel_downsample(&points, params.voxel_m),
                free_space,
            })
        })
        .collect();
    Ok(submaps)
}

/// One point per occupied `cell_m` voxel: the centroid of the points in it, in voxel key
/// order (deterministic, independent of the input order up to rounding). A non-positive or
/// non-finite `cell_m` returns the points unchanged.
pub fn voxel_downsample<P: SubmapPoint>(points: &[P], cell_m: f64) -> Vec<P> {
    if !(cell_m.is_finite() && cell_m > 0.0) {
        return points.to_vec();
    }
    let mut keyed: Vec<([i64; 3], u32)> = points
        .iter()
        .enumerate()
        .map(|(i, p)| (p.voxel_key(cell_m), i as u32))
        .collect();
    keyed.sort_unstable();
    let mut out = Vec::new();
    let mut run = keyed.as_slice();
    while let Some(&(key, _)) = run.first() {
        let length = run.iter().take_while(|(k, _)| *k == key).count();
        let (voxel, rest) = run.split_at(length);
        let mut sum = P::zero();
        for &(_, i) in voxel {
            if let Some(p) = points.get(i as usize) {
                sum = sum.add(p);
            }
        }
        out.push(sum.scaled(1.0 / length as f64));
        run = rest;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centres_keep_the_spacing() {
        let travel: Vec<f64> = (0..100).map(|k| k as f64 * 0.3).collect();
        let centres = submap_centres(&travel, 1.0);
        assert_eq!(centres[0], 0);
        for pair in centres.windows(2) {
            let gap = travel[pair[1]] - travel[pair[0]];
            assert!((1.0..1.3).contains(&gap), "{gap}");
        }
        assert!(submap_centres(&[], 1.0).is_empty());
        // Standing still: one submap.
        assert_eq!(submap_centres(&[0.0; 10], 1.0), vec![0]);
    }

    #[test]
    fn voxels_average_their_points() {
        let points = vec![
            Point2::new(0.01, 0.01),
            Point2::new(0.03, 0.05),
            Point2::new(-0.05, 0.0),
        ];
        let out = voxel_downsample(&points, 0.1);
        assert_eq!(out.len(), 2);
        assert!((out[0] - Point2::new(-0.05, 0.0)).norm() < 1e-12);
        assert!((out[1] - Point2::new(0.02, 0.03)).norm() < 1e-12);
        assert_eq!(voxel_downsample(&points, 0.0), points);
    }

    #[test]
    fn params_are_checked() {
        assert!(SubmapParams::default().validate().is_ok());
        assert!(SubmapParams::outdoor().validate().is_ok());
        let bad = SubmapParams {
            spacing_m: 0.0,
            ..SubmapParams::default()
        };
        assert!(bad.validate().is_err());
        let bad = SubmapParams {
            voxel_m: f64::NAN,
            ..SubmapParams::default()
        };
        assert!(bad.validate().is_err());
    }
}
