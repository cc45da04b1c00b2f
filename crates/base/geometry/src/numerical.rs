//! Central-difference Jacobians, for testing analytic ones (GTSAM's `numericalDerivative11`).

use nalgebra::{SMatrix, SVector};

use crate::lie::LieGroup;

/// `∂f/∂x` at `x` by central differences, `(f(x + h eᵢ) - f(x - h eᵢ)) / 2h`.
///
/// Truncation error is `O(h²)`, rounding `O(ε/h)`; `h = 1e-5` (GTSAM's default) suits
/// functions of order one.
pub fn numerical_jacobian<const N: usize, const M: usize>(
    f: impl Fn(&SVector<f64, N>) -> SVector<f64, M>,
    x: &SVector<f64, N>,
    step: f64,
) -> SMatrix<f64, M, N> {
    let mut jacobian = SMatrix::<f64, M, N>::zeros();
    for i in 0..N {
        let mut dx = SVector::<f64, N>::zeros();
        dx[i] = step;
        let column = (f(&(x + dx)) - f(&(x - dx))) / (2.0 * step);
        jacobian.set_column(i, &column);
    }
    jacobian
}

/// Jacobian of a map between Lie groups in the right-perturbation convention:
/// `∂ Log(f(x)⁻¹ f(x · Exp(δ))) / ∂δ` at `δ = 0`, by central differences.
pub fn numerical_lie_jacobian<const N: usize, const M: usize, G, H>(
    f: impl Fn(&G) -> H,
    x: &G,
    step: f64,
) -> SMatrix<f64, M, N>
where
    G: LieGroup<N>,
    H: LieGroup<M>,
{
    let y = f(x);
    numerical_jacobian(
        |delta: &SVector<f64, N>| y.local(&f(&x.retract(delta))),
        &SVector::zeros(),
        step,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix2, Vector2};

    #[test]
    fn differentiates_a_polynomial_map() {
        let f = |v: &Vector2<f64>| Vector2::new(v.x * v.x * v.y, v.y.powi(3) - v.x);
        let x = Vector2::new(1.5, -2.0);
        let want = Matrix2::new(2.0 * x.x * x.y, x.x * x.x, -1.0, 3.0 * x.y * x.y);
        let got = numerical_jacobian(f, &x, 1e-5);
        assert!((got - want).abs().max() < 1e-8, "{got} vs {want}");
    }
}
