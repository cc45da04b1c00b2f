//! Scan Context for 2D laser keyframes (Kim & Kim, "Scan Context: Egocentric Spatial
//! Descriptor for Place Recognition within 3D Point Cloud Map", IROS 2018), adapted to planar
//! scans.
//!
//! A polar grid of `ring_count` rings up to `max_radius_m` and `sector_count` sectors around
//! the keyframe origin (Sec. III-A, Eq. 1–2). Rotating the robot only shifts the sectors
//! circularly, so
//! - the *ring key* (one number per ring, Sec. IV-A) is rotation invariant and drives
//!   retrieval, and
//! - the *column-shift distance* (Eq. 5–6) compares two descriptors at every circular sector
//!   shift; the best shift times the sector angle estimates the relative yaw.
//!
//! **Bin value.** The 3D paper stores the maximum height per bin; a planar scan has no height.
//! We store a saturated, bilinearly splatted occupancy: each point spreads a unit weight over
//! the four nearest bin centres (ring × sector) and a bin's value is `min(1, Σ weights)`.
//! Reasons: (1) with evenly spaced beams a wall crossing a bin leaves ≈ the same number of
//! points at any range (beam spacing and sector arc both grow with range), so saturated
//! occupancy is insensitive to range and to density changes (another scanner, a local map of
//! several merged scans, voxel-downsampled input) while raw counts are not; (2) free space
//! shows as zeros, the 2D analogue of "low height"; (3) splatting makes the descriptor a
//! continuous function of the points, so the distance grows smoothly with translation
//! instead of jumping when a wall crosses a bin boundary.
//!
//! **Translation.** Scan Context is egocentric, so a translated origin moves points between
//! bins. Robustness to a few tens of cm comes from coarse rings (0.75 m by default) and the
//! splatting above: a 0.3 m shift moves most wall mass by less than one bin and changes the
//! cosine similarity of each column gradually (see the `distance_grows_smoothly` test).
//! Feeding a local map (several scans merged in the keyframe frame) instead of one scan fills
//! occlusion shadows and helps further; the descriptor needs no change for that.

use mapmerge_params::{Checker, Real, Validate};
use mapmerge_scan::Point2;
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use crate::descriptor::{DescriptorExtractor, DescriptorMatch, PlaceDescriptor};

/// Largest accepted ring and sector counts (bigger values are clamped).
const MAX_RINGS: usize = 256;
/// See [`MAX_RINGS`].
const MAX_SECTORS: usize = 1024;

/// Parameters of the 2D Scan Context descriptor.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScanContextParams {
    /// Number of rings (default: 20, as the paper). More rings resolve range better but make
    /// the descriptor more sensitive to translation; with `max_radius_m` it sets the ring
    /// width (0.75 m by default). Clamped to `1..=256`.
    pub ring_count: usize,
    /// Number of sectors (default: 60, 6° each, as the paper). More sectors give a finer yaw
    /// estimate but cost `O(sectors²)` per comparison. Clamped to `1..=1024`.
    pub sector_count: usize,
    /// Radius of the outermost ring (m) (default: 15). Points beyond are ignored. Indoors,
    /// 15 m reaches down corridors and into neighbouring rooms, which disambiguates places
    /// (on the Intel log recall@5 rose from 0.81 at 10 m to 0.84 at 15 m; 8 m gave 0.74).
    /// Non-finite or non-positive values fall back to 15.
    pub max_radius_m: f64,
    /// Spread each point bilinearly over the nearest bins (default: true). Off gives the
    /// paper's hard binning, which is faster to build but jumps under small translations
    /// (Intel log recall@5: 0.72 hard vs 0.84 soft).
    pub soft_binning: bool,
}

impl Default for ScanContextParams {
    fn default() -> Self {
        Self {
            ring_count: 20,
            sector_count: 60,
            max_radius_m: 15.0,
            soft_binning: true,
        }
    }
}

impl ScanContextParams {
    /// `(rings, sectors, max radius)` after clamping to valid values.
    fn sanitized(&self) -> (usize, usize, f64) {
        let radius = if self.max_radius_m.is_finite() && self.max_radius_m > 0.0 {
            self.max_radius_m
        } else {
            15.0
        };
        (
            self.ring_count.clamp(1, MAX_RINGS),
            self.sector_count.clamp(1, MAX_SECTORS),
            radius,
        )
    }
}

impl DescriptorExtractor for ScanContextParams {
    type Descriptor = ScanContext;

    fn describe(&self, points_in_keyframe: &[Point2]) -> ScanContext {
        ScanContext::new(points_in_keyframe, self)
    }
}

/// A 2D Scan Context: a `ring × sector` polar occupancy image of a keyframe, its ring key,
/// and its columns normalised for the column-shift distance.
#[derive(Clone, Debug, PartialEq)]
pub struct ScanContext {
    ring_count: usize,
    sector_count: usize,
    /// Mean of each ring (Sec. IV-A).
    ring_key: Vec<f32>,
    /// Column `j` (sector `j`, all rings) scaled to unit length (`ring × sector`); zeros for
    /// an empty column. With `column_norms` it is the whole image: a keyframe's descriptor
    /// is kept for as long as the map, so it holds one copy of it.
    unit_columns: DMatrix<f32>,
    /// The length of each column before scaling (0 for an empty column).
    column_norms: Vec<f32>,
    /// Whether column `j` holds any occupancy.
    column_occupied: Vec<bool>,
}

impl ScanContext {
    /// The descriptor of `points_in_keyframe` (keyframe frame, m). Non-finite points and
    /// points beyond `max_radius_m` are ignored; an empty input gives an empty descriptor.
    pub fn new(points_in_keyframe: &[Point2], params: &ScanContextParams) -> Self {
        let (rings, sectors, radius_m) = params.sanitized();
        let ring_width_m = radius_m / rings as f64;
        let sector_rad = std::f64::consts::TAU / sectors as f64;
        let mut weights = vec![0.0f64; rings * sectors];
        let mut add = |ring: usize, sector: usize, w: f64| {
            if let Some(bin) = weights.get_mut(ring * sectors + sector) {
                *bin += w;
            }
        };
        for p in points_in_keyframe {
            let range_m = p.norm();
            if !(range_m.is_finite() && range_m < radius_m) {
                continue;
            }
            // Angle in [0, 2π), measured from −π so that sector 0 starts behind the robot.
            let angle = (p.y.atan2(p.x) + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU);
            if params.soft_binning {
                // Continuous coordinates relative to bin centres.
                let s = angle / sector_rad - 0.5;
                let r = range_m / ring_width_m - 0.5;
                let s0 = s.floor();
                let r0 = r.floor();
                let (fs, fr) = (s - s0, r - r0);
                let sector_at = |k: f64| (k as i64).rem_euclid(sectors as i64) as usize;
                let ring_at = |k: f64| (k.max(0.0) as usize).min(rings - 1);
                add(ring_at(r0), sector_at(s0), (1.0 - fr) * (1.0 - fs));
                add(ring_at(r0), sector_at(s0 + 1.0), (1.0 - fr) * fs);
                add(ring_at(r0 + 1.0), sector_at(s0), fr * (1.0 - fs));
                add(ring_at(r0 + 1.0), sector_at(s0 + 1.0), fr * fs);
            } else {
                // Kim & Kim, Eq. 1–2: hard polar bins.
                let ring = ((range_m / ring_width_m) as usize).min(rings - 1);
                let sector = ((angle / sector_rad) as usize).min(sectors - 1);
                add(ring, sector, 1.0);
            }
        }
        let bins: Vec<f32> = weights.iter().map(|&w| w.min(1.0) as f32).collect();
        Self::from_bins(rings, sectors, bins)
    }

    /// Fills the derived keys from the bin values.
    fn from_bins(ring_count: usize, sector_count: usize, bins: Vec<f32>) -> Self {
        // Kim & Kim, Sec. IV-A: the ring key is the occupancy ratio of each ring, ψ(r_i) =
        // ‖r_i‖₀ / N_s; with soft values, the mean value of the ring.
        let ring_key = bins
            .chunks(sector_count)
            .map(|ring| ring.iter().sum::<f32>() / sector_count as f32)
            .collect();
        let mut unit_columns = DMatrix::<f32>::zeros(ring_count, sector_count);
        let mut column_norms = vec![0.0f32; sector_count];
        let mut column_occupied = vec![false; sector_count];
        for sector in 0..sector_count {
            let column = (0..ring_count).filter_map(|ring| bins.get(ring * sector_count + sector));
            let norm = column.map(|v| v * v).sum::<f32>().sqrt();
            if norm > 1e-6 {
                if let Some(flag) = column_occupied.get_mut(sector) {
                    *flag = true;
                }
                if let Some(out) = column_norms.get_mut(sector) {
                    *out = norm;
                }
                for ring in 0..ring_count {
                    let value = bins
                        .get(ring * sector_count + sector)
                        .copied()
                        .unwrap_or(0.0);
                    if let Some(out) = unit_columns.get_mut((ring, sector)) {
                        *out = value / norm;
                    }
                }
            }
        }
        Self {
            ring_count,
            sector_count,
            ring_key,
            unit_columns,
            column_norms,
            column_occupied,
        }
    }

    /// Number of rings.
    pub fn ring_count(&self) -> usize {
        self.ring_count
    }

    /// Number of sectors.
    pub fn sector_count(&self) -> usize {
        self.sector_count
    }

    /// Value of bin `(ring, sector)` in `[0, 1]` (0 outside the grid, and in a column whose
    /// values are all below about 1e-6).
    pub fn bin(&self, ring: usize, sector: usize) -> f32 {
        let unit = self.unit_columns.get((ring, sector)).copied();
        let norm = self.column_norms.get(sector).copied();
        unit.zip(norm).map_or(0.0, |(unit, norm)| unit * norm)
    }

    /// The ring key: the mean bin value of each ring, innermost first (rotation invariant).
    pub fn ring_key(&self) -> &[f32] {
        &self.ring_key
    }

    /// True when no point fell inside the grid.
    pub fn is_empty(&self) -> bool {
        !self.column_occupied.iter().any(|&o| o)
    }

    /// Kim & Kim, Eq. 5 at every circular shift: entry `n` is the mean cosine distance
    /// between query column `j` and candidate column `j + n`. Columns empty in both are
    /// skipped; a column empty in only one counts as fully different; a shift with no valid
    /// column gets 1. All `N_s²` column dot products come from one matrix product.
    fn shifted_distances(&self, candidate: &Self) -> Vec<f64> {
        let sectors = self.sector_count;
        // cosines[(j, k)] = q_j · c_k (unit columns).
        let cosines = self.unit_columns.tr_mul(&candidate.unit_columns);
        let cosines = cosines.as_slice();
        let occupied = |flags: &[bool]| flags.iter().filter(|&&f| f).count() as f64;
        let (q_count, c_count) = (
            occupied(&self.column_occupied),
            occupied(&candidate.column_occupied),
        );
        // Σ_j over valid columns of (1 − cos) = (#valid) − Σ_j cos_j,j+n, because the cosine
        // is 0 when either column is empty, and #valid = |q| + |c| − #(both occupied).
        let mut out = Vec::with_capacity(sectors);
        for shift in 0..sectors {
            let mut cosine_sum = 0.0f32;
            let mut both = 0usize;
            for j in 0..sectors {
                let k = if j + shift < sectors {
                    j + shift
                } else {
                    j + shift - sectors
                };
                cosine_sum += cosines.get(j + k * sectors).copied().unwrap_or(0.0);
                let q = self.column_occupied.get(j).copied().unwrap_or(false);
                let c = candidate.column_occupied.get(k).copied().unwrap_or(false);
                both += usize::from(q && c);
            }
            let valid = q_count + c_count - both as f64;
            out.push(if valid > 0.0 {
                ((valid - f64::from(cosine_sum)) / valid).clamp(0.0, 1.0)
            } else {
                1.0
            });
        }
        out
    }
}

impl PlaceDescriptor for ScanContext {
    fn retrieval_key(&self) -> &[f32] {
        &self.ring_key
    }

    /// Kim & Kim, Eq. 6: the minimum of Eq. 5 over all circular sector shifts; the best
    /// shift `n*` gives the yaw `n* · 2π / N_s`, refined by a parabola through the distances
    /// at `n* − 1, n*, n* + 1`. Descriptors of different shapes, or two empty ones, are at
    /// distance 1 with yaw 0.
    fn compare(&self, candidate: &Self) -> DescriptorMatch {
        let unmatched = DescriptorMatch {
            distance: 1.0,
            yaw_rad: 0.0,
        };
        if self.ring_count != candidate.ring_count || self.sector_count != candidate.sector_count {
            return unmatched;
        }
        let sectors = self.sector_count;
        let distances = self.shifted_distances(candidate);
        let Some((best_shift, &best)) = distances
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.total_cmp(b.1))
        else {
            return unmatched;
        };
        if self.is_empty() && candidate.is_empty() {
            return unmatched;
        }
        let before = distances
            .get((best_shift + sectors - 1) % sectors)
            .copied()
            .unwrap_or(best);
        let after = distances
            .get((best_shift + 1) % sectors)
            .copied()
            .unwrap_or(best);
        let curvature = before - 2.0 * best + after;
        let offset = if sectors >= 3 && curvature > 1e-12 {
            (0.5 * (before - after) / curvature).clamp(-0.5, 0.5)
        } else {
            0.0
        };
        let sector_rad = std::f64::consts::TAU / sectors as f64;
        DescriptorMatch {
            distance: best,
            yaw_rad: mapmerge_geometry::wrap_angle_rad((best_shift as f64 + offset) * sector_rad),
        }
    }
}

impl Validate for ScanContextParams {
    fn check(&self, check: &mut Checker) {
        check
            .size("ring_count", self.ring_count, 1, 256)
            .size("sector_count", self.sector_count, 1, MAX_SECTORS as u64)
            .real(
                "max_radius_m",
                self.max_radius_m,
                Real::positive_up_to(1000.0),
            );
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;
    use mapmerge_geometry::{wrap_angle_rad, Se2};
    use proptest::prelude::*;

    /// Hard bins: a point fills its bin with 1, two points in one bin still read 1, and every
    /// other bin reads 0, from the one copy of the image the descriptor keeps.
    #[test]
    fn the_bins_are_the_polar_image() {
        let params = ScanContextParams {
            soft_binning: false,
            ..ScanContextParams::default()
        };
        let (rings, sectors, radius_m) = params.sanitized();
        let ring_width_m = radius_m / rings as f64;
        let sector_rad = std::f64::consts::TAU / sectors as f64;
        // The centre of bin (ring, sector) in the keyframe frame (sector 0 starts behind).
        let at = |ring: usize, sector: usize| {
            let range_m = (ring as f64 + 0.5) * ring_width_m;
            let angle = (sector as f64 + 0.5) * sector_rad - std::f64::consts::PI;
            Point2::new(range_m * angle.cos(), range_m * angle.sin())
        };
        let filled = [(0, 0), (3, 7), (3, 8), (rings - 1, sectors - 1)];
        let mut points: Vec<Point2> = filled.iter().map(|&(r, s)| at(r, s)).collect();
        points.push(at(3, 7) * 1.001);
        let context = ScanContext::new(&points, &params);
        for ring in 0..rings {
            for sector in 0..sectors {
                let expected = if filled.contains(&(ring, sector)) {
                    1.0
                } else {
                    0.0
                };
                assert!(
                    (context.bin(ring, sector) - expected).abs() < 1e-6,
                    "({ring}, {sector})"
                );
            }
        }
        assert_eq!(context.bin(rings, 0), 0.0);
    }

    /// An L-shaped room with a pillar, seen from `(x, y)`: an asymmetric scene.
    fn room_points(x: f64, y: f64) -> Vec<Point2> {
        let mut points = Vec::new();
        let mut wall = |a: Point2, b: Point2| {
            let n = ((b - a).norm() / 0.05).ceil() as usize;
            for i in 0..=n {
                let t = i as f64 / n as f64;
                points.push(a + (b - a) * t - Point2::new(x, y));
            }
        };
        let c = [
            Point2::new(-3.0, -2.0),
            Point2::new(5.0, -2.0),
            Point2::new(5.0, 1.0),
            Point2::new(1.0, 1.0),
            Point2::new(1.0, 4.0),
            Point2::new(-3.0, 4.0),
        ];
        for i in 0..c.len() {
            wall(c[i], c[(i + 1) % c.len()]);
        }
        wall(Point2::new(2.5, -0.5), Point2::new(3.0, -0.5));
        wall(Point2::new(3.0, -0.5), Point2::new(3.0, 0.0));
        points
    }

    fn rotate(points: &[Point2], angle: f64) -> Vec<Point2> {
        let r = Se2::new(0.0, 0.0, angle);
        points.iter().map(|p| r.transform_point(p)).collect()
    }

    #[test]
    fn empty_and_non_finite_inputs_give_empty_descriptors() {
        let params = ScanContextParams::default();
        let empty = ScanContext::new(&[], &params);
        assert!(empty.is_empty());
        let junk = ScanContext::new(
            &[
                Point2::new(f64::NAN, 1.0),
                Point2::new(f64::INFINITY, 0.0),
                Point2::new(1e300, 1e300),
            ],
            &params,
        );
        assert!(junk.is_empty());
        assert!(junk.ring_key().iter().all(|v| *v == 0.0));
        let m = empty.compare(&junk);
        assert_eq!(m.distance, 1.0);
        let full = ScanContext::new(&room_points(0.0, 0.0), &params);
        assert_eq!(full.compare(&empty).distance, 1.0);
        // Degenerate parameters are clamped, not trusted.
        let odd = ScanContextParams {
            ring_count: 0,
            sector_count: 0,
            max_radius_m: f64::NAN,
            soft_binning: true,
        };
        let d = ScanContext::new(&room_points(0.0, 0.0), &odd);
        assert_eq!((d.ring_count(), d.sector_count()), (1, 1));
        assert!(d.compare(&d).distance < 1e-6);
        assert_eq!(d.compare(&full).distance, 1.0);
    }

    #[test]
    fn identical_inputs_are_at_distance_zero() {
        let params = ScanContextParams::default();
        let a = ScanContext::new(&room_points(0.3, 0.2), &params);
        let m = a.compare(&a);
        assert!(m.distance < 1e-6, "{m:?}");
        assert!(m.yaw_rad.abs() < 1e-9);
    }

    #[test]
    fn distance_grows_smoothly() {
        // Shifting the origin by 0.1 m steps raises the distance gradually: no step jumps by
        // more than a small amount, and 0.4 m stays well below an unrelated place.
        let params = ScanContextParams::default();
        let reference = ScanContext::new(&room_points(0.0, 0.0), &params);
        let other_place = ScanContext::new(&rotate(&room_points(-2.0, 3.0), 1.0), &params);
        let unrelated = reference.compare(&other_place).distance;
        let mut previous = 0.0;
        for step in 1..=6 {
            let shift = 0.1 * f64::from(step);
            let d = reference
                .compare(&ScanContext::new(&room_points(shift, 0.5 * shift), &params))
                .distance;
            assert!(d - previous < 0.12, "jump at {shift} m: {previous} → {d}");
            if shift <= 0.41 {
                assert!(
                    d < 0.6 * unrelated,
                    "{shift} m: {d} vs unrelated {unrelated}"
                );
            }
            previous = d.max(previous);
        }
    }

    proptest! {
        #[test]
        fn rotation_invariance(angle in -3.2..3.2f64, x in -0.5..0.5f64, y in -0.5..0.5f64) {
            let params = ScanContextParams::default();
            let points_in_c = room_points(x, y);
            // The query frame is the candidate frame turned by `angle`: p_q = R(−angle) p_c,
            // so candidate_from_query has yaw `angle`.
            let points_in_q = rotate(&points_in_c, -angle);
            let c = ScanContext::new(&points_in_c, &params);
            let q = ScanContext::new(&points_in_q, &params);
            // Ring keys agree up to binning: saturating the splatted weights depends a little
            // on where walls fall relative to sector centres (a few % of the key's norm).
            let norm = |k: &[f32]| k.iter().map(|v| v * v).sum::<f32>().sqrt();
            let difference: Vec<f32> = c.ring_key().iter().zip(q.ring_key()).map(|(a, b)| a - b).collect();
            prop_assert!(norm(&difference) <= 0.1 * norm(c.ring_key()), "{:?} vs {:?}", c.ring_key(), q.ring_key());
            prop_assert!(difference.iter().all(|d| d.abs() < 0.08));
            let m = q.compare(&c);
            prop_assert!(m.distance < 0.08, "distance {}", m.distance);
            let sector = std::f64::consts::TAU / 60.0;
            prop_assert!(wrap_angle_rad(m.yaw_rad - angle).abs() < sector,
                "yaw {} vs {}", m.yaw_rad, angle);
        }

        #[test]
        fn never_panics(points in proptest::collection::vec((-1e3..1e3f64, -1e3..1e3f64), 0..50),
                        rings in 0usize..40, sectors in 0usize..100, radius in -5.0..50.0f64, soft: bool) {
            let params = ScanContextParams { ring_count: rings, sector_count: sectors, max_radius_m: radius, soft_binning: soft };
            let points: Vec<Point2> = points.into_iter().map(|(x, y)| Point2::new(x, y)).collect();
            let d = ScanContext::new(&points, &params);
            let m = d.compare(&d);
            prop_assert!(m.distance.is_finite() && m.yaw_rad.is_finite());
        }
    }
}
