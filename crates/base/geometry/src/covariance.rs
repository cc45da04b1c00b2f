//! Jacobians of compose/inverse/between and first-order covariance propagation.
//!
//! Convention: perturbations act on the right on inputs and outputs, `x̃ = x · Exp(δ)` with
//! `δ ~ N(0, Σ)`. Jacobian blocks: Solà et al., "A micro Lie theory", Sec. IV (inverse and
//! composition); GTSAM `Pose3::compose/inverse/between(..., H1, H2)`. Propagation to first
//! order: `Σ_y = J Σ_x Jᵀ` (Barfoot, "State Estimation for Robotics", Sec. 7.3, compounding).

use nalgebra::SMatrix;

use crate::lie::LieGroup;

/// `(J_a, J_b)` of `a · b`: `(a Exp(δa)) (b Exp(δb)) ≈ (a b) Exp(J_a δa + J_b δb)`.
///
/// `J_a = Ad(b⁻¹)`, `J_b = I`; `a` does not enter.
pub fn compose_jacobians<const D: usize, G: LieGroup<D>>(
    _a: &G,
    b: &G,
) -> (SMatrix<f64, D, D>, SMatrix<f64, D, D>) {
    (b.inverse().adjoint(), SMatrix::identity())
}

/// `J` of `x⁻¹`: `(x Exp(δ))⁻¹ ≈ x⁻¹ Exp(J δ)`, `J = -Ad(x)`.
pub fn inverse_jacobian<const D: usize, G: LieGroup<D>>(x: &G) -> SMatrix<f64, D, D> {
    -x.adjoint()
}

/// `(J_a, J_b)` of `a⁻¹ · b` ([`LieGroup::between`]).
///
/// `J_a = -Ad(b⁻¹ a)`, `J_b = I` (chain rule on inverse and compose).
pub fn between_jacobians<const D: usize, G: LieGroup<D>>(
    a: &G,
    b: &G,
) -> (SMatrix<f64, D, D>, SMatrix<f64, D, D>) {
    (-b.between(a).adjoint(), SMatrix::identity())
}

/// Covariance of `a_from_c = a_from_b · b_from_c` for independent inputs:
/// `Σ_ac = Ad(b_from_c⁻¹) Σ_ab Ad(b_from_c⁻¹)ᵀ + Σ_bc`.
///
/// Only `b_from_c` enters (`J_a = Ad(b_from_c⁻¹)`, `J_b = I`).
pub fn compose_covariance<const D: usize, G: LieGroup<D>>(
    b_from_c: &G,
    cov_a_from_b: &SMatrix<f64, D, D>,
    cov_b_from_c: &SMatrix<f64, D, D>,
) -> SMatrix<f64, D, D> {
    let j_a = b_from_c.inverse().adjoint();
    symmetrize(j_a * cov_a_from_b * j_a.transpose() + cov_b_from_c)
}

/// Like [`compose_covariance`] for correlated inputs, where
/// `cross_ab_bc = E[δ_ab δ_bcᵀ]`: adds `J_a C + Cᵀ J_aᵀ` with `J_a = Ad(b_from_c⁻¹)`.
pub fn compose_covariance_correlated<const D: usize, G: LieGroup<D>>(
    b_from_c: &G,
    cov_a_from_b: &SMatrix<f64, D, D>,
    cov_b_from_c: &SMatrix<f64, D, D>,
    cross_ab_bc: &SMatrix<f64, D, D>,
) -> SMatrix<f64, D, D> {
    let j_a = b_from_c.inverse().adjoint();
    let cross = j_a * cross_ab_bc;
    symmetrize(j_a * cov_a_from_b * j_a.transpose() + cov_b_from_c + cross + cross.transpose())
}

/// Covariance of `x⁻¹`: `Σ_inv = Ad(x) Σ Ad(x)ᵀ`.
pub fn inverse_covariance<const D: usize, G: LieGroup<D>>(
    x: &G,
    cov: &SMatrix<f64, D, D>,
) -> SMatrix<f64, D, D> {
    let ad = x.adjoint();
    symmetrize(ad * cov * ad.transpose())
}

/// Covariance of `a⁻¹ · b` for independent inputs: `Ad(b⁻¹ a) Σ_a Ad(b⁻¹ a)ᵀ + Σ_b`.
pub fn between_covariance<const D: usize, G: LieGroup<D>>(
    a: &G,
    cov_a: &SMatrix<f64, D, D>,
    b: &G,
    cov_b: &SMatrix<f64, D, D>,
) -> SMatrix<f64, D, D> {
    let j_a = b.between(a).adjoint();
    symmetrize(j_a * cov_a * j_a.transpose() + cov_b)
}

/// `(M + Mᵀ) / 2`: removes the rounding asymmetry of `J Σ Jᵀ`.
fn symmetrize<const D: usize>(m: SMatrix<f64, D, D>) -> SMatrix<f64, D, D> {
    (m + m.transpose()) * 0.5
}

/// Information of a planar `(vx, vy, ω)` edge: the inverse of `covariance` with standard
/// deviations floored at `min_sigma` (m, rad) (a matcher's covariance can be overconfident or
/// singular); a non-finite covariance gives the floor's information.
pub fn planar_information_from_covariance(
    covariance: &nalgebra::Matrix3<f64>,
    min_sigma: (f64, f64),
) -> nalgebra::Matrix3<f64> {
    use nalgebra::{Matrix3, Vector3};
    let floor = Matrix3::from_diagonal(&Vector3::new(
        min_sigma.0 * min_sigma.0,
        min_sigma.0 * min_sigma.0,
        min_sigma.1 * min_sigma.1,
    ));
    let covariance = if covariance.iter().all(|v| v.is_finite()) {
        covariance + floor
    } else {
        floor
    };
    covariance
        .try_inverse()
        .filter(|i| i.iter().all(|v| v.is_finite()))
        .or_else(|| floor.try_inverse())
        .unwrap_or_else(Matrix3::identity)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Se2, Se3};
    use nalgebra::{Matrix3, UnitQuaternion, Vector3};

    #[test]
    fn composing_with_identity_adds_covariances() {
        let cov = Matrix3::from_diagonal(&Vector3::new(0.1, 0.2, 0.3));
        let sum = compose_covariance(&Se2::identity(), &cov, &cov);
        assert!((sum - cov * 2.0).abs().max() < 1e-15);
    }

    #[test]
    fn pure_rotation_rotates_translation_covariance() {
        // b_from_c rotates by +90°: a_from_b's x-uncertainty appears along c's y axis.
        let b_from_c = Se2::new(0.0, 0.0, core::f64::consts::FRAC_PI_2);
        let cov_ab = Matrix3::from_diagonal(&Vector3::new(4.0, 1.0, 0.0));
        let cov = compose_covariance(&b_from_c, &cov_ab, &Matrix3::zeros());
        assert!(
            (cov - Matrix3::from_diagonal(&Vector3::new(1.0, 4.0, 0.0)))
                .abs()
                .max()
                < 1e-12
        );
    }

    #[test]
    fn inverse_of_inverse_covariance_is_identity_map() {
        let x = Se3::new(
            UnitQuaternion::from_euler_angles(0.3, -1.2, 2.0),
            Vector3::new(1.0, -2.0, 3.0),
        );
        let cov = nalgebra::Matrix6::from_fn(|i, j| if i == j { 1.0 + i as f64 } else { 0.1 });
        let twice = inverse_covariance(&x.inverse(), &inverse_covariance(&x, &cov));
        assert!((twice - cov).abs().max() < 1e-12);
    }
}
