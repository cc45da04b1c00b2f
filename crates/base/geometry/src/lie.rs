//! The Lie-group interface every pose type implements.
//!
//! Conventions (shared with GTSAM so that chi2 values are comparable):
//! - perturbations act on the right: `x ⊞ δ = x · Exp(δ)`;
//! - SE(2) tangent order is `(v_x, v_y, ω)`, SE(3) is `(ω_x, ω_y, ω_z, v_x, v_y, v_z)`.

use nalgebra::{SMatrix, SVector};

/// A matrix Lie group of dimension `D` used as a pose type.
pub trait LieGroup<const D: usize>:
    Copy + Clone + core::fmt::Debug + PartialEq + Send + Sync + 'static
{
    /// The identity element.
    fn identity() -> Self;
    /// Group product `self · other` (`a_from_c = a_from_b.compose(b_from_c)`).
    fn compose(&self, other: &Self) -> Self;
    /// Group inverse.
    fn inverse(&self) -> Self;
    /// Exponential map from the tangent space at the identity.
    fn exp(xi: &SVector<f64, D>) -> Self;
    /// Logarithm map, the inverse of [`LieGroup::exp`] (rotation angle in [0, π]).
    fn log(&self) -> SVector<f64, D>;
    /// Adjoint matrix: `self · Exp(ξ) · self⁻¹ = Exp(Ad · ξ)`.
    fn adjoint(&self) -> SMatrix<f64, D, D>;
    /// Right Jacobian `Jr(ξ)`: `Exp(ξ + δ) ≈ Exp(ξ) · Exp(Jr(ξ) δ)`.
    fn right_jacobian(xi: &SVector<f64, D>) -> SMatrix<f64, D, D>;
    /// Inverse of [`LieGroup::right_jacobian`].
    fn right_jacobian_inverse(xi: &SVector<f64, D>) -> SMatrix<f64, D, D>;
    /// Left Jacobian `Jl(ξ) = Jr(-ξ)`: `Exp(ξ + δ) ≈ Exp(Jl(ξ) δ) · Exp(ξ)`.
    fn left_jacobian(xi: &SVector<f64, D>) -> SMatrix<f64, D, D> {
        Self::right_jacobian(&(-xi))
    }
    /// Inverse of [`LieGroup::left_jacobian`].
    fn left_jacobian_inverse(xi: &SVector<f64, D>) -> SMatrix<f64, D, D> {
        Self::right_jacobian_inverse(&(-xi))
    }
    /// The coordinates a pose-graph residual uses for a (small) relative transform.
    ///
    /// GTSAM's `Local` at the identity: the full logarithm for both SE(2) and SE(3) (GTSAM
    /// 4.3's `BetweenFactor` error, so our chi2 equals GTSAM's).
    fn error_coordinates(&self) -> SVector<f64, D>;
    /// `∂ error_coordinates(self · Exp(δ)) / ∂δ` at `δ = 0`.
    fn error_coordinates_jacobian(&self) -> SMatrix<f64, D, D>;
    /// True when every stored number is finite.
    fn is_finite(&self) -> bool;

    /// The residual of a relative-pose edge whose inverted measurement is `self`:
    /// `coords(z⁻¹ · from⁻¹ · to)`. The optimizer's hot path; groups may specialise it.
    fn relative_error(&self, from: &Self, to: &Self) -> SVector<f64, D> {
        self.compose(&from.between(to)).error_coordinates()
    }

    /// [`LieGroup::relative_error`] and its Jacobians with respect to right perturbations of
    /// `from` and `to`. With `P = from⁻¹·to`, `E = z⁻¹·P` and `C` the error-coordinates
    /// Jacobian at `E`: `J_to = C`, `J_from = −C · Ad(P⁻¹)`.
    #[allow(clippy::type_complexity)]
    fn relative_error_jacobians(
        &self,
        from: &Self,
        to: &Self,
    ) -> (SVector<f64, D>, SMatrix<f64, D, D>, SMatrix<f64, D, D>) {
        let predicted = from.between(to);
        let error = self.compose(&predicted);
        let c = error.error_coordinates_jacobian();
        (
            error.error_coordinates(),
            -(c * predicted.inverse().adjoint()),
            c,
        )
    }

    /// `self⁻¹ · other`, the pose of `other` seen from `self`.
    fn between(&self, other: &Self) -> Self {
        self.inverse().compose(other)
    }
    /// `self · Exp(delta)`.
    fn retract(&self, delta: &SVector<f64, D>) -> Self {
        self.compose(&Self::exp(delta))
    }
    /// `Log(self⁻¹ · other)`, the inverse of [`LieGroup::retract`].
    fn local(&self, other: &Self) -> SVector<f64, D> {
        self.between(other).log()
    }
    /// Geodesic interpolation: `self · Exp(t · Log(self⁻¹ · other))`, `t ∈ [0, 1]`.
    fn interpolate(&self, other: &Self, t: f64) -> Self {
        self.retract(&(self.local(other) * t))
    }
}

/// `[w]×`, the skew-symmetric matrix with `[w]× v = w × v`.
pub fn skew(w: &nalgebra::Vector3<f64>) -> nalgebra::Matrix3<f64> {
    nalgebra::Matrix3::new(0.0, -w.z, w.y, w.z, 0.0, -w.x, -w.y, w.x, 0.0)
}
