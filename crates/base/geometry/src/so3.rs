//! SO(3) helpers on unit quaternions and rotation vectors.
//!
//! Formulas: Solà, Deray, Atchuthan, "A micro Lie theory for state estimation in robotics"
//! (2018), Sec. IV-B and App. B; Barfoot, "State Estimation for Robotics" (2017), Sec. 7.1.

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

use crate::lie::skew;
use crate::trig::{inverse_jacobian_coefficient, one_minus_cos_over_t2, sinc, t_minus_sin_over_t3};

/// Below this `|q.imag()| = sin(θ/2)` the logarithm uses its series.
const SMALL_SIN_HALF_ANGLE: f64 = 1e-5;

/// `Exp(ω)` as a unit quaternion: `(cos(θ/2), sin(θ/2) ω/θ)` (Solà et al., App. B).
pub fn exp_so3(omega: &Vector3<f64>) -> UnitQuaternion<f64> {
    let half = 0.5 * omega.norm();
    // sin(θ/2)/θ = ½ sinc(θ/2), accurate at every angle.
    let k = 0.5 * sinc(half);
    UnitQuaternion::new_normalize(Quaternion::new(
        half.cos(),
        k * omega.x,
        k * omega.y,
        k * omega.z,
    ))
}

/// `Log(q)`: the rotation vector with angle in [0, π] (Solà et al., App. B).
///
/// Works for quaternions that drifted from unit norm: only ratios of components are used.
pub fn log_so3(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let (mut w, mut v) = (q.w, q.imag());
    // q and -q are the same rotation; w ≥ 0 picks the angle in [0, π].
    if w < 0.0 {
        w = -w;
        v = -v;
    }
    let n = v.norm();
    if n < SMALL_SIN_HALF_ANGLE {
        // θ = 2 atan(n / w) ≈ 2 n / w (1 - n² / (3 w²)); the next term is O(n⁴).
        return v * (2.0 / w * (1.0 - n * n / (3.0 * w * w)));
    }
    // atan2 stays accurate near π, where w → 0.
    let theta = 2.0 * n.atan2(w);
    v * (theta / n)
}

/// Right Jacobian of SO(3): `Jr(ω) = I - (1 - cos θ)/θ² [ω]× + (θ - sin θ)/θ³ [ω]×²`
/// (Solà et al., App. B; Barfoot, Sec. 7.1.5 with ω → -ω).
pub fn right_jacobian_so3(omega: &Vector3<f64>) -> Matrix3<f64> {
    let theta = omega.norm();
    let w = skew(omega);
    Matrix3::identity() - w * one_minus_cos_over_t2(theta) + w * w * t_minus_sin_over_t3(theta)
}

/// Inverse right Jacobian of SO(3):
/// `Jr⁻¹(ω) = I + ½[ω]× + (1/θ² - (1 + cos θ)/(2 θ sin θ)) [ω]×²` (Solà et al., App. B).
///
/// Singular at θ = 2π; finite (and accurate) on the whole range θ ≤ π of [`log_so3`].
pub fn right_jacobian_inverse_so3(omega: &Vector3<f64>) -> Matrix3<f64> {
    let theta = omega.norm();
    let w = skew(omega);
    Matrix3::identity() + w * 0.5 + w * w * inverse_jacobian_coefficient(theta)
}

/// Left Jacobian of SO(3), `Jl(ω) = Jr(-ω)`; also the `V` matrix of the SE(3) exponential.
pub fn left_jacobian_so3(omega: &Vector3<f64>) -> Matrix3<f64> {
    right_jacobian_so3(&(-omega))
}

/// Inverse left Jacobian of SO(3), `Jl⁻¹(ω) = Jr⁻¹(-ω)`.
pub fn left_jacobian_inverse_so3(omega: &Vector3<f64>) -> Matrix3<f64> {
    right_jacobian_inverse_so3(&(-omega))
}
