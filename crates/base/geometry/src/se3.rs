//! SE(3): rigid transforms. Tangent order `(ω, v)` (rotation first, as GTSAM).

use nalgebra::{Matrix3, Matrix4, Matrix6, Rotation3, UnitQuaternion, Vector3, Vector6};
use serde::{Deserialize, Serialize};

use crate::lie::{skew, LieGroup};
use crate::so3::{
    exp_so3, left_jacobian_inverse_so3, left_jacobian_so3, log_so3,
};

/// Below this angle (rad) the series expansions replace the closed forms.
const SMALL_ANGLE_RAD: f64 = 1e-4;

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
        Self { rotation, translation_m }
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
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.rotation_matrix());
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation_m);
        m
    }
    /// A pose from a rotation matrix (re-orthonormalised) and translation (m).
    pub fn from_rotation_matrix(rotation: &Matrix3<f64>, translation_m: Vector3<f64>) -> Self {
        let r = Rotation3::from_matrix(rotation);
        Self { rotation: UnitQuaternion::from_rotation_matrix(&r), translation_m }
    }
}

/// `Q(ω, v)`, the off-diagonal block of the SE(3) left Jacobian (Barfoot, eq. 7.86).
fn left_jacobian_q(omega: &Vector3<f64>, v: &Vector3<f64>) -> Matrix3<f64> {
    let theta = omega.norm();
    let t2 = theta * theta;
    let (c1, c2, c3) = if theta < SMALL_ANGLE_RAD {
        (1.0 / 6.0 - t2 / 120.0, 1.0 / 24.0 - t2 / 720.0, 1.0 / 120.0 - t2 / 2520.0)
    } else {
        let (s, c) = theta.sin_cos();
        let t4 = t2 * t2;
        (
            (theta - s) / (t2 * theta),
            (t2 + 2.0 * c - 2.0) / (2.0 * t4),
            (2.0 * theta - 3.0 * s + theta * c) / (2.0 * t4 * theta),
        )
    };
    let w = skew(omega);
    let p = skew(v);
    let wp = w * p;
    let pw = p * w;
    let wpw = wp * w;
    let ww = w * w;
    p * 0.5 + (wp + pw + wpw) * c1 + (ww * p + p * ww - wpw * 3.0) * c2 + (wpw * w + ww * p * w) * c3
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
    m.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-jl_inv * q * jl_inv));
    m
}

impl LieGroup<6> for Se3 {
    fn identity() -> Self {
        Self { rotation: UnitQuaternion::identity(), translation_m: Vector3::zeros() }
    }

    fn compose(&self, other: &Self) -> Self {
        Self {
            rotation: self.rotation * other.rotation,
            translation_m: self.rotation * other.translation_m + self.translation_m,
        }
    }

    fn inverse(&self) -> Self {
        let rotation = self.rotation.inverse();
        Self { rotation, translation_m: -(rotation * self.translation_m) }
    }

    fn exp(xi: &Vector6<f64>) -> Self {
        let omega = xi.fixed_rows::<3>(0).into_owned();
        let v = xi.fixed_rows::<3>(3).into_owned();
        Self { rotation: exp_so3(&omega), translation_m: left_jacobian_so3(&omega) * v }
    }

    fn log(&self) -> Vector6<f64> {
        let omega = log_so3(&self.rotation);
        let v = left_jacobian_inverse_so3(&omega) * self.translation_m;
        Vector6::new(omega.x, omega.y, omega.z, v.x, v.y, v.z)
    }

    fn adjoint(&self) -> Matrix6<f64> {
        let r = self.rotation_matrix();
        let mut m = Matrix6::zeros();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        m.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
        m.fixed_view_mut::<3, 3>(3, 0).copy_from(&(skew(&self.translation_m) * r));
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

    fn error_coordinates_jacobian(&self) -> Matrix6<f64> {
        Self::right_jacobian_inverse(&self.log())
    }

    fn is_finite(&self) -> bool {
        self.rotation.coords.iter().all(|c| c.is_finite())
            && self.translation_m.iter().all(|c| c.is_finite())
    }
}

