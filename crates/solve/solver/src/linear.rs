//! The sparse normal equations `H δ = −g` of a pose graph, in block form.
//!
//! The lower triangle of `H` is stored column-compressed with a fixed pattern (one `D×D` block
//! per free vertex and per pair of free vertices joined by an edge). The fill-reducing ordering
//! and symbolic Cholesky factorisation are computed once; every iteration only refills the
//! values and runs the numeric factorisation (faer's supernodal/simplicial LLᵀ).

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, SymbolicCholesky,
    SymmetricOrdering,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::{Conj, MatMut, Par, Side};
use nalgebra::{SMatrix, SVector};

use crate::error::SolveError;
use crate::problem::{EdgeLinearization, FIXED};

/// Where one edge's blocks go.
#[derive(Clone, Copy, Debug)]
struct EdgeSlots {
    from: u32,
    to: u32,
    /// Rank of the larger slot among the off-diagonal rows of the smaller slot's column, or
    /// `u32::MAX` when the edge has no off-diagonal block.
    offdiag_rank: u32,
}

/// The normal equations and their reusable factorisation.
pub(crate) struct NormalEquations<const D: usize> {
    dim: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    /// Lower triangle of `H`, filled by [`NormalEquations::assemble`].
    pub values: Vec<f64>,
    /// Damped copy handed to the factorisation.
    damped: Vec<f64>,
    /// `g = Jᵀ W r`.
    pub gradient: Vec<f64>,
    slots: Vec<EdgeSlots>,
    symbolic: SymbolicCholesky<usize>,
    factor_values: Vec<f64>,
    mem: MemBuffer,
    par: Par,
}

impl<const D: usize> NormalEquations<D> {
    /// Builds the pattern for `num_free` free vertices and edges given as `(from_slot, to_slot)`
    /// (`FIXED` for a fixed end), and runs the symbolic analysis.
    pub fn new(num_free: usize, edge_slots: &[(u32, u32)]) -> Result<Self, SolveError> {
        let dim = num_free * D;
        // Off-diagonal block rows of each block column (row > column).
        let mut below: Vec<Vec<u32>> = vec![Vec::new(); num_free];
        for &(a, b) in edge_slots {
            if a != FIXED && b != FIXED && a != b {
                let (lo, hi) = (a.min(b), a.max(b));
                below[lo as usize].push(hi);
            }
        }
        for rows in &mut below {
            rows.sort_unstable();
            rows.dedup();
        }
        let slots = edge_slots
            .iter()
            .map(|&(from, to)| {
                let offdiag_rank = if from != FIXED && to != FIXED && from != to {
                    let (lo, hi) = (from.min(to), from.max(to));
                    below[lo as usize].binary_search(&hi).map_or(u32::MAX, |k| k as u32)
                } else {
                    u32::MAX
                };
                EdgeSlots { from, to, offdiag_rank }
            })
            .collect();
        let nnz: usize = below
            .iter()
            .map(|rows| D * (D + 1) / 2 + D * D * rows.len())
            .sum();
        let mut col_ptr = Vec::with_capacity(dim + 1);
        let mut row_idx = Vec::with_capacity(nnz);
        col_ptr.push(0);
        for (c, rows) in below.iter().enumerate() {
            for a in 0..D {
                for b in a..D {
                    row_idx.push(c * D + b);
                }
                for &r in rows {
                    row_idx.extend((0..D).map(|b| r as usize * D + b));
                }
                col_ptr.push(row_idx.len());
            }
        }
        let pattern = SymbolicSparseColMatRef::new_checked(dim, dim, &col_ptr, None, &row_idx);
        let symbolic = factorize_symbolic_cholesky(
            pattern,
            Side::Lower,
            SymmetricOrdering::Amd,
            CholeskySymbolicParams::default(),
        )
        .map_err(|e| SolveError::Symbolic(format!("{e:?}")))?;
        let par = if dim > 20_000 { Par::rayon(0) } else { Par::Seq };
        let req = StackReq::any_of(&[
            symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default()),
            symbolic.solve_in_place_scratch::<f64>(1, par),
        ]);
        let mem = MemBuffer::try_new(req).map_err(|e| SolveError::Symbolic(format!("{e:?}")))?;
        let factor_values = vec![0.0; symbolic.len_val()];
        Ok(Self {
            dim,
            values: vec![0.0; row_idx.len()],
            damped: vec![0.0; row_idx.len()],
            gradient: vec![0.0; dim],
            col_ptr,
            row_idx,
            slots,
            symbolic,
            factor_values,
            mem,
            par,
        })
    }

    /// Number of scalar unknowns.
    pub fn dim(&self) -> usize {
        self.dim
    }

    #[inline]
    fn add_diagonal_block(&mut self, slot: u32, m: &SMatrix<f64, D, D>) {
        let c = slot as usize * D;
        for a in 0..D {
            let base = self.col_ptr[c + a];
            for b in a..D {
                self.values[base + b - a] += m[(b, a)];
            }
        }
    }

    /// Adds `m` at block (row slot, column slot) with row > column.
    #[inline]
    fn add_offdiagonal_block(&mut self, col_slot: u32, rank: u32, m: &SMatrix<f64, D, D>) {
        let c = col_slot as usize * D;
        for a in 0..D {
            let base = self.col_ptr[c + a] + (D - a) + rank as usize * D;
            for b in 0..D {
                self.values[base + b] += m[(b, a)];
            }
        }
    }

    #[inline]
    fn add_gradient(&mut self, slot: u32, g: &SVector<f64, D>) {
        let start = slot as usize * D;
        for (dst, src) in self.gradient[start..start + D].iter_mut().zip(g.iter()) {
            *dst += src;
        }
    }

    /// Fills `H = Σ Jᵀ (w Ω) J` and `g = Σ Jᵀ (w Ω) r` from per-edge linearisations, informations
    /// and weights.
    pub fn assemble(
        &mut self,
        linearizations: &[EdgeLinearization<D>],
        informations: impl Iterator<Item = SMatrix<f64, D, D>>,
        weights: &[f64],
    ) {
        self.values.iter_mut().for_each(|v| *v = 0.0);
        self.gradient.iter_mut().for_each(|v| *v = 0.0);
        for (k, (lin, info)) in linearizations.iter().zip(informations).enumerate() {
            let w = weights[k];
            if w == 0.0 {
                continue;
            }
            let slots = self.slots[k];
            let omega = info * w;
            let omega_r = omega * lin.residual;
            if slots.to != FIXED {
                let jt_omega = lin.jacobian_to.transpose() * omega;
                self.add_diagonal_block(slots.to, &(jt_omega * lin.jacobian_to));
                self.add_gradient(slots.to, &(lin.jacobian_to.transpose() * omega_r));
                if slots.offdiag_rank != u32::MAX && slots.to > slots.from {
                    self.add_offdiagonal_block(
                        slots.from,
                        slots.offdiag_rank,
                        &(jt_omega * lin.jacobian_from),
                    );
                }
            }
            if slots.from != FIXED && slots.from != slots.to {
                let jf_omega = lin.jacobian_from.transpose() * omega;
                self.add_diagonal_block(slots.from, &(jf_omega * lin.jacobian_from));
                self.add_gradient(slots.from, &(lin.jacobian_from.transpose() * omega_r));
                if slots.offdiag_rank != u32::MAX && slots.from > slots.to {
                    self.add_offdiagonal_block(
                        slots.to,
                        slots.offdiag_rank,
                        &(jf_omega * lin.jacobian_to),
                    );
                }
            }
        }
    }

    /// `max |g_i|`.
    pub fn gradient_max_abs(&self) -> f64 {
        self.gradient.iter().fold(0.0f64, |m, g| m.max(g.abs()))
    }

    /// Solves `(H + λ·diag(H)) δ = −g` into `step` (Marquardt damping; `λ = 0` is Gauss–Newton).
    /// Returns `false` when the damped matrix is not numerically positive definite.
    pub fn solve_damped(&mut self, lambda: f64, step: &mut Vec<f64>) -> bool {
        self.damped.copy_from_slice(&self.values);
        if lambda > 0.0 {
            for i in 0..self.dim {
                let p = self.col_ptr[i];
                let d = self.values[p].max(1e-9);
                self.damped[p] += lambda * d;
            }
        }
        step.clear();
        step.extend(self.gradient.iter().map(|g| -g));
        self.factor_and_solve(step.as_mut_slice(), 1)
    }

    /// Factorises the undamped `H` and solves `H X = B` in place for `B` with `ncols` columns
    /// stored column-major in `rhs`.
    pub fn solve_undamped(&mut self, rhs: &mut [f64], ncols: usize) -> bool {
        self.damped.copy_from_slice(&self.values);
        self.factor_and_solve(rhs, ncols)
    }

    fn factor_and_solve(&mut self, rhs: &mut [f64], ncols: usize) -> bool {
        let dim = self.dim;
        if dim == 0 {
            return true;
        }
        let pattern =
            SymbolicSparseColMatRef::new_checked(dim, dim, &self.col_ptr, None, &self.row_idx);
        let matrix = SparseColMatRef::new(pattern, &self.damped);
        if ncols > 1 {
            let req = self.symbolic.solve_in_place_scratch::<f64>(ncols, self.par);
            if let Ok(bigger) = MemBuffer::try_new(StackReq::any_of(&[
                req,
                self.symbolic.factorize_numeric_llt_scratch::<f64>(self.par, Default::default()),
            ])) {
                self.mem = bigger;
            } else {
                return false;
            }
        }
        let stack = MemStack::new(&mut self.mem);
        let llt = match self.symbolic.factorize_numeric_llt(
            &mut self.factor_values,
            matrix,
            Side::Lower,
            LltRegularization::default(),
            self.par,
            stack,
            Default::default(),
        ) {
            Ok(llt) => llt,
            Err(_) => return false,
        };
        let rhs_mat = MatMut::from_column_major_slice_mut(rhs, dim, ncols);
        llt.solve_in_place_with_conj(Conj::No, rhs_mat, self.par, MemStack::new(&mut self.mem));
        rhs.iter().all(|x| x.is_finite())
    }
}
