//! SE(2): planar rigid transforms. Tangent order `(v_x, v_y, ω)`.

use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::lie::LieGroup;

/// Below this angle (rad) the series expansions replace the closed forms.
const SMALL_ANGLE_RAD: f64 = 1e-5;

/// A planar pose `a_from_b`: rotation by `theta_rad`, then translation `(x_m, y_m)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Se2 {
    /// Translation x (m).
    pub x_m: f64,
    /// Translation y (m).
    pub y_m: f64,
    /// Heading (rad), kept in (-π, π].
    pub theta_rad: f64,
}

/// Wraps an angle into (-π, π].
pub fn wrap_angle_rad(angle_rad: f64) -> f64 {
    if angle_rad > -core::f64::consts::PI && angle_rad <= core::f64::consts::PI {
        return angle_rad;
    }
    let two_pi = 2.0 * core::f64::consts::PI;
    let wrapped = angle_rad - two_pi * ((angle_rad + core::f64::consts::PI) / two_pi).floor();
    if wrapped <= -core::f64::consts::PI {
        wrapped + two_pi
    } else {
        wrapped
    }
}

/// `(sin θ / θ, (1 - cos θ) / θ)`, with series near zero.
fn sinc_cosc(theta: f64) -> (f64, f64) {
    if theta.abs() < SMALL_ANGLE_RAD {
        let t2 = theta * theta;
        (1.0 - t2 / 6.0, theta / 2.0 - theta * t2 / 24.0)
    } else {
        let (s, c) = theta.sin_cos();
        (s / theta, (1.0 - c) / theta)
    }
}

impl Se2 {
    /// A pose from translation (m) and heading (rad); the heading is wrapped.
    pub fn new(x_m: f64, y_m: f64, theta_rad: f64) -> Self {
        Self { x_m, y_m, theta_rad: wrap_angle_rad(theta_rad) }
    }
    /// Translation as a vector (m).
    pub fn translation(&self) -> Vector2<f64> {
        Vector2::new(self.x_m, self.y_m)
    }
    /// Rotation matrix.
    pub fn rotation_matrix(&self) -> Matrix2<f64> {
        let (s, c) = self.theta_rad.sin_cos();
        Matrix2::new(c, -s, s, c)
    }
    /// Transforms a point: `p_in_a = a_from_b · p_in_b`.
    pub fn transform_point(&self, p_in_b: &Vector2<f64>) -> Vector2<f64> {
        self.rotation_matrix() * p_in_b + self.translation()
    }
    /// The 3x3 homogeneous matrix.
    pub fn to_matrix(&self) -> Matrix3<f64> {
        let (s, c) = self.theta_rad.sin_cos();
        Matrix3::new(c, -s, self.x_m, s, c, self.y_m, 0.0, 0.0, 1.0)
    }
}

impl LieGroup<3> for Se2 {
    fn identity() -> Self {
        Self { x_m: 0.0, y_m: 0.0, theta_rad: 0.0 }
    }

    fn compose(&self, other: &Self) -> Self {
        let (s, c) = self.theta_rad.sin_cos();
        Self {
            x_m: self.x_m + c * other.x_m - s * other.y_m,
            y_m: self.y_m + s * other.x_m + c * other.y_m,
            theta_rad: wrap_angle_rad(self.theta_rad + other.theta_rad),
        }
    }

    fn inverse(&self) -> Self {
        let (s, c) = self.theta_rad.sin_cos();
        Self {
            x_m: -(c * self.x_m + s * self.y_m),
            y_m: -(-s * self.x_m + c * self.y_m),
            theta_rad: wrap_angle_rad(-self.theta_rad),
        }
    }

    fn exp(xi: &Vector3<f64>) -> Self {
        let theta = xi[2];
        let (a, b) = sinc_cosc(theta);
        Self::new(a * xi[0] - b * xi[1], b * xi[0] + a * xi[1], theta)
    }

    fn log(&self) -> Vector3<f64> {
        let theta = self.theta_rad;
        let (a, b) = sinc_cosc(theta);
        let det = a * a + b * b;
        Vector3::new(
            (a * self.x_m + b * self.y_m) / det,
            (-b * self.x_m + a * self.y_m) / det,
            theta,
        )
    }

    fn adjoint(&self) -> Matrix3<f64> {
        let (s, c) = self.theta_rad.sin_cos();
        Matrix3::new(c, -s, self.y_m, s, c, -self.x_m, 0.0, 0.0, 1.0)
    }

    // Solà, Deray, Atchuthan, "A micro Lie theory", eq. (163).
    fn right_jacobian(xi: &Vector3<f64>) -> Matrix3<f64> {
        let (r1, r2, theta) = (xi[0], xi[1], xi[2]);
        if theta.abs() < SMALL_ANGLE_RAD {
            let t2 = theta * theta;
            return Matrix3::new(
                1.0 - t2 / 6.0,
                theta / 2.0,
                -r2 / 2.0 + r1 * theta / 6.0,
                -theta / 2.0,
                1.0 - t2 / 6.0,
                r1 / 2.0 + r2 * theta / 6.0,
                0.0,
                0.0,
                1.0,
            );
        }
        let (s, c) = theta.sin_cos();
        let t2 = theta * theta;
        Matrix3::new(
            s / theta,
            (1.0 - c) / theta,
            (theta * r1 - r2 + r2 * c - r1 * s) / t2,
            (c - 1.0) / theta,
            s / theta,
            (r1 + theta * r2 - r1 * c - r2 * s) / t2,
            0.0,
            0.0,
            1.0,
        )
    }

    fn right_jacobian_inverse(xi: &Vector3<f64>) -> Matrix3<f64> {
        // Block upper-triangular [[A, b], [0, 1]]: inverse is [[A⁻¹, -A⁻¹ b], [0, 1]].
        let jr = Self::right_jacobian(xi);
        let a = jr.fixed_view::<2, 2>(0, 0).into_owned();
        let b = jr.fixed_view::<2, 1>(0, 2).into_owned();
        let det = a[(0, 0)] * a[(1, 1)] - a[(0, 1)] * a[(1, 0)];
        let a_inv = Matrix2::new(a[(1, 1)], -a[(0, 1)], -a[(1, 0)], a[(0, 0)]) / det;
        let top = -a_inv * b;
        Matrix3::new(
            a_inv[(0, 0)],
            a_inv[(0, 1)],
            top[0],
            a_inv[(1, 0)],
            a_inv[(1, 1)],
            top[1],
            0.0,
            0.0,
            1.0,
        )
    }

    fn error_coordinates(&self) -> Vector3<f64> {
        Vector3::new(self.x_m, self.y_m, self.theta_rad)
    }

    fn error_coordinates_jacobian(&self) -> Matrix3<f64> {
        // (x, y, θ) of self · Exp(δ) ≈ (t + R δ_v, θ + δ_ω) to first order.
        let (s, c) = self.theta_rad.sin_cos();
        Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
    }

    fn is_finite(&self) -> bool {
        self.x_m.is_finite() && self.y_m.is_finite() && self.theta_rad.is_finite()
    }
}
