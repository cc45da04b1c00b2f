//! SE(2): planar rigid transforms. Tangent order `(v_x, v_y, ω)`.

use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::lie::LieGroup;
use crate::trig::{half_cot_half, one_minus_cos_over_t2, sinc, t_minus_sin_over_t3};

/// A planar pose `a_from_b`: rotation by `theta_rad`, then translation `(x_m, y_m)`.
///
/// Struct literals and deserialisation may leave `theta_rad` unwrapped; every operation wraps.
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
    use core::f64::consts::PI;
    if angle_rad > -PI && angle_rad <= PI {
        return angle_rad;
    }
    // `%` (fmod) is exact, so even huge angles land in (-2π, 2π) without cancellation; one
    // correcting step (also exact here) brings them into (-π, π].
    let two_pi = 2.0 * PI;
    let rem = angle_rad % two_pi;
    if rem > PI {
        rem - two_pi
    } else if rem <= -PI {
        rem + two_pi
    } else {
        rem
    }
}

impl Se2 {
    /// A pose from translation (m) and heading (rad); the heading is wrapped.
    pub fn new(x_m: f64, y_m: f64, theta_rad: f64) -> Self {
        Self {
            x_m,
            y_m,
            theta_rad: wrap_angle_rad(theta_rad),
        }
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
        Self {
            x_m: 0.0,
            y_m: 0.0,
            theta_rad: 0.0,
        }
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

    // Solà et al., eq. 156: t = V(θ) v with V = [[sin θ/θ, -(1-cos θ)/θ], [(1-cos θ)/θ, sin θ/θ]].
    fn exp(xi: &Vector3<f64>) -> Self {
        let theta = xi[2];
        let (a, b) = (sinc(theta), theta * one_minus_cos_over_t2(theta));
        Self::new(a * xi[0] - b * xi[1], b * xi[0] + a * xi[1], theta)
    }

    // Solà et al., App. C (inverse of eq. 156): v = V(θ)⁻¹ t,
    // V⁻¹ = [[h, θ/2], [-θ/2, h]] with h = (θ/2) cot(θ/2), finite up to |θ| = π.
    fn log(&self) -> Vector3<f64> {
        let theta = wrap_angle_rad(self.theta_rad);
        let (h, half) = (half_cot_half(theta), 0.5 * theta);
        Vector3::new(
            h * self.x_m + half * self.y_m,
            -half * self.x_m + h * self.y_m,
            theta,
        )
    }

    // Solà et al., App. C: Ad = [[R, [y, -x]ᵀ], [0, 1]] (GTSAM Pose2::AdjointMap).
    fn adjoint(&self) -> Matrix3<f64> {
        let (s, c) = self.theta_rad.sin_cos();
        Matrix3::new(c, -s, self.y_m, s, c, -self.x_m, 0.0, 0.0, 1.0)
    }

    // Solà et al., eq. 163, written with cancellation-free coefficients:
    // Jr = [[sin θ/θ, (1-cos θ)/θ, ρ1 (θ-sin θ)/θ² - ρ2 (1-cos θ)/θ²],
    //       [-(1-cos θ)/θ, sin θ/θ, ρ1 (1-cos θ)/θ² + ρ2 (θ-sin θ)/θ²], [0, 0, 1]].
    fn right_jacobian(xi: &Vector3<f64>) -> Matrix3<f64> {
        let (r1, r2, theta) = (xi[0], xi[1], xi[2]);
        let a = sinc(theta);
        let c = one_minus_cos_over_t2(theta);
        let b = theta * c;
        let d = theta * t_minus_sin_over_t3(theta);
        Matrix3::new(a, b, r1 * d - r2 * c, -b, a, r1 * c + r2 * d, 0.0, 0.0, 1.0)
    }

    // Jr = [[A, u], [0, 1]] ⇒ Jr⁻¹ = [[A⁻¹, -A⁻¹ u], [0, 1]], with A⁻¹ = [[h, -θ/2], [θ/2, h]].
    fn right_jacobian_inverse(xi: &Vector3<f64>) -> Matrix3<f64> {
        let (r1, r2, theta) = (xi[0], xi[1], xi[2]);
        let (h, half) = (half_cot_half(theta), 0.5 * theta);
        let c = one_minus_cos_over_t2(theta);
        let d = theta * t_minus_sin_over_t3(theta);
        let (u1, u2) = (r1 * d - r2 * c, r1 * c + r2 * d);
        Matrix3::new(
            h,
            -half,
            -(h * u1 - half * u2),
            half,
            h,
            -(half * u1 + h * u2),
            0.0,
            0.0,
            1.0,
        )
    }

    // GTSAM 4.3's Pose2 `Local` is the full logarithm (checked against its
    // `BetweenFactorPose2::unwhitenedError`), so chi2 values agree with GTSAM's.
    fn error_coordinates(&self) -> Vector3<f64> {
        self.log()
    }

    fn error_coordinates_jacobian(&self) -> Matrix3<f64> {
        Self::right_jacobian_inverse(&self.log())
    }

    fn is_finite(&self) -> bool {
        self.x_m.is_finite() && self.y_m.is_finite() && self.theta_rad.is_finite()
    }

    // Closed form of E = z⁻¹·from⁻¹·to (two sin/cos instead of three compositions' worth),
    // then Log(E).
    fn relative_error(&self, from: &Self, to: &Self) -> Vector3<f64> {
        self.relative_transform(from, to).log()
    }

    // With p = R_fromᵀ(t_to − t_from), R_z⁻¹ = R(self.θ), e_θ the error heading and
    // ξ = Log(E): ∂E/∂δ_from in E's (x, y, θ) is [[−R_z⁻¹, −R_z⁻¹ S p], [0, −1]]
    // (S = [[0,−1],[1,0]]); in E's tangent that is [[R(−e_θ), 0], [0, 1]] times it, and
    // Log adds Jr⁻¹(ξ): J_from = Jr⁻¹(ξ)·[[R(−e_θ)(…)]], J_to = Jr⁻¹(ξ).
    fn relative_error_jacobians(
        &self,
        from: &Self,
        to: &Self,
    ) -> (Vector3<f64>, Matrix3<f64>, Matrix3<f64>) {
        let (px, py) = from.inverse_rotate(to.x_m - from.x_m, to.y_m - from.y_m);
        let (sz, cz) = self.theta_rad.sin_cos();
        let error = Se2::new(
            cz * px - sz * py + self.x_m,
            sz * px + cz * py + self.y_m,
            self.theta_rad + to.theta_rad - from.theta_rad,
        );
        let xi = error.log();
        let jr_inv = Self::right_jacobian_inverse(&xi);
        // Ad(P⁻¹) in closed form: [[R(−e_θ) R_z⁻¹, R(−e_θ) R_z⁻¹ S p], [0, 1]].
        let (se, ce) = error.theta_rad.sin_cos();
        // R(−e_θ)·R_z⁻¹ = R(self.θ − e_θ).
        let (c, s) = (ce * cz + se * sz, ce * sz - se * cz);
        let (spx, spy) = (-py, px);
        let ad_inverse = Matrix3::new(
            c,
            -s,
            c * spx - s * spy,
            s,
            c,
            s * spx + c * spy,
            0.0,
            0.0,
            1.0,
        );
        (xi, -(jr_inv * ad_inverse), jr_inv)
    }
}

impl Se2 {
    /// `self · from⁻¹ · to` without composing three transforms.
    #[inline]
    fn relative_transform(&self, from: &Self, to: &Self) -> Self {
        let (px, py) = from.inverse_rotate(to.x_m - from.x_m, to.y_m - from.y_m);
        let (sz, cz) = self.theta_rad.sin_cos();
        Se2::new(
            cz * px - sz * py + self.x_m,
            sz * px + cz * py + self.y_m,
            self.theta_rad + to.theta_rad - from.theta_rad,
        )
    }
}

impl Se2 {
    /// `R(θ)ᵀ (dx, dy)`.
    #[inline]
    fn inverse_rotate(&self, dx: f64, dy: f64) -> (f64, f64) {
        let (s, c) = self.theta_rad.sin_cos();
        (c * dx + s * dy, -s * dx + c * dy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unwrapped_heading_from_struct_literal_is_wrapped() {
        // Deserialisation and struct literals bypass `Se2::new`.
        let raw = Se2 {
            x_m: 1.0,
            y_m: -2.0,
            theta_rad: 4.0,
        };
        let wrapped = Se2::new(1.0, -2.0, 4.0);
        assert!((raw.log() - wrapped.log()).abs().max() < 1e-15);
        assert!(
            (raw.error_coordinates() - wrapped.error_coordinates())
                .abs()
                .max()
                < 1e-15
        );
        assert!(raw.log()[2] <= core::f64::consts::PI);
    }

    #[test]
    fn wrap_angle_maps_into_half_open_interval() {
        use core::f64::consts::PI;
        assert_eq!(wrap_angle_rad(-PI), PI);
        assert_eq!(wrap_angle_rad(PI), PI);
        assert!((wrap_angle_rad(3.0 * PI + 0.1) - (-PI + 0.1)).abs() < 1e-12);
        assert!((wrap_angle_rad(-7.0) - (-7.0 + 2.0 * PI)).abs() < 1e-12);
        assert!(wrap_angle_rad(f64::NAN).is_nan());
        for huge in [1e20, -1e20, 4.0e15, 1e300] {
            let w = wrap_angle_rad(huge);
            assert!(w > -PI && w <= PI, "{huge} -> {w}");
        }
    }

    #[test]
    fn non_finite_input_gives_non_finite_output_without_panicking() {
        let xi = Vector3::new(f64::NAN, 0.0, f64::INFINITY);
        assert!(!Se2::exp(&xi).is_finite());
        assert!(Se2::right_jacobian_inverse(&xi)
            .iter()
            .any(|v| !v.is_finite()));
        assert!(Se2::new(0.0, f64::NAN, 0.0)
            .log()
            .iter()
            .any(|v| v.is_nan()));
    }
}
