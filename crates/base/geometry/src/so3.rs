//! SO(3) helpers on unit quaternions and rotation vectors.

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

use crate::lie::skew;

/// Below this angle (rad) the series expansions replace the closed forms.
const SMALL_ANGLE_RAD: f64 = 1e-5;

/// `Exp(ω)` as a unit quaternion.
pub fn exp_so3(omega: &Vector3<f64>) -> UnitQuaternion<f64> {
    let theta2 = omega.norm_squared();
    let theta = theta2.sqrt();
    let (w, k) = if theta < SMALL_ANGLE_RAD {
        (1.0 - theta2 / 8.0, 0.5 - theta2 / 48.0)
    } else {
        let half = 0.5 * theta;
        (half.cos(), half.sin() / theta)
    };
    UnitQuaternion::new_normalize(Quaternion::new(w, k * omega.x, k * omega.y, k * omega.z))
}

/// `Log(q)`: the rotation vector with angle in [0, π].
pub fn log_so3(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let (mut w, mut v) = (q.w, q.imag());
    if w < 0.0 {
        w = -w;
        v = -v;
    }
    let n = v.norm();
    if n < SMALL_ANGLE_RAD {
        // θ = 2 atan(n / w) ≈ 2 n / w (1 - n² / (3 w²))
        return v * (2.0 / w * (1.0 - n * n / (3.0 * w * w)));
    }
    let theta = 2.0 * n.atan2(w);
    v * (theta / n)
}

/// Coefficients `(a, b)` with `Jr(ω) = I - a [ω]× + b [ω]×²`.
fn right_jacobian_coefficients(theta: f64) -> (f64, f64) {
    if theta < SMALL_ANGLE_RAD {
        let t2 = theta * theta;
        (0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0)
    } else {
        let t2 = theta * theta;
        ((1.0 - theta.cos()) / t2, (theta - theta.sin()) / (t2 * theta))
    }
}

/// Right Jacobian of SO(3).
pub fn right_jacobian_so3(omega: &Vector3<f64>) -> Matrix3<f64> {
    let (a, b) = right_jacobian_coefficients(omega.norm());
    let w = skew(omega);
    Matrix3::identity() - w * a + w * w * b
}

/// Inverse right Jacobian of SO(3): `I + ½[ω]× + (1/θ² - (1 + cos θ)/(2 θ sin θ)) [ω]×²`.
pub fn right_jacobian_inverse_so3(omega: &Vector3<f64>) -> Matrix3<f64> {
    let theta = omega.norm();
    let c = if theta < SMALL_ANGLE_RAD {
        1.0 / 12.0 + theta * theta / 720.0
    } else {
        1.0 / (theta * theta) - (1.0 + theta.cos()) / (2.0 * theta * theta.sin())
    };
    let w = skew(omega);
    Matrix3::identity() + w * 0.5 + w * w * c
}

/// Left Jacobian of SO(3), `Jl(ω) = Jr(-ω)`.
pub fn left_jacobian_so3(omega: &Vector3<f64>) -> Matrix3<f64> {
    right_jacobian_so3(&(-omega))
}

/// Inverse left Jacobian of SO(3).
pub fn left_jacobian_inverse_so3(omega: &Vector3<f64>) -> Matrix3<f64> {
    right_jacobian_inverse_so3(&(-omega))
}
