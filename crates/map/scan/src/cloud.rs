//! Operations on planar point sets: transform, voxel downsampling, normals.

use std::collections::HashMap;

use mapmerge_geometry::Se2;
use nalgebra::{Matrix2, SymmetricEigen};

use crate::scan::transform_in_place;
use crate::Point2;

/// `a_from_b · p` for every `p` of `points_in_b`.
pub fn transform_points(a_from_b: &Se2, points_in_b: &[Point2]) -> Vec<Point2> {
    let mut out = points_in_b.to_vec();
    transform_in_place(a_from_b, &mut out);
    out
}

/// Integer voxel coordinates of `p` for cells of `cell_m`.
fn voxel_of(p: &Point2, cell_m: f64) -> (i64, i64) {
    // `as` saturates for huge or non-finite values, which only merges far-away points.
    ((p.x / cell_m).floor() as i64, (p.y / cell_m).floor() as i64)
}

/// One point per occupied `cell_m` voxel: the centroid of the points that fell into it.
/// Voxels appear in the order of their first point, so a scan stays in beam order.
/// A non-positive or non-finite `cell_m` returns the points unchanged.
pub fn voxel_downsample(points: &[Point2], cell_m: f64) -> Vec<Point2> {
    if !(cell_m.is_finite() && cell_m > 0.0) {
        return points.to_vec();
    }
    let mut slot_of_voxel: HashMap<(i64, i64), usize> = HashMap::with_capacity(points.len());
    let mut sums: Vec<(Point2, u32)> = Vec::new();
    for p in points {
        let slot = *slot_of_voxel.entry(voxel_of(p, cell_m)).or_insert_with(|| {
            sums.push((Point2::zeros(), 0));
            sums.len() - 1
        });
        if let Some((sum, count)) = sums.get_mut(slot) {
            *sum += p;
            *count += 1;
        }
    }
    sums.into_iter()
        .map(|(sum, count)| sum / f64::from(count.max(1)))
        .collect()
}

/// A point with its unit surface normal and how line-like its neighbourhood is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointNormal {
    /// The point.
    pub point: Point2,
    /// Unit normal (sign: pointing towards `viewpoint` given to [`estimate_normals`]).
    pub normal: Point2,
    /// `1 − λ_min / λ_max` of the neighbourhood covariance: 1 on a perfect line, 0 on an
    /// isotropic blob.
    pub planarity: f64,
}

/// Normals by principal component analysis of the neighbours within `radius_m` (the
/// eigenvector of the smallest eigenvalue of their covariance), oriented towards
/// `viewpoint` (the sensor origin in the points' frame). Points with fewer than
/// `min_neighbours` neighbours (themselves included) get no normal and are left out.
pub fn estimate_normals(
    points: &[Point2],
    radius_m: f64,
    min_neighbours: usize,
    viewpoint: &Point2,
) -> Vec<PointNormal> {
    if !(radius_m.is_finite() && radius_m > 0.0) {
        return Vec::new();
    }
    // Bucket the points in cells of `radius_m`; neighbours are in the 3×3 block around a cell.
    let mut buckets: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    for (index, p) in points.iter().enumerate() {
        buckets
            .entry(voxel_of(p, radius_m))
            .or_default()
            .push(index);
    }
    let radius_squared = radius_m * radius_m;
    let mut out = Vec::with_capacity(points.len());
    for p in points {
        let (cx, cy) = voxel_of(p, radius_m);
        let mut count = 0usize;
        let mut sum = Point2::zeros();
        let mut sum_outer = Matrix2::zeros();
        for dx in -1..=1 {
            for dy in -1..=1 {
                let Some(bucket) = buckets.get(&(cx.saturating_add(dx), cy.saturating_add(dy)))
                else {
                    continue;
                };
                for q in bucket.iter().filter_map(|&i| points.get(i)) {
                    if (q - p).norm_squared() <= radius_squared {
                        count += 1;
                        sum += q;
                        sum_outer += q * q.transpose();
                    }
                }
            }
        }
        if count < min_neighbours.max(2) {
            continue;
        }
        out.extend(normal_from_moments(p, count, &sum, &sum_outer, viewpoint));
    }
    out
}

/// The PCA normal of a neighbourhood of `p` given by its point count, sum and sum of outer
/// products, oriented towards `viewpoint`.
fn normal_from_moments(
    p: &Point2,
    count: usize,
    sum: &Point2,
    sum_outer: &Matrix2<f64>,
    viewpoint: &Point2,
) -> Option<PointNormal> {
    let n = count as f64;
    let mean = sum / n;
    let covariance = sum_outer / n - mean * mean.transpose();
    let eigen = SymmetricEigen::new(covariance);
    let (small, large) = if eigen.eigenvalues[0] <= eigen.eigenvalues[1] {
        (0, 1)
    } else {
        (1, 0)
    };
    let mut normal: Point2 = eigen.eigenvectors.column(small).into_owned();
    if !(normal.x.is_finite() && normal.y.is_finite()) {
        return None;
    }
    if normal.dot(&(viewpoint - p)) < 0.0 {
        normal = -normal;
    }
    let largest = eigen.eigenvalues[large].max(f64::MIN_POSITIVE);
    Some(PointNormal {
        point: *p,
        normal,
        planarity: (1.0 - eigen.eigenvalues[small].max(0.0) / largest).clamp(0.0, 1.0),
    })
}

/// Normals of a scan's points in beam order, from the PCA of each point and its neighbours
/// up to `half_window` positions before and after it that lie within
/// `max(min_gap_m, gap_per_range · range)` of it (range from `viewpoint`): beams fan out with
/// range, so the neighbourhood does too, and a jump to another surface breaks it. Points with
/// fewer than 3 such neighbours (themselves included) are left out.
pub fn scan_normals(
    points_in_beam_order: &[Point2],
    half_window: usize,
    min_gap_m: f64,
    gap_per_range: f64,
    viewpoint: &Point2,
) -> Vec<PointNormal> {
    let mut out = Vec::with_capacity(points_in_beam_order.len());
    for (k, p) in points_in_beam_order.iter().enumerate() {
        if !(p.x.is_finite() && p.y.is_finite()) {
            continue;
        }
        let gap = min_gap_m.max(gap_per_range * (p - viewpoint).norm());
        let gap_squared = gap * gap;
        let first = k.saturating_sub(half_window);
        let last = (k + half_window + 1).min(points_in_beam_order.len());
        let mut count = 0usize;
        let mut sum = Point2::zeros();
        let mut sum_outer = Matrix2::zeros();
        for q in points_in_beam_order.get(first..last).unwrap_or_default() {
            if (q - p).norm_squared() <= gap_squared {
                count += 1;
                sum += q;
                sum_outer += q * q.transpose();
            }
        }
        if count >= 3 {
            out.extend(normal_from_moments(p, count, &sum, &sum_outer, viewpoint));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn scan_normals_follow_walls_and_stop_at_jumps() {
        // A wall at x = 2 seen by beams from the origin, then a jump to a wall at x = 6.
        let mut points: Vec<Point2> = (-10..=10)
            .map(|k| Point2::new(2.0, 0.1 * f64::from(k)))
            .collect();
        points.extend((0..10).map(|k| Point2::new(6.0, 1.5 + 0.3 * f64::from(k))));
        let normals = scan_normals(&points, 3, 0.2, 0.06, &Point2::zeros());
        let near: Vec<&PointNormal> = normals.iter().filter(|n| n.point.x < 3.0).collect();
        assert_eq!(near.len(), 21, "every point of the near wall has a normal");
        for n in &near {
            assert!(
                (n.normal.x + 1.0).abs() < 1e-9,
                "towards the viewpoint: {n:?}"
            );
            assert!(n.planarity > 0.99);
        }
        // The far wall's points are 0.3 m apart, within 6 % of their ~6.5 m range.
        assert!(normals.iter().filter(|n| n.point.x > 3.0).count() >= 8);
        // Across the jump no neighbourhood mixes the walls: normals stay axis-aligned.
        assert!(normals.iter().all(|n| n.normal.y.abs() < 1e-6));
        assert!(scan_normals(&points[..2], 3, 0.2, 0.06, &Point2::zeros()).is_empty());
    }

    #[test]
    fn voxel_centroids() {
        let points = [
            Point2::new(0.01, 0.01),
            Point2::new(0.03, 0.05),
            Point2::new(0.51, 0.0),
        ];
        let down = voxel_downsample(&points, 0.1);
        assert_eq!(down.len(), 2);
        assert!((down[0] - Point2::new(0.02, 0.03)).norm() < 1e-12);
        assert_eq!(down[1], points[2]);
        assert_eq!(voxel_downsample(&points, 0.0), points.to_vec());
    }

    #[test]
    fn normals_of_a_wall_point_to_the_sensor() {
        // A wall along y = 2 seen from the origin.
        let wall: Vec<Point2> = (0..50)
            .map(|i| Point2::new(-1.0 + 0.04 * f64::from(i), 2.0))
            .collect();
        let normals = estimate_normals(&wall, 0.2, 3, &Point2::zeros());
        assert_eq!(normals.len(), wall.len());
        for n in &normals {
            assert!(
                (n.normal - Point2::new(0.0, -1.0)).norm() < 1e-9,
                "{:?}",
                n.normal
            );
            assert!(n.planarity > 0.999);
        }
    }

    proptest! {
        #[test]
        fn transform_then_inverse_is_identity(x in -50.0..50.0f64, y in -50.0..50.0f64, t in -4.0..4.0f64,
                                             px in -20.0..20.0f64, py in -20.0..20.0f64) {
            let pose = Se2::new(x, y, t);
            let p = [Point2::new(px, py)];
            let back = transform_points(&mapmerge_geometry::LieGroup::inverse(&pose), &transform_points(&pose, &p));
            prop_assert!((back[0] - p[0]).norm() < 1e-9);
        }

        #[test]
        fn downsampling_keeps_one_point_per_voxel(points in proptest::collection::vec((-5.0..5.0f64, -5.0..5.0f64), 0..200), cell in 0.05..2.0f64) {
            let points: Vec<Point2> = points.into_iter().map(|(x, y)| Point2::new(x, y)).collect();
            let down = voxel_downsample(&points, cell);
            let voxels: std::collections::HashSet<_> = points.iter().map(|p| voxel_of(p, cell)).collect();
            prop_assert_eq!(down.len(), voxels.len());
            // Each centroid lies in the (closed) voxel of its points.
            for c in &down {
                let (vx, vy) = voxel_of(c, cell);
                prop_assert!(voxels.contains(&(vx, vy)) || voxels.iter().any(|&(x, y)| (x - vx).abs() <= 1 && (y - vy).abs() <= 1));
            }
        }
    }
}
