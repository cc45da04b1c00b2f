//! The sparse normal equations `H δ = −g` of a pose graph, in block form.
//!
//! The lower triangle of `H` is stored column-compressed with a fixed pattern (one `D×D` block
//! per free vertex and per pair of free vertices joined by an edge). The fill-reducing ordering
//! and symbolic Cholesky factorisation are computed once; every iteration only refills the
//! values and runs the numeric factorisation (faer's supernodal/simplicial LLᵀ).

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::amd;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use nalgebra::{SMatrix, SVector};

use crate::error::SolveError;
use crate::problem::{EdgeLinearization, FIXED};

/// The factorisation runs on one thread: faer's parallel supernodal factorisation cost more
/// than it saved on every benchmark graph measured (2 cores; cubicle 5.4 → 9.1 s, w10000
/// 0.29 → 0.40 s, with as many again in system time).
const PAR: Par = Par::Seq;

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
///
/// Storage is the lower triangle, column-compressed: block column `c` holds, for each scalar
/// column `c·D + a`, first the diagonal block's rows `c·D + a .. c·D + D`, then the `D` rows of
/// every block row `r > c` joined to `c` (ascending). The diagonal entry is first in its
/// column. Lower is the side faer's supernodal factorisation reads, so it never transposes.
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
}

impl<const D: usize> NormalEquations<D> {
    /// Builds the pattern for `num_free` free vertices and edges given as `(from_slot, to_slot)`
    /// (`FIXED` for a fixed end), and runs the symbolic analysis. The slots must already be in
    /// fill-reducing order ([`fill_reducing_slots`]): no further permutation is applied.
    pub fn new(num_free: usize, edge_slots: &[(u32, u32)]) -> Result<Self, SolveError> {
        let dim = num_free * D;
        // Off-diagonal block rows of each block column (row > column).
        let mut below: Vec<Vec<u32>> = vec![Vec::new(); num_free];
        for &(a, b) in edge_slots {
            if a != FIXED && b != FIXED && a != b {
                below[a.min(b) as usize].push(a.max(b));
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
                    below[lo as usize]
                        .binary_search(&hi)
                        .map_or(u32::MAX, |k| k as u32)
                } else {
                    u32::MAX
                };
                EdgeSlots {
                    from,
                    to,
                    offdiag_rank,
                }
            })
            .collect();
        let (col_ptr, row_idx) = scalar_pattern::<D>(&below, Side::Lower);
        // faer's symbolic analysis reads the upper triangle whatever side it is told when the
        // ordering is the identity, so it gets the transposed block pattern.
        let mut above: Vec<Vec<u32>> = vec![Vec::new(); num_free];
        for (c, rows) in below.iter().enumerate() {
            for &r in rows {
                above[r as usize].push(c as u32);
            }
        }
        let (upper_col_ptr, upper_row_idx) = scalar_pattern::<D>(&above, Side::Upper);
        let pattern =
            SymbolicSparseColMatRef::new_checked(dim, dim, &upper_col_ptr, None, &upper_row_idx);
        let symbolic = factorize_symbolic_cholesky(
            pattern,
            Side::Upper,
            SymmetricOrdering::Identity,
            CholeskySymbolicParams {
                // Pose-graph systems are made of dense D×D blocks: supernodal wins even where
                // faer's flop heuristic would pick simplicial (M3500: 1.7× faster here).
                supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
                ..Default::default()
            },
        )
        .map_err(|e| SolveError::Symbolic(format!("{e:?}")))?;
        let req = StackReq::any_of(&[
            symbolic.factorize_numeric_llt_scratch::<f64>(PAR, Default::default()),
            symbolic.solve_in_place_scratch::<f64>(1, PAR),
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
        })
    }

    /// Number of scalar unknowns.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Index of the diagonal entry of scalar column `i`.
    #[inline]
    fn diagonal_position(&self, i: usize) -> usize {
        self.col_ptr[i]
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

    /// Adds `m` at block (row slot, column slot) with row > column; `rank` is the row's rank
    /// among the column's off-diagonal rows.
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
            let from_free = slots.from != FIXED && slots.from != slots.to;
            if slots.to != FIXED {
                let jt_omega = lin.jacobian_to.transpose() * omega;
                self.add_diagonal_block(slots.to, &(jt_omega * lin.jacobian_to));
                self.add_gradient(slots.to, &(lin.jacobian_to.transpose() * omega_r));
                if slots.offdiag_rank != u32::MAX && slots.to > slots.from {
                    let m = jt_omega * lin.jacobian_from;
                    self.add_offdiagonal_block(slots.from, slots.offdiag_rank, &m);
                }
            }
            if from_free {
                let jf_omega = lin.jacobian_from.transpose() * omega;
                self.add_diagonal_block(slots.from, &(jf_omega * lin.jacobian_from));
                self.add_gradient(slots.from, &(lin.jacobian_from.transpose() * omega_r));
                if slots.offdiag_rank != u32::MAX && slots.from > slots.to {
                    let m = jf_omega * lin.jacobian_to;
                    self.add_offdiagonal_block(slots.to, slots.offdiag_rank, &m);
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
                let p = self.diagonal_position(i);
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
            let req = self.symbolic.solve_in_place_scratch::<f64>(ncols, PAR);
            if let Ok(bigger) = MemBuffer::try_new(StackReq::any_of(&[
                req,
                self.symbolic
                    .factorize_numeric_llt_scratch::<f64>(PAR, Default::default()),
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
            PAR,
            stack,
            Default::default(),
        ) {
            Ok(llt) => llt,
            Err(_) => return false,
        };
        let rhs_mat = MatMut::from_column_major_slice_mut(rhs, dim, ncols);
        llt.solve_in_place_with_conj(Conj::No, rhs_mat, PAR, MemStack::new(&mut self.mem));
        rhs.iter().all(|x| x.is_finite())
    }
}

/// The scalar column-compressed pattern of one triangle of a block-sparse symmetric matrix.
/// `blocks[c]` lists, ascending, the off-diagonal block rows of block column `c` on `side`
/// (rows `> c` for lower, `< c` for upper); the diagonal block's triangle is first in each
/// column for lower, last for upper, so every column's rows ascend.
fn scalar_pattern<const D: usize>(blocks: &[Vec<u32>], side: Side) -> (Vec<usize>, Vec<usize>) {
    let nnz: usize = blocks
        .iter()
        .map(|rows| D * (D + 1) / 2 + D * D * rows.len())
        .sum();
    let mut col_ptr = Vec::with_capacity(blocks.len() * D + 1);
    let mut row_idx = Vec::with_capacity(nnz);
    col_ptr.push(0);
    for (c, rows) in blocks.iter().enumerate() {
        for a in 0..D {
            if side == Side::Lower {
                row_idx.extend((a..D).map(|b| c * D + b));
            }
            for &r in rows {
                row_idx.extend((0..D).map(|b| r as usize * D + b));
            }
            if side == Side::Upper {
                row_idx.extend((0..=a).map(|b| c * D + b));
            }
            col_ptr.push(row_idx.len());
        }
    }
    (col_ptr, row_idx)
}

/// A fill-reducing numbering of `num_free` block unknowns: AMD on the block graph (one node
/// per free vertex, an edge per pair of free vertices sharing an edge). Returns `new_of_old`.
///
/// Ordering blocks rather than scalars keeps each vertex's `D` unknowns together (dense
/// `D`-aligned supernodes), is `D²` times cheaper, and lets the matrix be assembled already
/// permuted, so the numeric factorisation never permutes.
pub(crate) fn fill_reducing_slots(
    num_free: usize,
    edge_slots: &[(u32, u32)],
) -> Result<Vec<u32>, SolveError> {
    let n = num_free;
    let mut below: Vec<Vec<u32>> = vec![Vec::new(); n];
    for &(a, b) in edge_slots {
        if a != FIXED && b != FIXED && a != b {
            below[a.min(b) as usize].push(a.max(b));
        }
    }
    let mut col_ptr = Vec::with_capacity(n + 1);
    let mut row_idx = Vec::new();
    col_ptr.push(0usize);
    for (c, rows) in below.iter_mut().enumerate() {
        rows.sort_unstable();
        rows.dedup();
        row_idx.push(c);
        row_idx.extend(rows.iter().map(|&r| r as usize));
        col_ptr.push(row_idx.len());
    }
    let pattern = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
    let mut forward = vec![0usize; n];
    let mut inverse = vec![0usize; n];
    let mut mem = MemBuffer::try_new(amd::order_scratch::<usize>(n, row_idx.len()))
        .map_err(|e| SolveError::Symbolic(format!("{e:?}")))?;
    amd::order(
        &mut forward,
        &mut inverse,
        pattern,
        amd::Control::default(),
        MemStack::new(&mut mem),
    )
    .map_err(|e| SolveError::Symbolic(format!("{e:?}")))?;
    // `forward[new] = old`, `inverse[old] = new`.
    Ok(inverse.into_iter().map(|new| new as u32).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Dense `H = Σ Jᵀ(wΩ)J` and `g = Σ Jᵀ(wΩ)r` over the free slots, the reference for
    /// the block-sparse assembly.
    fn dense_system<const D: usize>(
        dim: usize,
        edge_slots: &[(u32, u32)],
        lins: &[EdgeLinearization<D>],
        infos: &[SMatrix<f64, D, D>],
        weights: &[f64],
    ) -> (DMatrix<f64>, Vec<f64>) {
        let mut h = DMatrix::zeros(dim, dim);
        let mut g = vec![0.0; dim];
        for (k, &(from, to)) in edge_slots.iter().enumerate() {
            let lin = &lins[k];
            // An edge from a vertex to itself is a prior: only its `to` Jacobian counts.
            let from = if from == to { FIXED } else { from };
            let mut j = DMatrix::zeros(D, dim);
            for (slot, jac) in [(from, lin.jacobian_from), (to, lin.jacobian_to)] {
                if slot != FIXED {
                    let c = slot as usize * D;
                    for a in 0..D {
                        for b in 0..D {
                            j[(a, c + b)] += jac[(a, b)];
                        }
                    }
                }
            }
            let omega = DMatrix::from_fn(D, D, |a, b| weights[k] * infos[k][(a, b)]);
            let r = DMatrix::from_fn(D, 1, |a, _| lin.residual[a]);
            h += j.transpose() * &omega * &j;
            let jg = j.transpose() * &omega * r;
            for (gi, x) in g.iter_mut().zip(jg.iter()) {
                *gi += x;
            }
        }
        (h, g)
    }

    fn check_against_dense<const D: usize>(seed: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let num_free = rng.random_range(1..12usize);
        let slot = |rng: &mut ChaCha8Rng| {
            if rng.random_bool(0.15) {
                FIXED
            } else {
                rng.random_range(0..num_free as u32)
            }
        };
        // A chain keeps every slot constrained; random extra edges, fixed ends, repeats and
        // self-loops exercise every branch of the assembly.
        let mut edge_slots: Vec<(u32, u32)> = (1..num_free as u32).map(|s| (s - 1, s)).collect();
        edge_slots.push((FIXED, 0));
        for _ in 0..rng.random_range(0..3 * num_free) {
            let (a, b) = (slot(&mut rng), slot(&mut rng));
            edge_slots.push((a, b));
        }
        let random_block = |rng: &mut ChaCha8Rng| {
            SMatrix::<f64, D, D>::from_fn(|_, _| rng.random_range(-1.0..1.0))
        };
        let lins: Vec<EdgeLinearization<D>> = edge_slots
            .iter()
            .map(|_| EdgeLinearization {
                residual: SVector::<f64, D>::from_fn(|_, _| rng.random_range(-1.0..1.0)),
                jacobian_from: random_block(&mut rng),
                jacobian_to: random_block(&mut rng) + SMatrix::<f64, D, D>::identity() * 2.0,
                chi2: 0.0,
            })
            .collect();
        let infos: Vec<SMatrix<f64, D, D>> = edge_slots
            .iter()
            .map(|_| {
                let a = random_block(&mut rng);
                a * a.transpose() + SMatrix::<f64, D, D>::identity()
            })
            .collect();
        let weights: Vec<f64> = edge_slots
            .iter()
            .map(|_| {
                if rng.random_bool(0.1) {
                    0.0
                } else {
                    rng.random_range(0.1..1.0)
                }
            })
            .collect();
        // The chain and its anchor keep full weight, so H stays positive definite.
        let weights: Vec<f64> = weights
            .iter()
            .enumerate()
            .map(|(k, w)| if k < num_free { 1.0 } else { *w })
            .collect();

        let mut normal = NormalEquations::<D>::new(num_free, &edge_slots).expect("pattern");
        normal.assemble(&lins, infos.iter().copied(), &weights);
        let dim = num_free * D;
        let (h, g) = dense_system(dim, &edge_slots, &lins, &infos, &weights);
        for c in 0..dim {
            for p in normal.col_ptr[c]..normal.col_ptr[c + 1] {
                let r = normal.row_idx[p];
                assert!(
                    r >= c,
                    "seed {seed}: row {r} above the diagonal in column {c}"
                );
                let expected = h[(r, c)];
                assert!(
                    (normal.values[p] - expected).abs() <= 1e-9 * (1.0 + expected.abs()),
                    "seed {seed}: H[{r},{c}] = {} against {expected}",
                    normal.values[p]
                );
            }
            assert_eq!(
                normal.row_idx[normal.diagonal_position(c)],
                c,
                "seed {seed}"
            );
        }
        for (a, b) in normal.gradient.iter().zip(&g) {
            assert!(
                (a - b).abs() <= 1e-9 * (1.0 + b.abs()),
                "seed {seed}: g {a} against {b}"
            );
        }
        // Every nonzero of the dense H is in the pattern.
        let stored: usize = (0..dim)
            .map(|c| (c..dim).filter(|&r| h[(r, c)] != 0.0).count())
            .sum();
        let in_pattern: usize = normal.values.iter().filter(|v| **v != 0.0).count();
        assert_eq!(stored, in_pattern, "seed {seed}");

        let mut step = Vec::new();
        assert!(normal.solve_damped(0.0, &mut step), "seed {seed}");
        let expected = h
            .clone()
            .cholesky()
            .expect("positive definite")
            .solve(&DMatrix::from_fn(dim, 1, |i, _| -g[i]));
        for (a, b) in step.iter().zip(expected.iter()) {
            assert!(
                (a - b).abs() <= 1e-7 * (1.0 + b.abs()),
                "seed {seed}: δ {a} against {b}"
            );
        }
    }

    #[test]
    fn the_lower_triangle_and_its_solution_match_a_dense_assembly() {
        for seed in 0..40 {
            check_against_dense::<3>(seed);
            check_against_dense::<6>(seed);
        }
    }
}
