//! Absolute trajectory error between two graphs over their common vertex ids, optionally after
//! the best rigid alignment (Horn 1987 / Umeyama 1991 without scale).

use mapmerge_posegraph::PoseGraph;
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use crate::pose::EvalPose;
use crate::EvalError;

/// A rigid transform of points: `p ↦ rotation · p + translation_m`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RigidTransform {
    /// Rotation matrix (a rotation about z for planar data).
    pub rotation: Matrix3<f64>,
    /// Translation, m.
    pub translation_m: Vector3<f64>,
}

impl RigidTransform {
    /// The identity transform.
    pub fn identity() -> Self {
        Self {
            rotation: Matrix3::identity(),
            translation_m: Vector3::zeros(),
        }
    }

    /// `rotation · p + translation_m`.
    pub fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p + self.translation_m
    }
}

/// Translation errors over the vertices two graphs share.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrajectoryError {
    /// Root mean square of the position errors, m.
    pub rms_m: f64,
    /// Largest position error, m.
    pub max_m: f64,
    /// Mean position error, m.
    pub mean_m: f64,
    /// Number of common vertex ids the errors are taken over.
    pub matched: usize,
    /// `reference_from_estimate`, the transform applied to the estimate before measuring
    /// (the identity without alignment).
    pub alignment: RigidTransform,
}

/// The rigid transform `T` minimising `Σ |reference_i − T(estimate_i)|²` (no scale).
///
/// Planar data (`planar = true`, z ignored) gets the closed form
/// `θ = atan2(Σ (e_i × r_i)_z, Σ e_i · r_i)` over centred points; 3D data gets Umeyama's SVD
/// solution with the reflection fix (Umeyama 1991, Eq. 39–42). Fails if the slices are empty or
/// differ in length. If the SVD does not converge, only the centroids are aligned.
pub fn align_rigid(
    reference: &[Vector3<f64>],
    estimate: &[Vector3<f64>],
    planar: bool,
) -> Result<RigidTransform, EvalError> {
    if reference.len() != estimate.len() {
        return Err(EvalError::InvalidParams {
            field: "estimate",
            reason: format!(
                "{} points vs {} reference points",
                estimate.len(),
                reference.len()
            ),
        });
    }
    if reference.is_empty() {
        return Err(EvalError::NoCommonVertices);
    }
    let n = reference.len() as f64;
    let mut r_mean = reference.iter().sum::<Vector3<f64>>() / n;
    let mut e_mean = estimate.iter().sum::<Vector3<f64>>() / n;
    let rotation = if planar {
        r_mean.z = 0.0;
        e_mean.z = 0.0;
        let (mut cross, mut dot) = (0.0, 0.0);
        for (r, e) in reference.iter().zip(estimate) {
            let (rx, ry) = (r.x - r_mean.x, r.y - r_mean.y);
            let (ex, ey) = (e.x - e_mean.x, e.y - e_mean.y);
            cross += ex * ry - ey * rx;
            dot += ex * rx + ey * ry;
        }
        let theta = cross.atan2(dot);
        let (s, c) = theta.sin_cos();
        Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
    } else {
        // Cross-covariance Σ (r − r̄)(e − ē)ᵀ; R = U S Vᵀ with S = diag(1, 1, det(U)·det(V)).
        let mut h = Matrix3::zeros();
        for (r, e) in reference.iter().zip(estimate) {
            h += (r - r_mean) * (e - e_mean).transpose();
        }
        match h.try_svd(true, true, f64::EPSILON, 0) {
            Some(svd) => match (svd.u, svd.v_t) {
                (Some(u), Some(v_t)) => {
                    let d = if (u * v_t).determinant() < 0.0 {
                        -1.0
                    } else {
                        1.0
                    };
                    u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * v_t
                }
                _ => Matrix3::identity(),
            },
            None => Matrix3::identity(),
        }
    };
    let translation_m = r_mean - rotation * e_mean;
    Ok(RigidTransform {
        rotation,
        translation_m,
    })
}

/// Position errors of `estimate` against `reference` over the vertex ids both contain,
/// after the best rigid alignment of the estimate onto the reference when `align` is set
/// ([`align_rigid`]). Fails if the graphs share no vertex id.
pub fn trajectory_error<G, const D: usize>(
    reference: &PoseGraph<G, D>,
    estimate: &PoseGraph<G, D>,
    align: bool,
) -> Result<TrajectoryError, EvalError>
where
    G: EvalPose<D>,
{
    let (mut p_ref, mut p_est) = (Vec::new(), Vec::new());
    for (id, v) in reference.vertices() {
        if let Some(w) = estimate.vertex(id) {
            p_ref.push(v.pose.position_m());
            p_est.push(w.pose.position_m());
        }
    }
    position_errors(&p_ref, &p_est, G::PLANAR, align)
}

/// Position errors of `estimate` against `reference` (paired by position in the slices), after
/// the best rigid alignment ([`align_rigid`]) when `align` is set. Shared by
/// [`trajectory_error`] (graphs) and `absolute_trajectory_error` (scan-indexed trajectories).
pub(crate) fn position_errors(
    p_ref: &[Vector3<f64>],
    p_est: &[Vector3<f64>],
    planar: bool,
    align: bool,
) -> Result<TrajectoryError, EvalError> {
    if p_ref.is_empty() {
        return Err(EvalError::NoCommonVertices);
    }
    let alignment = if align {
        align_rigid(p_ref, p_est, planar)?
    } else {
        RigidTransform::identity()
    };
    let (mut sum, mut sum_sq, mut max) = (0.0f64, 0.0f64, 0.0f64);
    for (r, e) in p_ref.iter().zip(p_est) {
        let err = (r - alignment.apply(e)).norm();
        sum += err;
        sum_sq += err * err;
        max = max.max(err);
    }
    let n = p_ref.len() as f64;
    Ok(TrajectoryError {
        rms_m: (sum_sq / n).sqrt(),
        max_m: max,
        mean_m: sum / n,
        matched: p_ref.len(),
        alignment,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;
    use mapmerge_geometry::{LieGroup, Se2, Se3};
    use mapmerge_posegraph::{NodeId, PoseGraph2, PoseGraph3, Vertex};
    use nalgebra::UnitQuaternion;
    use proptest::prelude::*;

    fn planar_graph(poses: &[(u64, Se2)]) -> PoseGraph2 {
        let mut g = PoseGraph2::new();
        for (id, p) in poses {
            g.add_vertex(NodeId(*id), Vertex::new(*p)).unwrap();
        }
        g
    }

    fn wiggly(n: u64) -> Vec<(u64, Se2)> {
        (0..n)
            .map(|i| {
                let t = i as f64 * 0.3;
                (i, Se2::new(3.0 * t.cos() + t, 2.0 * (1.7 * t).sin(), t))
            })
            .collect()
    }

    #[test]
    fn identical_graphs_have_zero_error() {
        let g = planar_graph(&wiggly(30));
        for align in [false, true] {
            let e = trajectory_error(&g, &g, align).unwrap();
            assert_eq!(e.matched, 30);
            assert!(e.rms_m < 1e-12 && e.max_m < 1e-12 && e.mean_m < 1e-12);
        }
    }

    #[test]
    fn planar_alignment_recovers_a_known_transform() {
        let reference = wiggly(50);
        let moved = Se2::new(-4.0, 7.5, 2.4);
        let estimate: Vec<(u64, Se2)> = reference
            .iter()
            .map(|(i, p)| (*i, moved.compose(p)))
            .collect();
        let (r, e) = (planar_graph(&reference), planar_graph(&estimate));
        let unaligned = trajectory_error(&r, &e, false).unwrap();
        assert!(unaligned.rms_m > 1.0);
        let aligned = trajectory_error(&r, &e, true).unwrap();
        assert!(aligned.rms_m < 1e-9, "{aligned:?}");
        // The alignment is the inverse of the applied motion.
        let inv = moved.inverse();
        assert!((aligned.alignment.translation_m.x - inv.x_m).abs() < 1e-9);
        assert!((aligned.alignment.translation_m.y - inv.y_m).abs() < 1e-9);
        let angle = aligned.alignment.rotation[(1, 0)].atan2(aligned.alignment.rotation[(0, 0)]);
        assert!((angle - inv.theta_rad).abs() < 1e-9);
    }

    #[test]
    fn only_common_ids_count() {
        let r = planar_graph(&[(0, Se2::new(0.0, 0.0, 0.0)), (1, Se2::new(1.0, 0.0, 0.0))]);
        let e = planar_graph(&[(1, Se2::new(1.0, 3.0, 0.0)), (2, Se2::new(9.0, 9.0, 0.0))]);
        let err = trajectory_error(&r, &e, false).unwrap();
        assert_eq!(err.matched, 1);
        assert!((err.rms_m - 3.0).abs() < 1e-12 && (err.max_m - 3.0).abs() < 1e-12);
        let none = planar_graph(&[(7, Se2::identity())]);
        assert_eq!(
            trajectory_error(&r, &none, true),
            Err(EvalError::NoCommonVertices)
        );
    }

    #[test]
    fn error_statistics() {
        let r = planar_graph(&[(0, Se2::identity()), (1, Se2::identity())]);
        let e = planar_graph(&[(0, Se2::new(3.0, 0.0, 0.0)), (1, Se2::new(0.0, 4.0, 0.0))]);
        let err = trajectory_error(&r, &e, false).unwrap();
        assert!((err.mean_m - 3.5).abs() < 1e-12);
        assert!((err.max_m - 4.0).abs() < 1e-12);
        assert!((err.rms_m - 12.5f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn length_mismatch_is_an_error() {
        let a = [Vector3::zeros(); 2];
        let b = [Vector3::zeros(); 3];
        assert!(align_rigid(&a, &b, false).is_err());
        assert_eq!(
            align_rigid(&[], &[], true),
            Err(EvalError::NoCommonVertices)
        );
    }

    proptest! {
        #[test]
        fn spatial_alignment_recovers_a_known_transform(
            axis in prop::array::uniform3(-1.0f64..1.0),
            angle in -3.1f64..3.1,
            shift in prop::array::uniform3(-50.0f64..50.0),
            seed_points in prop::collection::vec(prop::array::uniform3(-20.0f64..20.0), 4..40),
        ) {
            let axis = Vector3::from(axis);
            prop_assume!(axis.norm() > 0.1);
            let q = UnitQuaternion::from_scaled_axis(axis.normalize() * angle);
            let moved = Se3::new(q, Vector3::from(shift));
            let mut r = PoseGraph3::new();
            let mut e = PoseGraph3::new();
            for (i, p) in seed_points.iter().enumerate() {
                let pose = Se3::new(UnitQuaternion::identity(), Vector3::from(*p));
                r.add_vertex(NodeId(i as u64), Vertex::new(pose)).unwrap();
                e.add_vertex(NodeId(i as u64), Vertex::new(moved.compose(&pose))).unwrap();
            }
            // Points in general position (not all nearly collinear).
            let pts: Vec<Vector3<f64>> = seed_points.iter().map(|p| Vector3::from(*p)).collect();
            let c = pts.iter().sum::<Vector3<f64>>() / pts.len() as f64;
            let cov = pts.iter().fold(Matrix3::zeros(), |m, p| m + (p - c) * (p - c).transpose());
            let eig = cov.symmetric_eigenvalues();
            prop_assume!(eig.iter().copied().fold(f64::INFINITY, f64::min) > 1.0);
            let err = trajectory_error(&r, &e, true).unwrap();
            prop_assert!(err.rms_m < 1e-8, "{:?}", err);
            let expected = moved.inverse().rotation_matrix();
            prop_assert!((err.alignment.rotation - expected).norm() < 1e-8);
            prop_assert!((err.alignment.rotation.determinant() - 1.0).abs() < 1e-9);
        }

        #[test]
        fn planar_alignment_never_increases_error(
            dx in -10.0f64..10.0, dy in -10.0f64..10.0, dth in -3.1f64..3.1,
            noise in prop::collection::vec(prop::array::uniform2(-0.5f64..0.5), 20),
        ) {
            let reference = wiggly(20);
            let moved = Se2::new(dx, dy, dth);
            let estimate: Vec<(u64, Se2)> = reference.iter().zip(&noise).map(|((i, p), n)| {
                let q = moved.compose(p);
                (*i, Se2::new(q.x_m + n[0], q.y_m + n[1], q.theta_rad))
            }).collect();
            let (r, e) = (planar_graph(&reference), planar_graph(&estimate));
            let aligned = trajectory_error(&r, &e, true).unwrap();
            let unaligned = trajectory_error(&r, &e, false).unwrap();
            prop_assert!(aligned.rms_m <= unaligned.rms_m + 1e-12);
            // The noise bounds the aligned error (|n| ≤ 0.5·√2 per point).
            prop_assert!(aligned.rms_m <= 0.5 * 2f64.sqrt() + 1e-9);
            prop_assert!((aligned.alignment.rotation.determinant() - 1.0).abs() < 1e-12);
        }
    }
}
