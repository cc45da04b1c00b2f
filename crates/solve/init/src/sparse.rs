//! Sparse normal equations `A x = b` assembled from triplets and solved by faer's sparse
//! Cholesky (`A` symmetric positive definite, only its lower triangle stored).

use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Mat, Side};

use crate::error::InitError;

/// Normal equations with `dim` unknowns and `rhs_cols` right-hand sides.
pub(crate) struct NormalEquations {
    dim: usize,
    rhs_cols: usize,
    triplets: Vec<Triplet<usize, usize, f64>>,
    /// Column-major `dim x rhs_cols`.
    rhs: Vec<f64>,
}

impl NormalEquations {
    /// An all-zero system; `nnz_hint` reserves room for that many lower-triangle entries.
    pub fn new(dim: usize, rhs_cols: usize, nnz_hint: usize) -> Self {
        Self {
            dim,
            rhs_cols,
            triplets: Vec::with_capacity(nnz_hint),
            rhs: vec![0.0; dim * rhs_cols],
        }
    }

    /// Adds `value` to `A[row][col]` and, when `row != col`, to `A[col][row]` (only the lower
    /// triangle is stored; duplicates are summed when the matrix is built).
    #[inline]
    pub fn add(&mut self, row: usize, col: usize, value: f64) {
        let (row, col) = if row >= col { (row, col) } else { (col, row) };
        self.triplets.push(Triplet::new(row, col, value));
    }

    /// Adds `value` to `b[row][col]`.
    #[inline]
    pub fn add_rhs(&mut self, row: usize, col: usize, value: f64) {
        self.rhs[col * self.dim + row] += value;
    }

    /// Solves the system; returns `x` column-major (`x[col * dim + row]`). `stage` names the
    /// system in errors.
    pub fn solve(self, stage: &'static str) -> Result<Vec<f64>, InitError> {
        let (dim, cols) = (self.dim, self.rhs_cols);
        if dim == 0 {
            return Ok(Vec::new());
        }
        let fail = |reason: String| InitError::LinearSolve { stage, reason };
        let a = SparseColMat::<usize, f64>::try_new_from_triplets(dim, dim, &self.triplets)
            .map_err(|e| fail(format!("building the matrix: {e:?}")))?;
        let symbolic = SymbolicLlt::try_new(a.symbolic(), Side::Lower)
            .map_err(|e| fail(format!("symbolic factorisation: {e:?}")))?;
        let llt = Llt::try_new_with_symbolic(symbolic, a.as_ref(), Side::Lower).map_err(|e| {
            fail(format!(
                "numeric factorisation (matrix not positive definite?): {e:?}"
            ))
        })?;
        let mut x = Mat::<f64>::from_fn(dim, cols, |i, j| self.rhs[j * dim + i]);
        llt.solve_in_place(x.as_mut());
        let mut out = Vec::with_capacity(dim * cols);
        for j in 0..cols {
            out.extend(x.col(j).iter().copied());
        }
        if out.iter().any(|v| !v.is_finite()) {
            return Err(fail("the solution is not finite".to_string()));
        }
        Ok(out)
    }

    /// Adds `(x_to − x_from − target)ᵀ w (x_to − x_from − target)` for `N`-vectors `x` to the
    /// normal equations (right-hand side 0). Vertex `k` with `unknown[k] = Some(u)` owns unknowns
    /// `N u .. N u + N`; a vertex with `None` is constant with value `known(k)`.
    pub fn add_difference<const N: usize>(
        &mut self,
        unknown: &[Option<usize>],
        from: usize,
        to: usize,
        w: &nalgebra::SMatrix<f64, N, N>,
        target: &nalgebra::SVector<f64, N>,
        known: impl Fn(usize) -> nalgebra::SVector<f64, N>,
    ) {
        let add_diagonal = |normal: &mut NormalEquations, u: usize| {
            for a in 0..N {
                for b in 0..=a {
                    normal.add(N * u + a, N * u + b, w[(a, b)]);
                }
            }
        };
        let normal = self;
        match (unknown[from], unknown[to]) {
            (Some(i), Some(j)) => {
                add_diagonal(normal, i);
                add_diagonal(normal, j);
                for a in 0..N {
                    for b in 0..N {
                        normal.add(N * j + a, N * i + b, -w[(a, b)]);
                    }
                }
                let wt = w * target;
                for a in 0..N {
                    normal.add_rhs(N * i + a, 0, -wt[a]);
                    normal.add_rhs(N * j + a, 0, wt[a]);
                }
            }
            (None, Some(j)) => {
                add_diagonal(normal, j);
                let rhs = w * (known(from) + target);
                for a in 0..N {
                    normal.add_rhs(N * j + a, 0, rhs[a]);
                }
            }
            (Some(i), None) => {
                add_diagonal(normal, i);
                let rhs = w * (known(to) - target);
                for a in 0..N {
                    normal.add_rhs(N * i + a, 0, rhs[a]);
                }
            }
            (None, None) => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_a_small_spd_system_with_two_right_hand_sides() {
        // A = [[4, 1, 0], [1, 3, 1], [0, 1, 2]], entries split into summed duplicates.
        let mut ne = NormalEquations::new(3, 2, 8);
        ne.add(0, 0, 3.0);
        ne.add(0, 0, 1.0);
        ne.add(0, 1, 1.0); // upper entry: stored as (1, 0)
        ne.add(1, 1, 3.0);
        ne.add(2, 1, 1.0);
        ne.add(2, 2, 2.0);
        let x_true = [[1.0, -2.0, 0.5], [0.0, 1.0, 3.0]];
        let a = [[4.0, 1.0, 0.0], [1.0, 3.0, 1.0], [0.0, 1.0, 2.0]];
        for (c, x) in x_true.iter().enumerate() {
            for (r, row) in a.iter().enumerate() {
                let b: f64 = row.iter().zip(x).map(|(a, x)| a * x).sum();
                ne.add_rhs(r, c, b);
            }
        }
        let x = match ne.solve("test") {
            Ok(x) => x,
            Err(e) => panic!("{e}"),
        };
        for c in 0..2 {
            for r in 0..3 {
                assert!((x[c * 3 + r] - x_true[c][r]).abs() < 1e-12, "{x:?}");
            }
        }
    }

    #[test]
    fn singular_system_is_an_error_not_a_panic() {
        let mut ne = NormalEquations::new(2, 1, 3);
        ne.add(0, 0, 1.0);
        ne.add(1, 0, -1.0);
        ne.add(1, 1, 1.0);
        ne.add_rhs(0, 0, 1.0);
        assert!(matches!(
            ne.solve("test"),
            Err(InitError::LinearSolve { stage: "test", .. })
        ));
    }

    #[test]
    fn empty_system_solves_to_nothing() {
        assert_eq!(NormalEquations::new(0, 3, 0).solve("test"), Ok(Vec::new()));
    }
}
