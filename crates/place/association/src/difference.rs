//! The cosine difference matrix between two segments (Yin et al., AutoMerge, Sec. V-A:
//! `D = d(f_i, f_j) ∈ R^{N_i × N_j}`, `d` the cosine distance), computed as one blocked f32
//! matrix product `D = 1 − A Bᵀ` of the row-normalised descriptor matrices.
//!
//! The product is organised like BLIS: `B` is packed once into k-major panels of [`NR`] columns,
//! output rows are split into blocks of [`MC`] rows computed in parallel (rayon), and inside a
//! block every packed panel stays in L1 while strips of [`MR`] rows of `A` stream past it. The
//! micro-kernel keeps an `MR × NR` tile of dot products in registers: AVX2 + FMA on x86_64 when
//! the CPU has them (runtime detection), otherwise a portable kernel written so LLVM vectorises
//! it for the baseline target.

use rayon::prelude::*;

/// Errors of the association crate.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum AssociationError {
    /// A descriptor dimension of zero.
    #[error("descriptor dimension must be positive")]
    ZeroDimension,
    /// The flat descriptor data does not split into rows of the dimension.
    #[error("descriptor data has {len} values, not a multiple of the dimension {dim}")]
    RaggedData { len: usize, dim: usize },
    /// A NaN or infinite descriptor component.
    #[error("descriptor row {row}, component {component} is not finite ({value})")]
    NonFinite {
        row: usize,
        component: usize,
        value: f32,
    },
    /// Two descriptor matrices (or a matrix and its data) that do not fit together.
    #[error("dimension mismatch: {what} is {found}, expected {expected}")]
    DimensionMismatch {
        what: &'static str,
        found: usize,
        expected: usize,
    },
    /// A parameter outside its valid range.
    #[error(transparent)]
    InvalidParams(#[from] mapmerge_params::ParamError),
}

/// Rows of the register tile of the micro-kernel.
pub const MR: usize = 6;
/// Columns of the register tile (two AVX2 vectors) = width of a packed panel of `B`.
pub const NR: usize = 16;
/// Output rows per parallel block (a multiple of [`MR`]); the block's rows of `A` stay in L2.
pub const MC: usize = 96;
/// Descriptor components per pass over a packed panel (a panel chunk of `KC × NR` f32 = 16 KiB
/// stays in L1).
pub const KC: usize = 256;

/// One segment's submap descriptors: `rows` rows of `dim` f32, row-major, every row scaled to
/// unit L2 norm at construction (all-zero rows stay zero: their cosine difference to anything is
/// 1).
#[derive(Clone, Debug, PartialEq)]
pub struct DescriptorMatrix {
    dim: usize,
    rows: usize,
    data: Vec<f32>,
}

impl DescriptorMatrix {
    /// Takes `data.len() / dim` descriptors of `dim` components, row-major, and normalises each
    /// row. Errors on `dim == 0`, a length that is not a multiple of `dim`, or a non-finite value.
    pub fn new(dim: usize, mut data: Vec<f32>) -> Result<Self, AssociationError> {
        if dim == 0 {
            return Err(AssociationError::ZeroDimension);
        }
        if data.len() % dim != 0 {
            return Err(AssociationError::RaggedData {
                len: data.len(),
                dim,
            });
        }
        if let Some(index) = data.iter().position(|v| !v.is_finite()) {
            return Err(AssociationError::NonFinite {
                row: index / dim,
                component: index % dim,
                value: data[index],
            });
        }
        for row in data.chunks_exact_mut(dim) {
            // f64 so that large finite components cannot overflow the squared norm.
            let norm = row
                .iter()
                .map(|&v| f64::from(v) * f64::from(v))
                .sum::<f64>()
                .sqrt();
            if norm > 0.0 {
                let inv_norm = 1.0 / norm;
                for v in row.iter_mut() {
                    *v = (f64::from(*v) * inv_norm) as f32;
                }
            }
        }
        let rows = data.len() / dim;
        Ok(Self { dim, rows, data })
    }

    /// Components per descriptor.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Number of descriptors (submaps).
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// True when there are no descriptors.
    pub fn is_empty(&self) -> bool {
        self.rows == 0
    }

    /// Descriptor `i` (unit norm or all zero). Panics if `i >= rows()`, like slice indexing.
    pub fn row(&self, i: usize) -> &[f32] {
        &self.data[i * self.dim..(i + 1) * self.dim]
    }

    /// All descriptors, row-major.
    pub fn as_slice(&self) -> &[f32] {
        &self.data
    }
}

/// `D_ij = 1 − cos(a_i, b_j)` ∈ [0, 2] for every submap `i` of the query segment (rows) and `j`
/// of the reference segment (columns), row-major.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DifferenceMatrix {
    rows: usize,
    cols: usize,
    data: Vec<f32>,
}

impl DifferenceMatrix {
    /// An empty matrix, to be filled by [`difference_matrix_into`].
    pub fn empty() -> Self {
        Self::default()
    }

    /// Wraps `rows × cols` row-major values (e.g. a matrix computed elsewhere, or a test
    /// fixture). Errors when the length does not match or a value is NaN.
    pub fn from_vec(rows: usize, cols: usize, data: Vec<f32>) -> Result<Self, AssociationError> {
        let expected = rows.checked_mul(cols).ok_or_else(|| {
            AssociationError::InvalidParams(mapmerge_params::ParamError {
                field: "rows × cols".into(),
                value: format!("{rows} × {cols}"),
                allowed: "the product must fit in usize".into(),
            })
        })?;
        if data.len() != expected {
            return Err(AssociationError::DimensionMismatch {
                what: "difference matrix data length",
                found: data.len(),
                expected,
            });
        }
        if let Some(index) = data.iter().position(|v| v.is_nan()) {
            return Err(AssociationError::NonFinite {
                row: index / cols.max(1),
                component: index % cols.max(1),
                value: f32::NAN,
            });
        }
        Ok(Self { rows, cols, data })
    }

    /// Query submaps (rows).
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Reference submaps (columns).
    pub fn cols(&self) -> usize {
        self.cols
    }

    /// `D_ij`, or `None` outside the matrix.
    pub fn get(&self, i: usize, j: usize) -> Option<f32> {
        if i < self.rows && j < self.cols {
            Some(self.data[i * self.cols + j])
        } else {
            None
        }
    }

    /// Row `i` (query submap `i` against every reference submap). Panics if `i >= rows()`, like
    /// slice indexing.
    pub fn row(&self, i: usize) -> &[f32] {
        &self.data[i * self.cols..(i + 1) * self.cols]
    }

    /// All values, row-major.
    pub fn as_slice(&self) -> &[f32] {
        &self.data
    }

    /// Mutable access to all values, row-major (e.g. for contrast enhancement in place).
    pub fn as_mut_slice(&mut self) -> &mut [f32] {
        &mut self.data
    }
}

/// The difference matrix between query descriptors `a` (rows) and reference descriptors `b`
/// (columns). Errors when the descriptor dimensions differ.
pub fn difference_matrix(
    a: &DescriptorMatrix,
    b: &DescriptorMatrix,
) -> Result<DifferenceMatrix, AssociationError> {
    let mut out = DifferenceMatrix::empty();
    difference_matrix_into(&mut out, a, b)?;
    Ok(out)
}

/// [`difference_matrix`] into `out`, reusing its buffer (no allocation once it is large enough,
/// apart from the packed copy of `b`).
pub fn difference_matrix_into(
    out: &mut DifferenceMatrix,
    a: &DescriptorMatrix,
    b: &DescriptorMatrix,
) -> Result<(), AssociationError> {
    if a.dim != b.dim {
        return Err(AssociationError::DimensionMismatch {
            what: "reference descriptor dimension",
            found: b.dim,
            expected: a.dim,
        });
    }
    let (rows, cols, dim) = (a.rows, b.rows, a.dim);
    out.rows = rows;
    out.cols = cols;
    out.data.clear();
    out.data.resize(rows * cols, 0.0);
    if rows == 0 || cols == 0 {
        return Ok(());
    }
    let packed = pack_panels(b);
    let kernel = Kernel::detect();
    out.data
        .par_chunks_mut(MC * cols)
        .enumerate()
        .for_each(|(block, out_block)| {
            let row0 = block * MC;
            let block_rows = out_block.len() / cols;
            let a_block = &a.data[row0 * dim..(row0 + block_rows) * dim];
            compute_block(kernel, a_block, block_rows, &packed, cols, dim, out_block);
        });
    Ok(())
}

/// `b` packed into `ceil(cols / NR)` panels; panel `p` holds columns `p·NR ..` k-major
/// (`panel[k·NR + l] = b[p·NR + l][k]`), zero-padded past the last column.
fn pack_panels(b: &DescriptorMatrix) -> Vec<f32> {
    let (cols, dim) = (b.rows, b.dim);
    let panel_count = cols.div_ceil(NR);
    let mut packed = vec![0.0f32; panel_count * dim * NR];
    packed
        .par_chunks_mut(dim * NR)
        .enumerate()
        .for_each(|(p, panel)| {
            for l in 0..NR.min(cols - p * NR) {
                let column = b.row(p * NR + l);
                for (k, &v) in column.iter().enumerate() {
                    panel[k * NR + l] = v;
                }
            }
        });
    packed
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kernel {
    Portable,
    #[cfg(target_arch = "x86_64")]
    Avx2Fma,
}

impl Kernel {
    fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
                return Kernel::Avx2Fma;
            }
        }
        Kernel::Portable
    }
}

/// One block of output rows: `out_block` = `block_rows × cols`, `a_block` its rows of `A`.
fn compute_block(
    kernel: Kernel,
    a_block: &[f32],
    block_rows: usize,
    packed: &[f32],
    cols: usize,
    dim: usize,
    out_block: &mut [f32],
) {
    let mut tile = [[0.0f32; NR]; MR];
    let panel_count = cols.div_ceil(NR);
    let mut k0 = 0;
    while k0 < dim {
        let k1 = (k0 + KC).min(dim);
        let (first, last) = (k0 == 0, k1 == dim);
        for p in 0..panel_count {
            let panel = &packed[p * dim * NR..(p + 1) * dim * NR];
            let col0 = p * NR;
            let width = NR.min(cols - col0);
            let mut r0 = 0;
            while r0 < block_rows {
                let strip_rows = MR.min(block_rows - r0);
                let a_strip = &a_block[r0 * dim..(r0 + strip_rows) * dim];
                micro_tile(kernel, strip_rows, a_strip, dim, k0, k1, panel, &mut tile);
                for (r, tile_row) in tile.iter().enumerate().take(strip_rows) {
                    let out = &mut out_block[(r0 + r) * cols + col0..][..width];
                    store_tile_row(out, &tile_row[..width], first, last);
                }
                r0 += MR;
            }
        }
        k0 = k1;
    }
}

/// Accumulates a partial dot-product tile into the output; on the last `k` chunk converts the
/// dot products to cosine differences `1 − cos`, clamped to [0, 2] against rounding.
#[inline(always)]
fn store_tile_row(out: &mut [f32], dots: &[f32], first: bool, last: bool) {
    for (o, &dot) in out.iter_mut().zip(dots) {
        let sum = if first { dot } else { *o + dot };
        *o = if last {
            (1.0 - sum).clamp(0.0, 2.0)
        } else {
            sum
        };
    }
}

/// Dispatches the `rows × NR` micro-kernel (rows ≤ MR) to the const-generic instance.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn micro_tile(
    kernel: Kernel,
    rows: usize,
    a: &[f32],
    dim: usize,
    k0: usize,
    k1: usize,
    panel: &[f32],
    tile: &mut [[f32; NR]; MR],
) {
    macro_rules! dispatch {
        ($r:literal) => {
            match kernel {
                Kernel::Portable => micro_portable::<$r>(a, dim, k0, k1, panel, tile),
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `Avx2Fma` is only chosen when the CPU reports AVX2 and FMA.
                Kernel::Avx2Fma => unsafe { micro_avx2::<$r>(a, dim, k0, k1, panel, tile) },
            }
        };
    }
    match rows {
        6 => dispatch!(6),
        5 => dispatch!(5),
        4 => dispatch!(4),
        3 => dispatch!(3),
        2 => dispatch!(2),
        _ => dispatch!(1),
    }
}

/// Portable micro-kernel: `tile[r][l] = Σ_{k0 ≤ k < k1} a[r][k] · panel[k][l]`; fixed-width
/// accumulator rows that LLVM keeps in vector registers.
#[inline(always)]
fn micro_portable<const R: usize>(
    a: &[f32],
    dim: usize,
    k0: usize,
    k1: usize,
    panel: &[f32],
    tile: &mut [[f32; NR]; MR],
) {
    let mut acc = [[0.0f32; NR]; R];
    let panel_chunk = &panel[k0 * NR..k1 * NR];
    for (dk, b) in panel_chunk.chunks_exact(NR).enumerate() {
        let k = k0 + dk;
        for (r, acc_row) in acc.iter_mut().enumerate() {
            let a_rk = a[r * dim + k];
            for (c, &b_l) in acc_row.iter_mut().zip(b) {
                *c += a_rk * b_l;
            }
        }
    }
    tile[..R].copy_from_slice(&acc);
}

/// AVX2 + FMA micro-kernel: `R × 16` accumulators in `2R` ymm registers, one broadcast of
/// `a[r][k]` and two panel loads per `k`.
///
/// # Safety
/// The CPU must support AVX2 and FMA. Slice bounds are checked on entry.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn micro_avx2<const R: usize>(
    a: &[f32],
    dim: usize,
    k0: usize,
    k1: usize,
    panel: &[f32],
    tile: &mut [[f32; NR]; MR],
) {
    use std::arch::x86_64::{
        __m256, _mm256_broadcast_ss, _mm256_fmadd_ps, _mm256_loadu_ps, _mm256_setzero_ps,
        _mm256_storeu_ps,
    };
    if R == 0 || R > MR || k0 > k1 || a.len() < (R - 1) * dim + k1 || panel.len() < k1 * NR {
        return;
    }
    let mut c0: [__m256; R] = [_mm256_setzero_ps(); R];
    let mut c1: [__m256; R] = [_mm256_setzero_ps(); R];
    let a_ptr = a.as_ptr();
    let b_ptr = panel.as_ptr();
    for k in k0..k1 {
        // SAFETY: k < k1 ≤ panel.len() / NR and (R − 1)·dim + k < a.len(), checked above.
        unsafe {
            let b0 = _mm256_loadu_ps(b_ptr.add(k * NR));
            let b1 = _mm256_loadu_ps(b_ptr.add(k * NR + 8));
            for r in 0..R {
                let a_rk = _mm256_broadcast_ss(&*a_ptr.add(r * dim + k));
                c0[r] = _mm256_fmadd_ps(a_rk, b0, c0[r]);
                c1[r] = _mm256_fmadd_ps(a_rk, b1, c1[r]);
            }
        }
    }
    for r in 0..R {
        // SAFETY: each tile row holds NR = 16 f32.
        unsafe {
            _mm256_storeu_ps(tile[r].as_mut_ptr(), c0[r]);
            _mm256_storeu_ps(tile[r].as_mut_ptr().add(8), c1[r]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn naive(a: &DescriptorMatrix, b: &DescriptorMatrix) -> Vec<f64> {
        let mut out = Vec::with_capacity(a.rows() * b.rows());
        for i in 0..a.rows() {
            for j in 0..b.rows() {
                let dot: f64 = a
                    .row(i)
                    .iter()
                    .zip(b.row(j))
                    .map(|(&x, &y)| f64::from(x) * f64::from(y))
                    .sum();
                out.push(1.0 - dot);
            }
        }
        out
    }

    fn random_matrix(rng: &mut ChaCha8Rng, rows: usize, dim: usize) -> DescriptorMatrix {
        let data = (0..rows * dim)
            .map(|_| rng.random_range(-1.0f32..1.0))
            .collect();
        DescriptorMatrix::new(dim, data).unwrap()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        #[test]
        fn blocked_product_equals_naive_double_loop(
            rows in 0usize..130, cols in 0usize..70, dim in 1usize..300, seed in any::<u64>()
        ) {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let a = random_matrix(&mut rng, rows, dim);
            let b = random_matrix(&mut rng, cols, dim);
            let d = difference_matrix(&a, &b).unwrap();
            prop_assert_eq!((d.rows(), d.cols()), (rows, cols));
            for (got, want) in d.as_slice().iter().zip(naive(&a, &b)) {
                prop_assert!((f64::from(*got) - want).abs() < 1e-5, "{} vs {}", got, want);
            }
        }
    }

    #[test]
    fn portable_kernel_equals_detected_kernel() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (rows, cols, dim) = (101, 45, 300);
        let a = random_matrix(&mut rng, rows, dim);
        let b = random_matrix(&mut rng, cols, dim);
        let packed = pack_panels(&b);
        let mut portable = vec![0.0; rows * cols];
        compute_block(
            Kernel::Portable,
            a.as_slice(),
            rows,
            &packed,
            cols,
            dim,
            &mut portable,
        );
        let detected = difference_matrix(&a, &b).unwrap();
        for (x, y) in portable.iter().zip(detected.as_slice()) {
            assert!((x - y).abs() < 1e-5);
        }
    }

    #[test]
    fn zero_rows_are_at_distance_one_and_identical_rows_at_zero() {
        let a = DescriptorMatrix::new(3, vec![0.0, 0.0, 0.0, 2.0, 0.0, 0.0]).unwrap();
        let b =
            DescriptorMatrix::new(3, vec![5.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0]).unwrap();
        let d = difference_matrix(&a, &b).unwrap();
        assert_eq!(d.row(0), &[1.0, 1.0, 1.0]);
        assert_eq!(d.row(1), &[0.0, 1.0, 2.0]);
        assert_eq!(d.get(1, 2), Some(2.0));
        assert_eq!(d.get(2, 0), None);
    }

    #[test]
    fn into_reuses_and_resizes_the_buffer() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let (a, b) = (
            random_matrix(&mut rng, 20, 8),
            random_matrix(&mut rng, 30, 8),
        );
        let mut out = DifferenceMatrix::empty();
        difference_matrix_into(&mut out, &a, &b).unwrap();
        assert_eq!(out, difference_matrix(&a, &b).unwrap());
        difference_matrix_into(&mut out, &b, &a).unwrap();
        assert_eq!((out.rows(), out.cols()), (30, 20));
        assert_eq!(out, difference_matrix(&b, &a).unwrap());
    }

    #[test]
    fn bad_input_is_an_error() {
        assert_eq!(
            DescriptorMatrix::new(0, vec![]),
            Err(AssociationError::ZeroDimension)
        );
        assert_eq!(
            DescriptorMatrix::new(3, vec![1.0; 4]),
            Err(AssociationError::RaggedData { len: 4, dim: 3 })
        );
        assert!(matches!(
            DescriptorMatrix::new(2, vec![1.0, 0.0, f32::NAN, 1.0]),
            Err(AssociationError::NonFinite {
                row: 1,
                component: 0,
                ..
            })
        ));
        let a = DescriptorMatrix::new(2, vec![1.0, 0.0]).unwrap();
        let b = DescriptorMatrix::new(3, vec![1.0, 0.0, 0.0]).unwrap();
        assert!(matches!(
            difference_matrix(&a, &b),
            Err(AssociationError::DimensionMismatch { .. })
        ));
        assert!(DifferenceMatrix::from_vec(2, 2, vec![0.0; 3]).is_err());
        assert!(DifferenceMatrix::from_vec(1, 2, vec![0.0, f32::NAN]).is_err());
    }

    #[test]
    fn huge_finite_components_normalise_without_overflow() {
        let a = DescriptorMatrix::new(2, vec![f32::MAX, f32::MAX]).unwrap();
        let norm: f32 = a.row(0).iter().map(|v| v * v).sum::<f32>().sqrt();
        assert!((norm - 1.0).abs() < 1e-6);
    }
}
