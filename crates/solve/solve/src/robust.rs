//! Robust kernels applied to an edge's squared Mahalanobis error `s = rᵀ Ω r`.
//!
//! Iteratively reweighted least squares: each edge's information is scaled by `ρ'(s)` and the
//! cost is `Σ ρ(s)`.

use mapmerge_params::{Checker, Real, Validate};
use serde::{Deserialize, Serialize};

/// A robust kernel `ρ(s)` on the squared error `s`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum RobustKernel {
    /// Plain least squares, `ρ(s) = s`.
    #[default]
    None,
    /// Huber: quadratic up to `|r| = delta`, linear beyond (`delta` in Mahalanobis units).
    Huber {
        /// Transition point (default 1.345 · √D is common; the CLI uses √χ²₀.₉₅).
        delta: f64,
    },
    /// Cauchy: `ρ(s) = c² ln(1 + s / c²)`.
    Cauchy {
        /// Scale `c` in Mahalanobis units.
        c: f64,
    },
    /// Dynamic Covariance Scaling (Agarwal et al., ICRA 2013, eq. 13): weight
    /// `min(1, 2Φ / (Φ + s))²`.
    Dcs {
        /// `Φ`, the squared error at which scaling starts (paper default 1).
        phi: f64,
    },
}

impl RobustKernel {
    /// `ρ(s)`.
    pub fn cost(&self, s: f64) -> f64 {
        match *self {
            Self::None => s,
            Self::Huber { delta } => {
                let d2 = delta * delta;
                if s <= d2 {
                    s
                } else {
                    2.0 * delta * s.sqrt() - d2
                }
            }
            Self::Cauchy { c } => {
                let c2 = c * c;
                c2 * (s / c2).ln_1p()
            }
            // ∫ of the DCS weight: Φ(3s − Φ)/(s + Φ) beyond Φ (continuous at s = Φ).
            Self::Dcs { phi } => {
                if s <= phi {
                    s
                } else {
                    phi * (3.0 * s - phi) / (s + phi)
                }
            }
        }
    }

    /// `ρ'(s)`, the IRLS weight on the edge information.
    pub fn weight(&self, s: f64) -> f64 {
        match *self {
            Self::None => 1.0,
            Self::Huber { delta } => {
                if s <= delta * delta {
                    1.0
                } else {
                    delta / s.sqrt()
                }
            }
            Self::Cauchy { c } => 1.0 / (1.0 + s / (c * c)),
            Self::Dcs { phi } => {
                let scale = (2.0 * phi / (phi + s)).min(1.0);
                scale * scale
            }
        }
    }
}

impl Validate for RobustKernel {
    fn check(&self, check: &mut Checker) {
        let positive = Real::positive_up_to(1e9);
        match *self {
            Self::None => check,
            Self::Huber { delta } => check.real("delta", delta, positive),
            Self::Cauchy { c } => check.real("c", c, positive),
            Self::Dcs { phi } => check.real("phi", phi, positive),
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weight_is_derivative_of_cost() {
        let kernels = [
            RobustKernel::None,
            RobustKernel::Huber { delta: 1.5 },
            RobustKernel::Cauchy { c: 2.0 },
            RobustKernel::Dcs { phi: 1.0 },
        ];
        for k in kernels {
            for s in [0.01f64, 0.5, 0.99, 1.7, 3.0, 10.0, 250.0] {
                let h = 1e-6 * s.max(1.0);
                let numeric = (k.cost(s + h) - k.cost(s - h)) / (2.0 * h);
                assert!(
                    (numeric - k.weight(s)).abs() < 1e-6,
                    "{k:?} at {s}: {numeric}"
                );
            }
        }
    }

    #[test]
    fn robust_costs_grow_slower_than_quadratic() {
        for k in [
            RobustKernel::Huber { delta: 1.0 },
            RobustKernel::Cauchy { c: 1.0 },
            RobustKernel::Dcs { phi: 1.0 },
        ] {
            assert!(k.cost(1e4) < 1e3, "{k:?}");
            assert!(k.validate().is_ok());
        }
        assert!(RobustKernel::Huber { delta: -1.0 }.validate().is_err());
    }
}
