//! One EKF on SE(2) per hypothesis (Banerjee et al., Sec. 3.2.1, Eq. 4–8).
//!
//! The state `G = robot_from_target` carries its covariance in the LEFT tangent
//! (`G_true = Exp(ξ)·G`, `ξ ~ N(0, Σ_G)`), as the paper's equations are written; tangent order
//! `(v_x, v_y, ω)` like `mapmerge-geometry`, whose `adjoint` satisfies
//! `T·Exp(ξ) = Exp(Ad_T ξ)·T`.

use mapmerge_geometry::{LieGroup, Se2};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};

use crate::HypothesisError;

/// `(A + Aᵀ) / 2`.
pub(crate) fn symmetrised(m: &Matrix3<f64>) -> Matrix3<f64> {
    (m + m.transpose()) * 0.5
}

/// A finite, symmetric positive definite covariance (symmetrised), or an error naming `what`.
pub(crate) fn checked_pd(
    m: &Matrix3<f64>,
    what: &'static str,
) -> Result<Matrix3<f64>, HypothesisError> {
    if m.iter().any(|v| !v.is_finite()) {
        return Err(HypothesisError::NonFinite { what });
    }
    let s = symmetrised(m);
    // Cholesky alone accepts a tiny negative pivot's neighbour; the eigenvalues decide.
    let eigen = SymmetricEigen::try_new(s, f64::EPSILON, 1000)
        .ok_or(HypothesisError::NotPositiveDefinite { what })?;
    let max = eigen.eigenvalues.max();
    if eigen.eigenvalues.min() > max * 1e-15 && s.cholesky().is_some() {
        Ok(s)
    } else {
        Err(HypothesisError::NotPositiveDefinite { what })
    }
}

/// A finite, symmetric positive semidefinite covariance (symmetrised; tiny negative eigenvalues
/// from rounding are accepted), or an error naming `what`.
pub(crate) fn checked_psd(
    m: &Matrix3<f64>,
    what: &'static str,
) -> Result<Matrix3<f64>, HypothesisError> {
    if m.iter().any(|v| !v.is_finite()) {
        return Err(HypothesisError::NonFinite { what });
    }
    let s = symmetrised(m);
    let eigen = SymmetricEigen::try_new(s, f64::EPSILON, 1000)
        .ok_or(HypothesisError::NotPositiveSemidefinite { what })?;
    let scale = eigen.eigenvalues.abs().max();
    if eigen.eigenvalues.min() >= -1e-12 * scale {
        Ok(s)
    } else {
        Err(HypothesisError::NotPositiveSemidefinite { what })
    }
}

/// Eq. 5, the motion update: `T = previous_robot_from_robot⁻¹`, `G ← T·G`,
/// `Σ_G ← Ad_T Σ_G Ad_Tᵀ + Σ_T`.
///
/// The increment's covariance `Σ_η` is in its RIGHT tangent (`Δ = Δ̄·Exp(η)`), as a scan matcher
/// or odometry gives it. Then `T = Δ⁻¹ = Exp(−η)·Δ̄⁻¹`: in `T`'s left tangent the noise is `−η`,
/// so `Σ_T = Σ_η` with no adjoint.
pub(crate) fn predict(
    robot_from_target: &Se2,
    covariance: &Matrix3<f64>,
    previous_robot_from_robot: &Se2,
    increment_covariance: &Matrix3<f64>,
) -> (Se2, Matrix3<f64>) {
    let robot_from_previous = previous_robot_from_robot.inverse();
    let ad = robot_from_previous.adjoint();
    (
        robot_from_previous.compose(robot_from_target),
        symmetrised(&(ad * covariance * ad.transpose() + increment_covariance)),
    )
}

/// Eq. 6, the innovation of observation `z` against a hypothesis.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Innovation {
    /// `Log(R)`, `R = z·G⁻¹`.
    pub log_residual: Vector3<f64>,
    /// `Log(R)ᵀ Σ_R⁻¹ Log(R)` with `Σ_R = Ad_R Σ_G Ad_Rᵀ + Σ_z`.
    pub mahalanobis_sq: f64,
}

/// Eq. 6. `None` when `Σ_R` is not positive definite (cannot happen for valid inputs).
pub(crate) fn innovation(
    robot_from_target: &Se2,
    covariance: &Matrix3<f64>,
    observed_robot_from_target: &Se2,
    observation_covariance: &Matrix3<f64>,
) -> Option<Innovation> {
    let residual = observed_robot_from_target.compose(&robot_from_target.inverse());
    let log_residual = residual.log();
    let ad = residual.adjoint();
    let residual_covariance =
        symmetrised(&(ad * covariance * ad.transpose() + observation_covariance));
    let whitened = residual_covariance
        .cholesky()?
        .l()
        .solve_lower_triangular(&log_residual)?;
    let mahalanobis_sq = whitened.norm_squared();
    mahalanobis_sq.is_finite().then_some(Innovation {
        log_residual,
        mahalanobis_sq,
    })
}

/// Eq. 7–8, the measurement update: `K = Σ_G (Σ_G + Σ_z)⁻¹`, `G ← Exp(K·Log(R))·G`,
/// `Σ_G ← (Σ_G⁻¹ + Σ_z⁻¹)⁻¹`, the latter in Joseph form `(I−K) Σ_G (I−K)ᵀ + K Σ_z Kᵀ`
/// (equal in exact arithmetic, symmetric and positive by construction).
pub(crate) fn update(
    robot_from_target: &Se2,
    covariance: &Matrix3<f64>,
    log_residual: &Vector3<f64>,
    observation_covariance: &Matrix3<f64>,
) -> Result<(Se2, Matrix3<f64>), HypothesisError> {
    let numerical = HypothesisError::Numerical {
        what: "measurement update",
    };
    let sum = symmetrised(&(covariance + observation_covariance));
    // Both covariances are symmetric, so K = Σ_G S⁻¹ = (S⁻¹ Σ_G)ᵀ.
    let gain = sum
        .cholesky()
        .ok_or(numerical.clone())?
        .solve(covariance)
        .transpose();
    let complement = Matrix3::identity() - gain;
    let updated_covariance = symmetrised(
        &(complement * covariance * complement.transpose()
            + gain * observation_covariance * gain.transpose()),
    );
    let updated = Se2::exp(&(gain * log_residual)).compose(robot_from_target);
    if !updated.is_finite() || checked_pd(&updated_covariance, "updated covariance").is_err() {
        return Err(numerical);
    }
    Ok((updated, updated_covariance))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// SplitMix64 with Box–Muller: seeded, dependency-free normal samples.
    struct Normal(u64);
    impl Normal {
        fn uniform(&mut self) -> f64 {
            self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            z ^= z >> 31;
            ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        }
        fn standard(&mut self) -> f64 {
            let (u, v) = (self.uniform(), self.uniform());
            (-2.0 * u.ln()).sqrt() * (2.0 * core::f64::consts::PI * v).cos()
        }
        fn sample(&mut self, covariance: &Matrix3<f64>) -> Vector3<f64> {
            let l = covariance.cholesky().unwrap().l();
            l * Vector3::new(self.standard(), self.standard(), self.standard())
        }
    }

    fn se2() -> impl Strategy<Value = Se2> {
        (-20.0..20.0f64, -20.0..20.0f64, -3.1..3.1f64).prop_map(|(x, y, t)| Se2::new(x, y, t))
    }

    fn tangent() -> impl Strategy<Value = Vector3<f64>> {
        (-2.0..2.0f64, -2.0..2.0f64, -3.0..3.0f64).prop_map(|(x, y, t)| Vector3::new(x, y, t))
    }

    fn pose_distance(a: &Se2, b: &Se2) -> f64 {
        a.between(b).log().abs().max()
    }

    proptest! {
        // What Eq. 5, 6 and 8 rely on: T·Exp(ξ) = Exp(Ad_T ξ)·T.
        #[test]
        fn adjoint_moves_a_right_perturbation_to_the_left(t in se2(), xi in tangent()) {
            let right = t.compose(&Se2::exp(&xi));
            let left = Se2::exp(&(t.adjoint() * xi)).compose(&t);
            prop_assert!(pose_distance(&right, &left) < 1e-9, "{right:?} vs {left:?}");
        }
    }

    #[test]
    fn motion_update_covariance_matches_monte_carlo() {
        // Large rotation and translation in both G and the increment, so that a missing or
        // misplaced adjoint changes Σ by far more than the sampling error (~1 %).
        let robot_from_target = Se2::new(3.0, -2.0, 2.2);
        let covariance = Matrix3::new(
            0.004, 0.001, 0.0005, 0.001, 0.006, -0.0004, 0.0005, -0.0004, 0.002,
        );
        let previous_robot_from_robot = Se2::new(1.5, 0.8, 0.9);
        let increment_covariance = Matrix3::new(
            0.003, -0.0008, 0.0006, -0.0008, 0.001, 0.0002, 0.0006, 0.0002, 0.0015,
        );
        let (predicted, predicted_covariance) = predict(
            &robot_from_target,
            &covariance,
            &previous_robot_from_robot,
            &increment_covariance,
        );

        let mut rng = Normal(7);
        let samples = 20_000;
        let mut sum = Vector3::zeros();
        let mut outer = Matrix3::zeros();
        for _ in 0..samples {
            let g = Se2::exp(&rng.sample(&covariance)).compose(&robot_from_target);
            let increment =
                previous_robot_from_robot.compose(&Se2::exp(&rng.sample(&increment_covariance)));
            // Left-tangent error of the sample about the prediction.
            let xi = increment
                .inverse()
                .compose(&g)
                .compose(&predicted.inverse())
                .log();
            sum += xi;
            outer += xi * xi.transpose();
        }
        let n = samples as f64;
        let mean = sum / n;
        let empirical = (outer - mean * mean.transpose() * n) / (n - 1.0);
        assert!(mean.abs().max() < 3e-3, "biased mean {mean}");
        // Largest error relative to the predicted standard deviations.
        let relative_error = |cov: &Matrix3<f64>| {
            let mut worst: f64 = 0.0;
            for i in 0..3 {
                for j in 0..3 {
                    let scale =
                        (predicted_covariance[(i, i)] * predicted_covariance[(j, j)]).sqrt();
                    worst = worst.max((empirical[(i, j)] - cov[(i, j)]).abs() / scale);
                }
            }
            worst
        };
        let error = relative_error(&predicted_covariance);
        assert!(
            error < 0.04,
            "{error}: {empirical} vs {predicted_covariance}"
        );
        // The test can fail: common mistakes are far off. Σ_T taken as Ad_Δ Σ_η Ad_Δᵀ (the
        // increment's left tangent) or as Ad_T Σ_η Ad_Tᵀ, or Σ_G left unrotated.
        let ad_increment = previous_robot_from_robot.adjoint();
        let ad_t = previous_robot_from_robot.inverse().adjoint();
        let rotated = ad_t * covariance * ad_t.transpose();
        for wrong in [
            rotated + ad_increment * increment_covariance * ad_increment.transpose(),
            rotated + ad_t * increment_covariance * ad_t.transpose(),
            covariance + increment_covariance,
        ] {
            let wrong_error = relative_error(&wrong);
            assert!(wrong_error > 5.0 * 0.04, "{wrong_error}");
        }
    }

    /// `argmin_G ‖Log(G·Ḡ⁻¹)‖²_{Σ_G⁻¹} + ‖Log(z·G⁻¹)‖²_{Σ_z⁻¹}` by Gauss–Newton in the left
    /// tangent with numerical Jacobians; returns the optimum and the inverse Hessian there.
    fn map_estimate(
        prior: &Se2,
        prior_cov: &Matrix3<f64>,
        z: &Se2,
        z_cov: &Matrix3<f64>,
    ) -> (Se2, Matrix3<f64>) {
        let (w_prior, w_z) = (
            prior_cov.try_inverse().unwrap(),
            z_cov.try_inverse().unwrap(),
        );
        let residuals = |g: &Se2| {
            (
                g.compose(&prior.inverse()).log(),
                z.compose(&g.inverse()).log(),
            )
        };
        let jacobians = |g: &Se2| {
            let (mut j_prior, mut j_z) = (Matrix3::zeros(), Matrix3::zeros());
            let h = 1e-6;
            for k in 0..3 {
                let mut d = Vector3::zeros();
                d[k] = h;
                let (p1, z1) = residuals(&Se2::exp(&d).compose(g));
                let (p0, z0) = residuals(&Se2::exp(&-d).compose(g));
                j_prior.set_column(k, &((p1 - p0) / (2.0 * h)));
                j_z.set_column(k, &((z1 - z0) / (2.0 * h)));
            }
            (j_prior, j_z)
        };
        let mut g = *prior;
        let mut hessian = Matrix3::identity();
        for _ in 0..50 {
            let (r_prior, r_z) = residuals(&g);
            let (j_prior, j_z) = jacobians(&g);
            hessian = j_prior.transpose() * w_prior * j_prior + j_z.transpose() * w_z * j_z;
            let gradient = j_prior.transpose() * w_prior * r_prior + j_z.transpose() * w_z * r_z;
            let step = -hessian.cholesky().unwrap().solve(&gradient);
            g = Se2::exp(&step).compose(&g);
            if step.norm() < 1e-13 {
                break;
            }
        }
        (g, hessian.try_inverse().unwrap())
    }

    #[test]
    fn measurement_update_matches_the_map_estimate_for_small_residuals() {
        // G far from the identity so that applying the correction on the wrong side shows.
        let prior = Se2::new(4.0, -3.0, 2.0);
        let prior_cov = Matrix3::new(
            0.02, 0.004, 0.002, 0.004, 0.01, -0.001, 0.002, -0.001, 0.004,
        );
        let z_cov = Matrix3::new(0.01, -0.002, 0.0, -0.002, 0.03, 0.001, 0.0, 0.001, 0.002);
        for (k, offset) in [
            Vector3::new(0.01, -0.008, 0.006),
            Vector3::new(-0.012, 0.004, -0.01),
            Vector3::new(0.0, 0.015, 0.004),
        ]
        .iter()
        .enumerate()
        {
            let z = Se2::exp(offset).compose(&prior);
            let inn = innovation(&prior, &prior_cov, &z, &z_cov).unwrap();
            let (updated, updated_cov) =
                update(&prior, &prior_cov, &inn.log_residual, &z_cov).unwrap();
            let (map, map_cov) = map_estimate(&prior, &prior_cov, &z, &z_cov);
            let error = pose_distance(&updated, &map);
            // Second order in the residual (~1e-2): 1e-4 · few.
            assert!(
                error < 5e-4,
                "case {k}: EKF {updated:?} vs MAP {map:?} ({error})"
            );
            let cov_error = (updated_cov - map_cov).abs().max() / map_cov.abs().max();
            assert!(cov_error < 0.05, "case {k}: {updated_cov} vs {map_cov}");

            // The test can fail: a swapped gain or a right-side correction are far off.
            let swapped_gain =
                Matrix3::identity() - prior_cov * (prior_cov + z_cov).try_inverse().unwrap();
            let swapped = Se2::exp(&(swapped_gain * inn.log_residual)).compose(&prior);
            let right_side = prior.compose(&Se2::exp(
                &(prior_cov * (prior_cov + z_cov).try_inverse().unwrap() * inn.log_residual),
            ));
            assert!(pose_distance(&swapped, &map) > 10.0 * 5e-4);
            assert!(pose_distance(&right_side, &map) > 10.0 * 5e-4);
        }
    }

    #[test]
    fn joseph_form_equals_information_form() {
        let cov = Matrix3::new(
            0.02, 0.004, 0.002, 0.004, 0.01, -0.001, 0.002, -0.001, 0.004,
        );
        let z_cov = Matrix3::new(0.01, -0.002, 0.0, -0.002, 0.03, 0.001, 0.0, 0.001, 0.002);
        let (_, updated) =
            update(&Se2::new(1.0, 2.0, 0.3), &cov, &Vector3::zeros(), &z_cov).unwrap();
        let information = (cov.try_inverse().unwrap() + z_cov.try_inverse().unwrap())
            .try_inverse()
            .unwrap();
        assert!((updated - information).abs().max() < 1e-12);
        assert_eq!(updated, updated.transpose());
    }

    #[test]
    fn mahalanobis_distance_uses_the_residual_covariance() {
        let g = Se2::new(1.0, 0.0, 0.0);
        let cov = Matrix3::from_diagonal(&Vector3::new(0.01, 0.01, 0.001));
        let z_cov = cov;
        // 0.2 m along x with Σ_R = 0.02 → d² = 0.04 / 0.02 = 2.
        let z = Se2::new(1.2, 0.0, 0.0);
        let inn = innovation(&g, &cov, &z, &z_cov).unwrap();
        assert!(
            (inn.mahalanobis_sq - 2.0).abs() < 1e-9,
            "{}",
            inn.mahalanobis_sq
        );
    }

    #[test]
    fn covariance_checks_refuse_bad_input() {
        let nan = Matrix3::from_element(f64::NAN);
        assert!(matches!(
            checked_pd(&nan, "z"),
            Err(HypothesisError::NonFinite { .. })
        ));
        assert!(checked_pd(&Matrix3::zeros(), "z").is_err());
        assert!(checked_pd(&Matrix3::from_diagonal(&Vector3::new(1.0, -1e-3, 1.0)), "z").is_err());
        assert!(checked_psd(&Matrix3::zeros(), "z").is_ok());
        assert!(checked_psd(&Matrix3::from_diagonal(&Vector3::new(1.0, -1e-3, 1.0)), "z").is_err());
        assert!(checked_pd(&Matrix3::identity(), "z").is_ok());
    }
}
