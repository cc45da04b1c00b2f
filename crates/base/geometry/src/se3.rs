//! SE(3): rigid transforms. Tangent order `(ω, v)` (rotation first, as GTSAM).

use nalgebra::{
    Matrix3, Matrix4, Matrix6, Quaternion, Rotation3, UnitQuaternion, Vector3, Vector6,
};
use serde::{Deserialize, Serialize};

use crate::lie::{skew, LieGroup};
use crate::so3::{exp_so3, left_jacobian_inverse_so3, left_jacobian_so3, log_so3};
use crate::trig::{barfoot_q_c2, barfoot_q_c3, t_minus_sin_over_t3};

/// Iteration cap of the SVD that projects a matrix onto SO(3).
const SVD_MAX_ITERATIONS: usize = 100;

/// A rigid transform `a_from_b`: `p_in_a = rotation · p_in_b + translation_m`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Se3 {
    /// Rotation as a unit quaternion.
    pub rotation: UnitQuaternion<f64>,
    /// Translation (m).
    pub translation_m: Vector3<f64>,
}

impl Se3 {
    /// A pose from rotation and translation (m).
    pub fn new(rotation: UnitQuaternion<f64>, translation_m: Vector3<f64>) -> Self {
        Self {
            rotation,
            translation_m,
        }
    }
    /// Rotation matrix.
    pub fn rotation_matrix(&self) -> Matrix3<f64> {
        self.rotation.to_rotation_matrix().into_inner()
    }
    /// Transforms a point: `p_in_a = a_from_b · p_in_b`.
    pub fn transform_point(&self, p_in_b: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p_in_b + self.translation_m
    }
    /// The 4x4 homogeneous matrix.
    pub fn to_matrix(&self) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&self.rotation_matrix());
        m.fixed_view_mut::<3, 1>(0, 3)
            .copy_from(&self.translation_m);
        m
    }
    /// A pose from a rotation matrix (projected onto the nearest rotation) and translation (m).
    ///
    /// Non-finite input gives a non-finite pose (see [`LieGroup::is_finite`]); use
    /// [`Se3::try_from_rotation_matrix`] to get `None` instead.
    pub fn from_rotation_matrix(rotation: &Matrix3<f64>, translation_m: Vector3<f64>) -> Self {
        Self::try_from_rotation_matrix(rotation, translation_m).unwrap_or(Self {
            rotation: UnitQuaternion::new_unchecked(Quaternion::new(f64::NAN, 0.0, 0.0, 0.0)),
            translation_m,
        })
    }

    /// Like [`Se3::from_rotation_matrix`], or `None` when an input is not finite.
    ///
    /// The rotation is the nearest one in Frobenius norm, `U diag(1, 1, det(U Vᵀ)) Vᵀ` from the
    /// SVD `M = U S Vᵀ` (orthogonal Procrustes, Umeyama 1991); a rotation is kept up to rounding.
    pub fn try_from_rotation_matrix(
        rotation: &Matrix3<f64>,
        translation_m: Vector3<f64>,
    ) -> Option<Self> {
        if !rotation
            .iter()
            .chain(translation_m.iter())
            .all(|c| c.is_finite())
        {
            return None;
        }
        let svd = rotation.try_svd(true, true, f64::EPSILON, SVD_MAX_ITERATIONS)?;
        let (u, v_t) = (svd.u?, svd.v_t?);
        let mut s = Matrix3::identity();
        s[(2, 2)] = (u * v_t).determinant().signum();
        let r = Rotation3::from_matrix_unchecked(u * s * v_t);
        Some(Self {
            rotation: UnitQuaternion::from_rotation_matrix(&r),
            translation_m,
        })
    }
}

/// `Q(ω, v)`, the off-diagonal block of the SE(3) left Jacobian (Barfoot, eq. 7.86).
fn left_jacobian_q(omega: &Vector3<f64>, v: &Vector3<f64>) -> Matrix3<f64> {
    let theta = omega.norm();
    let (c1, c2, c3) = (
        t_minus_sin_over_t3(theta),
        barfoot_q_c2(theta),
        barfoot_q_c3(theta),
    );
    let w = skew(omega);
    let p = skew(v);
    let wp = w * p;
    let pw = p * w;
    let wpw = wp * w;
    let ww = w * w;
    p * 0.5
        + (wp + pw + wpw) * c1
        + (ww * p + p * ww - wpw * 3.0) * c2
        + (wpw * w + ww * p * w) * c3
}

/// The SE(3) left Jacobian in `(ω, v)` order: `[[Jl(ω), 0], [Q, Jl(ω)]]`.
fn left_jacobian_se3(xi: &Vector6<f64>) -> Matrix6<f64> {
    let omega = xi.fixed_rows::<3>(0).into_owned();
    let v = xi.fixed_rows::<3>(3).into_owned();
    let jl = left_jacobian_so3(&omega);
    let q = left_jacobian_q(&omega, &v);
    let mut m = Matrix6::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&jl);
    m.fixed_view_mut::<3, 3>(3, 3).copy_from(&jl);
    m.fixed_view_mut::<3, 3>(3, 0).copy_from(&q);
    m
}

/// Inverse of [`left_jacobian_se3`]: `[[Jl⁻¹, 0], [-Jl⁻¹ Q Jl⁻¹, Jl⁻¹]]`.
fn left_jacobian_inverse_se3(xi: &Vector6<f64>) -> Matrix6<f64> {
    let omega = xi.fixed_rows::<3>(0).into_owned();
    let v = xi.fixed_rows::<3>(3).into_owned();
    let jl_inv = left_jacobian_inverse_so3(&omega);
    let q = left_jacobian_q(&omega, &v);
    let mut m = Matrix6::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&jl_inv);
    m.fixed_view_mut::<3, 3>(3, 3).copy_from(&jl_inv);
    m.fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&(-jl_inv * q * jl_inv));
    m
}

impl LieGroup<6> for Se3 {
    fn identity() -> Self {
        Self {
            rotation: UnitQuaternion::identity(),
            translation_m: Vector3::zeros(),
        }
    }

    fn compose(&self, other: &Self) -> Self {
        // Renormalise so long chains of compositions do not drift off the unit sphere.
        let q = self.rotation.quaternion() * other.rotation.quaternion();
        Self {
            rotation: UnitQuaternion::new_normalize(q),
            translation_m: self.rotation * other.translation_m + self.translation_m,
        }
    }

    fn inverse(&self) -> Self {
        let rotation = self.rotation.inverse();
        Self {
            rotation,
            translation_m: -(rotation * self.translation_m),
        }
    }

    // Solà et al., App. D: Exp(ω, v) = (Exp(ω), Jl(ω) v).
    fn exp(xi: &Vector6<f64>) -> Self {
        let omega = xi.fixed_rows::<3>(0).into_owned();
        let v = xi.fixed_rows::<3>(3).into_owned();
        Self {
            rotation: exp_so3(&omega),
            translation_m: left_jacobian_so3(&omega) * v,
        }
    }

    // Solà et al., App. D: v = Jl(ω)⁻¹ t.
    fn log(&self) -> Vector6<f64> {
        let omega = log_so3(&self.rotation);
        let v = left_jacobian_inverse_so3(&omega) * self.translation_m;
        Vector6::new(omega.x, omega.y, omega.z, v.x, v.y, v.z)
    }

    // (ω, v) order: Ad = [[R, 0], [[t]× R, R]] (GTSAM Pose3::AdjointMap).
    fn adjoint(&self) -> Matrix6<f64> {
        let r = self.rotation_matrix();
        let mut m = Matrix6::zeros();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        m.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
        m.fixed_view_mut::<3, 3>(3, 0)
            .copy_from(&(skew(&self.translation_m) * r));
        m
    }

    fn right_jacobian(xi: &Vector6<f64>) -> Matrix6<f64> {
        left_jacobian_se3(&(-xi))
    }

    fn right_jacobian_inverse(xi: &Vector6<f64>) -> Matrix6<f64> {
        left_jacobian_inverse_se3(&(-xi))
    }

    fn left_jacobian(xi: &Vector6<f64>) -> Matrix6<f64> {
        left_jacobian_se3(xi)
    }

    fn left_jacobian_inverse(xi: &Vector6<f64>) -> Matrix6<f64> {
        left_jacobian_inverse_se3(xi)
    }

    fn error_coordinates(&self) -> Vector6<f64> {
        self.log()
    }

    // ∂ Log(x · Exp(δ)) / ∂δ = Jr⁻¹(Log x) (Solà et al., Sec. IV-B).
    fn error_coordinates_jacobian(&self) -> Matrix6<f64> {
        Self::right_jacobian_inverse(&self.log())
    }

    fn is_finite(&self) -> bool {
        self.rotation.coords.iter().all(|c| c.is_finite())
            && self.translation_m.iter().all(|c| c.is_finite())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rotation_angle_between(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> f64 {
        log_so3(&(a.inverse() * b)).norm()
    }

    #[test]
    fn from_rotation_matrix_keeps_a_rotation() {
        let q = UnitQuaternion::from_euler_angles(0.4, -1.1, 2.9);
        let pose = Se3::from_rotation_matrix(&q.to_rotation_matrix().into_inner(), Vector3::x());
        assert!(rotation_angle_between(&pose.rotation, &q) < 1e-14);
    }

    #[test]
    fn from_rotation_matrix_projects_a_noisy_matrix() {
        let q = UnitQuaternion::from_euler_angles(-2.0, 0.3, 1.0);
        let noisy = q.to_rotation_matrix().into_inner()
            + Matrix3::from_fn(|i, j| 1e-3 * (i as f64 - j as f64 * 0.5));
        let pose = Se3::from_rotation_matrix(&noisy, Vector3::zeros());
        assert!((pose.rotation.norm() - 1.0).abs() < 1e-15);
        assert!(rotation_angle_between(&pose.rotation, &q) < 2e-3);
    }

    #[test]
    fn from_rotation_matrix_of_reflection_returns_a_proper_rotation() {
        let reflection = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
        let pose = Se3::from_rotation_matrix(&reflection, Vector3::zeros());
        assert!((pose.rotation_matrix().determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn from_rotation_matrix_of_zeros_gives_a_rotation() {
        let pose = Se3::from_rotation_matrix(&Matrix3::zeros(), Vector3::zeros());
        assert!(pose.is_finite());
        assert!((pose.rotation_matrix().determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn from_rotation_matrix_of_non_finite_input_is_rejected() {
        // The old code used nalgebra's Rotation3::from_matrix, which never returns on NaN.
        let mut m = Matrix3::identity();
        m[(1, 2)] = f64::NAN;
        assert!(Se3::try_from_rotation_matrix(&m, Vector3::zeros()).is_none());
        assert!(!Se3::from_rotation_matrix(&m, Vector3::zeros()).is_finite());
        let t = Vector3::new(f64::INFINITY, 0.0, 0.0);
        assert!(Se3::try_from_rotation_matrix(&Matrix3::identity(), t).is_none());
    }

    #[test]
    fn long_composition_chain_stays_unit_quaternion() {
        let step = Se3::exp(&Vector6::new(0.01, -0.02, 0.013, 0.1, 0.0, 0.05));
        let mut pose = Se3::identity();
        for _ in 0..100_000 {
            pose = pose.compose(&step);
        }
        assert!((pose.rotation.norm() - 1.0).abs() < 1e-14);
    }

    #[test]
    fn non_finite_input_gives_non_finite_output_without_panicking() {
        let xi = Vector6::new(f64::NAN, 0.0, 0.0, 1.0, 0.0, f64::INFINITY);
        assert!(!Se3::exp(&xi).is_finite());
        assert!(Se3::right_jacobian(&xi).iter().any(|v| v.is_nan()));
        assert!(Se3::left_jacobian_inverse(&xi).iter().any(|v| v.is_nan()));
    }
}
