//! Scalar coefficient functions of the SO(3)/SE(2)/SE(3) closed forms, accurate for every angle.
//!
//! The closed forms cancel catastrophically near 0 (e.g. `θ - sin θ` loses all digits below
//! θ ≈ 1e-5). Below [`SERIES_LIMIT_RAD`] each function sums its Taylor series instead; with
//! [`SERIES_TERMS`] terms the truncation error is below 1e-20 there, and at and above that
//! limit the closed forms lose at most a few ulps.

/// Below this |θ| (rad) the Taylor series replace the closed forms.
const SERIES_LIMIT_RAD: f64 = 1.0;
/// Terms summed: the first omitted one is at most 1 / (2·SERIES_TERMS + 5)! ≈ 1e-22.
const SERIES_TERMS: usize = 10;

/// `1 / n!` for `n < 32`.
const INV_FACTORIAL: [f64; 32] = {
    let mut table = [1.0; 32];
    let mut n = 1;
    while n < 32 {
        table[n] = table[n - 1] / n as f64;
        n += 1;
    }
    table
};

/// `Σ_m (-1)^m coefficient(m) θ^{2m}` over the first [`SERIES_TERMS`] terms (Horner, smallest first).
fn alternating_even_series(theta2: f64, coefficient: impl Fn(usize) -> f64) -> f64 {
    let mut sum = 0.0;
    for m in (0..SERIES_TERMS).rev() {
        let signed = if m % 2 == 0 {
            coefficient(m)
        } else {
            -coefficient(m)
        };
        sum = sum * theta2 + signed;
    }
    sum
}

/// `sin θ / θ`.
pub(crate) fn sinc(theta: f64) -> f64 {
    if theta.abs() < SERIES_LIMIT_RAD {
        alternating_even_series(theta * theta, |m| INV_FACTORIAL[2 * m + 1])
    } else {
        theta.sin() / theta
    }
}

/// `(1 - cos θ) / θ² = ½ sinc²(θ/2)` (half-angle form: no cancellation anywhere).
pub(crate) fn one_minus_cos_over_t2(theta: f64) -> f64 {
    let s = sinc(0.5 * theta);
    0.5 * s * s
}

/// `(θ - sin θ) / θ³`.
pub(crate) fn t_minus_sin_over_t3(theta: f64) -> f64 {
    if theta.abs() < SERIES_LIMIT_RAD {
        alternating_even_series(theta * theta, |m| INV_FACTORIAL[2 * m + 3])
    } else {
        (theta - theta.sin()) / (theta * theta * theta)
    }
}

/// `(θ² + 2 cos θ - 2) / (2 θ⁴) = (½ - (1 - cos θ)/θ²) / θ²` (Barfoot, eq. 7.86, 2nd coefficient).
pub(crate) fn barfoot_q_c2(theta: f64) -> f64 {
    if theta.abs() < SERIES_LIMIT_RAD {
        alternating_even_series(theta * theta, |m| INV_FACTORIAL[2 * m + 4])
    } else {
        (0.5 - one_minus_cos_over_t2(theta)) / (theta * theta)
    }
}

/// `(2θ - 3 sin θ + θ cos θ) / (2 θ⁵)` (Barfoot, eq. 7.86, 3rd coefficient).
///
/// Series: `Σ_m (-1)^m (m + 1) θ^{2m} / (2m + 5)!`.
pub(crate) fn barfoot_q_c3(theta: f64) -> f64 {
    if theta.abs() < SERIES_LIMIT_RAD {
        alternating_even_series(theta * theta, |m| (m + 1) as f64 * INV_FACTORIAL[2 * m + 5])
    } else {
        let (s, c) = theta.sin_cos();
        (2.0 * theta - 3.0 * s + theta * c) / (2.0 * theta.powi(5))
    }
}

/// `(θ/2) cot(θ/2) = cos(θ/2) / sinc(θ/2)`, finite for |θ| < 2π.
pub(crate) fn half_cot_half(theta: f64) -> f64 {
    let half = 0.5 * theta;
    half.cos() / sinc(half)
}

/// `(1 - (θ/2) cot(θ/2)) / θ² = 1/θ² - (1 + cos θ) / (2 θ sin θ)`, the `[ω]×²` coefficient of
/// the inverse SO(3) Jacobian (Solà et al., App. B).
///
/// With `x = θ/2`: `1 - x cot x = (sinc x - cos x) / sinc x` and
/// `sinc x - cos x = Σ_{m≥0} (-1)^m (2m + 2) x^{2m+2} / (2m + 3)!`.
pub(crate) fn inverse_jacobian_coefficient(theta: f64) -> f64 {
    let half = 0.5 * theta;
    if theta.abs() < SERIES_LIMIT_RAD {
        let numerator = alternating_even_series(half * half, |m| {
            (2 * m + 2) as f64 * INV_FACTORIAL[2 * m + 3]
        });
        // (x² · numerator / sinc x) / θ² with θ² = 4x².
        0.25 * numerator / sinc(half)
    } else {
        (1.0 - half_cot_half(theta)) / (theta * theta)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rel_err(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs().max(1e-300)
    }

    /// The closed forms, evaluated where they are accurate (|θ| near 1 and above).
    fn closed_forms(theta: f64) -> [f64; 6] {
        let (s, c) = theta.sin_cos();
        let t2 = theta * theta;
        [
            s / theta,
            (1.0 - c) / t2,
            (theta - s) / (t2 * theta),
            (t2 + 2.0 * c - 2.0) / (2.0 * t2 * t2),
            (2.0 * theta - 3.0 * s + theta * c) / (2.0 * t2 * t2 * theta),
            1.0 / t2 - (1.0 + c) / (2.0 * theta * s),
        ]
    }

    fn all(theta: f64) -> [f64; 6] {
        [
            sinc(theta),
            one_minus_cos_over_t2(theta),
            t_minus_sin_over_t3(theta),
            barfoot_q_c2(theta),
            barfoot_q_c3(theta),
            inverse_jacobian_coefficient(theta),
        ]
    }

    #[test]
    fn series_match_closed_forms_below_the_switch() {
        for theta in [0.9, SERIES_LIMIT_RAD * (1.0 - 1e-12), -0.95] {
            for (i, (got, want)) in all(theta).into_iter().zip(closed_forms(theta)).enumerate() {
                let err = rel_err(got, want);
                assert!(
                    err < 5e-14,
                    "function {i} at θ = {theta}: relative error {err:e}"
                );
            }
        }
    }

    #[test]
    fn small_angle_values_match_leading_terms() {
        for theta in [0.0, 1e-12, 1e-9, 1e-6, 1e-5, 2e-5, 1e-4, 3e-4] {
            let t2 = theta * theta;
            let cases = [
                (sinc(theta), 1.0 - t2 / 6.0 + t2 * t2 / 120.0),
                (
                    one_minus_cos_over_t2(theta),
                    0.5 - t2 / 24.0 + t2 * t2 / 720.0,
                ),
                (
                    t_minus_sin_over_t3(theta),
                    1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0,
                ),
                (
                    barfoot_q_c2(theta),
                    1.0 / 24.0 - t2 / 720.0 + t2 * t2 / 40320.0,
                ),
                (
                    barfoot_q_c3(theta),
                    1.0 / 120.0 - t2 / 2520.0 + t2 * t2 / 120960.0,
                ),
                (
                    inverse_jacobian_coefficient(theta),
                    1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0,
                ),
            ];
            for (i, (got, want)) in cases.into_iter().enumerate() {
                let err = rel_err(got, want);
                assert!(
                    err < 1e-15,
                    "function {i} at θ = {theta:e}: relative error {err:e}"
                );
            }
        }
    }

    #[test]
    fn closed_forms_are_used_at_large_angles() {
        use core::f64::consts::PI;
        for theta in [SERIES_LIMIT_RAD, 1.5, 2.0, 3.0, -3.0] {
            for (i, (got, want)) in all(theta).into_iter().zip(closed_forms(theta)).enumerate() {
                let err = rel_err(got, want);
                assert!(
                    err < 5e-14,
                    "function {i} at θ = {theta}: relative error {err:e}"
                );
            }
        }
        // Near π, (1 + cos θ)/sin θ cancels; cot(θ/2) does not: at π the coefficient is 1/π².
        assert!(rel_err(inverse_jacobian_coefficient(PI), 1.0 / (PI * PI)) < 1e-15);
        let near = PI - 1e-7;
        let want = 1.0 / (near * near) - (0.5 * near).cos() / (0.5 * near).sin() / (2.0 * near);
        assert!(rel_err(inverse_jacobian_coefficient(near), want) < 1e-15);
        assert!(half_cot_half(PI).abs() < 1e-16);
    }
}
