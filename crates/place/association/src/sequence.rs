//! Sequence matching (SeqSLAM, Milford & Wyeth 2012, AutoMerge's ref. [9]) and single-frame
//! matches on a [`DifferenceMatrix`] (Yin et al., AutoMerge, Sec. V-A: `C_seq` from sequence
//! matching for long overlaps, single-frame candidates for short ones).
//!
//! Sequence search: for query submap `i` a window of `ds` consecutive query rows around `i`, and
//! for every reference submap `j` and velocity `v` the straight line through `(i, j)` that visits
//! column `j + round(v·(r − i))` in row `r`; its score is the mean difference along the line.
//! Negative velocities are the reverse traversal (AutoMerge takes the minimum over forward and
//! reverse). The best `(j, v)` is accepted when its score is low enough and clearly better than
//! the best line outside a window around `j` (SeqSLAM's uniqueness test).
//!
//! Cost: for one velocity the offsets `round(v·(r − i))` do not depend on `j`, so all lines of a
//! query are sums of `ds` shifted, contiguous row slices, accumulated in fixed-width registers
//! (no stores until the line is complete). Identical offset patterns of different velocities
//! and phases are searched once. Queries run in parallel (rayon).

use crate::difference::{AssociationError, DifferenceMatrix};
use crate::SubmapMatch;
use mapmerge_params::{Checker, Real, Validate};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Parameters of [`sequence_matches`]. Defaults suit submaps every ~1 m indoors.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SequenceParams {
    /// Sequence length `ds` in query submaps (default 10). Longer sequences reject more
    /// aliasing but miss overlaps shorter than about `ds / 2` and cost linearly more.
    pub sequence_length: usize,
    /// Slowest relative velocity searched, reference submaps per query submap (default 0.8).
    pub velocity_min: f32,
    /// Fastest relative velocity searched (default 1.25). Submaps are spaced by distance, so
    /// velocities stay near 1; widen only for different submap spacings.
    pub velocity_max: f32,
    /// Velocities searched per direction, geometrically spaced in `[velocity_min, velocity_max]`
    /// (default 3: 0.8, 1.0, 1.25). With `ds = 10` these already reach every integer end offset
    /// of the range; the phases below fill in between. Cost grows with the distinct lines.
    pub velocity_steps: usize,
    /// Also search negative velocities, i.e. the reference traversing the place in reverse
    /// (default true).
    pub reverse: bool,
    /// Sub-submap phases per velocity (default 2): lines through `(i, j + δ)` with `δ` evenly
    /// spread in (−½, ½), sampled at the nearest column. With one phase a line of velocity ≠ 1
    /// whose true crossing of row `i` is half-way between two columns is sampled one column off
    /// for part of its length. Phases that give the same columns (always at |v| = 1) are searched
    /// once.
    pub velocity_phases: usize,
    /// Acceptance threshold on the mean cosine difference along the best line (default 0.6).
    /// Descriptor-dependent. A line centred just past the end of an overlap still has half its
    /// samples on the overlap, so a loose threshold lets matches run up to `ds / 2` submaps past
    /// the overlap's ends.
    pub max_score: f32,
    /// Uniqueness: accept only when `best ≤ max_uniqueness_ratio · rival`, the rival being the
    /// best line whose reference index lies outside `exclusion_radius` of the best (default
    /// 0.8; lower is stricter).
    pub max_uniqueness_ratio: f32,
    /// Half-width in reference submaps of the window excluded when looking for the rival
    /// (default 10).
    pub exclusion_radius: usize,
    /// SeqSLAM's local contrast enhancement: when > 0, lines are ranked on the difference matrix
    /// normalised per row by the mean and standard deviation of the `2·w + 1` references around
    /// each column (default 0 = off). Thresholds and the reported distance stay on the raw
    /// cosine differences. Helps when some places look like everything (low contrast rows).
    pub contrast_window: usize,
}

impl Default for SequenceParams {
    fn default() -> Self {
        Self {
            sequence_length: 10,
            velocity_min: 0.8,
            velocity_max: 1.25,
            velocity_steps: 3,
            reverse: true,
            velocity_phases: 2,
            max_score: 0.6,
            max_uniqueness_ratio: 0.8,
            exclusion_radius: 10,
            contrast_window: 0,
        }
    }
}

impl SequenceParams {
    /// Checks ranges; every public entry point calls it.
    pub fn validate(&self) -> Result<(), AssociationError> {
        Ok(Validate::validate(self)?)
    }

    /// The signed velocities searched: forward ones, then (if `reverse`) their negatives.
    pub fn velocities(&self) -> Vec<f32> {
        let steps = self.velocity_steps.max(1);
        let ratio = self.velocity_max / self.velocity_min;
        let forward = (0..steps).map(|s| {
            if steps == 1 {
                self.velocity_min
            } else {
                self.velocity_min * ratio.powf(s as f32 / (steps - 1) as f32)
            }
        });
        let mut velocities: Vec<f32> = forward.collect();
        if self.reverse {
            let reverse: Vec<f32> = velocities.iter().map(|v| -v).collect();
            velocities.extend(reverse);
        }
        velocities
    }
}

/// Parameters of [`single_frame_matches`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SingleFrameParams {
    /// Acceptance threshold on the cosine difference (default 0.5): single frames must be
    /// clearly similar, because no sequence backs them.
    pub max_distance: f32,
    /// Accept only when `best ≤ max_ratio · second`, the second best of the row outside
    /// `exclusion_radius` of the best (default 0.8).
    pub max_ratio: f32,
    /// Half-width in reference submaps of the neighbourhood that is not a rival (default 3):
    /// neighbouring submaps overlap and look alike.
    pub exclusion_radius: usize,
}

impl Default for SingleFrameParams {
    fn default() -> Self {
        Self {
            max_distance: 0.5,
            max_ratio: 0.8,
            exclusion_radius: 3,
        }
    }
}

impl SingleFrameParams {
    /// Checks ranges.
    pub fn validate(&self) -> Result<(), AssociationError> {
        Ok(Validate::validate(self)?)
    }
}

/// Offsets of all searched lines of one query (`ds` per line), at most.
const MAX_LINE_SAMPLES: usize = 1_000_000;

/// Cosine differences lie in `[0, 2]`.
const COSINE_DIFFERENCE: Real = Real::within(0.0, 2.0);

impl Validate for SequenceParams {
    fn check(&self, check: &mut Checker) {
        // With |v| ≤ 100 and ds ≤ 10 000, line offsets stay within 1e6 submaps.
        check
            .size("sequence_length", self.sequence_length, 1, 10_000)
            .real(
                "velocity_min",
                f64::from(self.velocity_min),
                Real::positive_up_to(100.0),
            )
            .real(
                "velocity_max",
                f64::from(self.velocity_max),
                Real::positive_up_to(100.0),
            )
            .rule(
                "velocity_max",
                self.velocity_max,
                self.velocity_max >= self.velocity_min,
                "must be ≥ velocity_min",
            )
            .size("velocity_steps", self.velocity_steps, 1, 1000)
            .size("velocity_phases", self.velocity_phases, 1, 16)
            .real("max_score", f64::from(self.max_score), COSINE_DIFFERENCE)
            .real(
                "max_uniqueness_ratio",
                f64::from(self.max_uniqueness_ratio),
                Real::positive_up_to(1.0),
            )
            .size("exclusion_radius", self.exclusion_radius, 0, 10_000)
            .size("contrast_window", self.contrast_window, 0, 10_000);
        // Each search thread holds `ds` offsets of every line.
        let line_samples = [
            self.velocity_steps,
            self.velocity_phases,
            if self.reverse { 2 } else { 1 },
        ]
        .iter()
        .fold(self.sequence_length, |n, &f| n.saturating_mul(f));
        check.rule(
            "velocity_steps",
            self.velocity_steps,
            line_samples <= MAX_LINE_SAMPLES,
            "sequence_length · velocity_steps · velocity_phases · (2 with reverse) must be \
             ≤ 1 000 000",
        );
    }
}

impl Validate for SingleFrameParams {
    fn check(&self, check: &mut Checker) {
        check
            .real(
                "max_distance",
                f64::from(self.max_distance),
                COSINE_DIFFERENCE,
            )
            .real(
                "max_ratio",
                f64::from(self.max_ratio),
                Real::positive_up_to(1.0),
            )
            .size("exclusion_radius", self.exclusion_radius, 0, 10_000);
    }
}

/// Sequence matches of every query submap (row of `d`): at most one per query, in query order,
/// `distance` = mean raw cosine difference along the accepted line.
pub fn sequence_matches(
    d: &DifferenceMatrix,
    params: &SequenceParams,
) -> Result<Vec<SubmapMatch>, AssociationError> {
    params.validate()?;
    let (rows, cols) = (d.rows(), d.cols());
    if rows == 0 || cols == 0 {
        return Ok(Vec::new());
    }
    let enhanced;
    let search = if params.contrast_window > 0 {
        enhanced = contrast_enhanced(d, params.contrast_window);
        &enhanced
    } else {
        d
    };
    let velocities = params.velocities();
    let phases: Vec<f32> = (0..params.velocity_phases)
        .map(|p| (p as f32 + 0.5) / params.velocity_phases as f32 - 0.5)
        .collect();
    let lines: Vec<(f32, f32)> = velocities
        .iter()
        .flat_map(|&v| phases.iter().map(move |&phase| (v, phase)))
        .collect();
    let ds = params.sequence_length.min(rows);
    let kernel = LineKernel::detect();
    let matches = (0..rows)
        .into_par_iter()
        .map_init(
            || QueryScratch::new(cols, ds, lines.len()),
            |scratch, i| match_query(kernel, d, search, i, ds, &lines, params, scratch),
        )
        .flatten_iter()
        .collect();
    Ok(matches)
}

/// Per-thread buffers of the sequence search.
struct QueryScratch {
    /// Best (over velocities) line score per reference column.
    best_per_column: Vec<f32>,
    /// Distinct offset patterns of this query, `ds` each, concatenated.
    patterns: Vec<isize>,
}

impl QueryScratch {
    fn new(cols: usize, ds: usize, velocity_count: usize) -> Self {
        Self {
            best_per_column: vec![f32::INFINITY; cols],
            patterns: Vec::with_capacity(ds * velocity_count),
        }
    }
}

/// Lines running off the reference's ends keep at least this fraction of their samples.
const MIN_LINE_COVERAGE: f32 = 0.5;

#[allow(clippy::too_many_arguments)]
fn match_query(
    kernel: LineKernel,
    raw: &DifferenceMatrix,
    search: &DifferenceMatrix,
    i: usize,
    ds: usize,
    lines: &[(f32, f32)],
    params: &SequenceParams,
    scratch: &mut QueryScratch,
) -> Option<SubmapMatch> {
    let (rows, cols) = (search.rows(), search.cols());
    // The window of query rows: centred on i, shifted inwards at the ends of the query segment.
    let start = i.saturating_sub(ds / 2).min(rows - ds);
    scratch.patterns.clear();
    for &(v, phase) in lines {
        let first = scratch.patterns.len();
        for r in start..start + ds {
            scratch
                .patterns
                .push((v * (r as f32 - i as f32) + phase).round() as isize);
        }
        let (earlier, new) = scratch.patterns.split_at(first);
        if earlier.chunks_exact(ds).any(|p| p == new) {
            scratch.patterns.truncate(first);
        }
    }
    scratch.best_per_column.fill(f32::INFINITY);
    let window = &search.as_slice()[start * cols..(start + ds) * cols];
    kernel.accumulate_lines(
        window,
        cols,
        ds,
        &scratch.patterns,
        &mut scratch.best_per_column,
    );

    // Best column and the rival outside the exclusion window (SeqSLAM's uniqueness test).
    let (best_j, _) = argmin(&scratch.best_per_column, 0..cols)?;
    let lo = best_j.saturating_sub(params.exclusion_radius);
    let hi = (best_j + params.exclusion_radius + 1).min(cols);
    let left = argmin(&scratch.best_per_column, 0..lo);
    let right = argmin(&scratch.best_per_column, hi..cols);
    let (rival_j, _) = match (left, right) {
        (Some(l), Some(r)) => Some(if r.1 < l.1 { r } else { l }),
        (l, r) => l.or(r),
    }?;

    // Thresholds on the raw mean difference of the chosen lines.
    let best_score = best_raw_line(raw, search, start, ds, best_j, &scratch.patterns)?;
    let rival_score = best_raw_line(raw, search, start, ds, rival_j, &scratch.patterns)?;
    (best_score <= params.max_score && best_score <= params.max_uniqueness_ratio * rival_score)
        .then_some(SubmapMatch {
            query: i,
            reference: best_j,
            distance: best_score,
        })
}

/// Index and value of the smallest finite value of `values[range]` (first on ties).
fn argmin(values: &[f32], range: std::ops::Range<usize>) -> Option<(usize, f32)> {
    let mut best: Option<(usize, f32)> = None;
    for j in range {
        let v = values[j];
        if v.is_finite() && best.is_none_or(|(_, b)| v < b) {
            best = Some((j, v));
        }
    }
    best
}

/// Mean of `values` along the line through column `j` with offsets `pattern` over rows
/// `start..start + pattern.len()`, skipping samples outside the matrix; `None` below the
/// minimum coverage.
fn line_mean(m: &DifferenceMatrix, start: usize, j: usize, pattern: &[isize]) -> Option<f32> {
    let cols = m.cols() as isize;
    let (mut sum, mut count) = (0.0f32, 0usize);
    for (t, &offset) in pattern.iter().enumerate() {
        let c = j as isize + offset;
        if (0..cols).contains(&c) {
            sum += m.as_slice()[(start + t) * m.cols() + c as usize];
            count += 1;
        }
    }
    let enough = count as f32 >= MIN_LINE_COVERAGE * pattern.len() as f32 && count > 0;
    enough.then(|| sum / count as f32)
}

/// The raw mean of the line through column `j` that scores best on the search matrix.
fn best_raw_line(
    raw: &DifferenceMatrix,
    search: &DifferenceMatrix,
    start: usize,
    ds: usize,
    j: usize,
    patterns: &[isize],
) -> Option<f32> {
    let mut best: Option<(f32, &[isize])> = None;
    for pattern in patterns.chunks_exact(ds) {
        if let Some(score) = line_mean(search, start, j, pattern) {
            if best.is_none_or(|(b, _)| score < b) {
                best = Some((score, pattern));
            }
        }
    }
    let (_, pattern) = best?;
    line_mean(raw, start, j, pattern)
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum LineKernel {
    Portable,
    #[cfg(target_arch = "x86_64")]
    Avx2,
}

impl LineKernel {
    fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::is_x86_feature_detected!("avx2") {
                return LineKernel::Avx2;
            }
        }
        LineKernel::Portable
    }

    /// `best[j] = min over patterns of the mean of window[t][j + pattern[t]]` for every
    /// column `j`; `patterns` holds `ds` offsets per pattern.
    fn accumulate_lines(
        self,
        window: &[f32],
        cols: usize,
        ds: usize,
        patterns: &[isize],
        best: &mut [f32],
    ) {
        match self {
            LineKernel::Portable => accumulate_lines_generic(window, cols, ds, patterns, best),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Avx2` is only chosen when the CPU reports AVX2.
            LineKernel::Avx2 => unsafe { accumulate_lines_avx2(window, cols, ds, patterns, best) },
        }
    }
}

/// The generic body compiled with AVX2 enabled, so LLVM vectorises it 8 lanes wide.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn accumulate_lines_avx2(
    window: &[f32],
    cols: usize,
    ds: usize,
    patterns: &[isize],
    best: &mut [f32],
) {
    accumulate_lines_generic(window, cols, ds, patterns, best);
}

/// Columns per register block of line sums (4 AVX2 vectors: independent add chains).
const LINE_LANES: usize = 32;

/// Column blocks outer, patterns inner: the `ds` rows' few cache lines around a block stay in
/// L1 while every pattern reads them, and the minimum over patterns stays in registers.
#[inline(always)]
fn accumulate_lines_generic(
    window: &[f32],
    cols: usize,
    ds: usize,
    patterns: &[isize],
    best: &mut [f32],
) {
    if ds == 0 || cols == 0 || window.len() < ds * cols || best.len() < cols {
        return;
    }
    let (min_offset, max_offset) = patterns
        .iter()
        .fold((0isize, 0isize), |(lo, hi), &o| (lo.min(o), hi.max(o)));
    // Columns whose every line lies inside the matrix: j + offset ∈ [0, cols) for all offsets.
    let interior_lo = ((-min_offset).max(0) as usize).min(cols);
    let interior_hi = ((cols as isize - max_offset).max(0) as usize).max(interior_lo);
    let inv_ds = 1.0 / ds as f32;
    let mut j = interior_lo;
    while j + LINE_LANES <= interior_hi {
        let mut block_best = [f32::INFINITY; LINE_LANES];
        for pattern in patterns.chunks_exact(ds) {
            let mut acc = [0.0f32; LINE_LANES];
            for (t, &offset) in pattern.iter().enumerate() {
                // In bounds: interior_lo ≤ j + offset and j + offset + LINE_LANES ≤ cols.
                let begin = t * cols + (j as isize + offset) as usize;
                let Some(src) = window.get(begin..begin + LINE_LANES) else {
                    return;
                };
                for (a, &s) in acc.iter_mut().zip(src) {
                    *a += s;
                }
            }
            for (b, &a) in block_best.iter_mut().zip(&acc) {
                *b = if a < *b { a } else { *b };
            }
        }
        for (b, &a) in best[j..j + LINE_LANES].iter_mut().zip(&block_best) {
            let mean = a * inv_ds;
            *b = if mean < *b { mean } else { *b };
        }
        j += LINE_LANES;
    }
    // The rest of the interior, and lines that run off either end of the reference segment.
    let edge_columns = (0..interior_lo).chain(j.max(interior_lo)..cols);
    for j in edge_columns {
        for pattern in patterns.chunks_exact(ds) {
            let (mut sum, mut count) = (0.0f32, 0usize);
            for (t, &offset) in pattern.iter().enumerate() {
                let c = j as isize + offset;
                if (0..cols as isize).contains(&c) {
                    sum += window[t * cols + c as usize];
                    count += 1;
                }
            }
            if count > 0 && count as f32 >= MIN_LINE_COVERAGE * ds as f32 {
                let mean = sum / count as f32;
                if mean < best[j] {
                    best[j] = mean;
                }
            }
        }
    }
}

/// SeqSLAM's local contrast enhancement: each value minus the mean of the `2w + 1` values around
/// it in its row, divided by their standard deviation (windows clipped at the row ends).
pub fn contrast_enhanced(d: &DifferenceMatrix, half_window: usize) -> DifferenceMatrix {
    let (rows, cols) = (d.rows(), d.cols());
    let mut out = vec![0.0f32; rows * cols];
    if cols > 0 {
        out.par_chunks_mut(cols)
            .zip(d.as_slice().par_chunks(cols))
            .for_each_init(
                || (vec![0.0f64; cols + 1], vec![0.0f64; cols + 1]),
                |(sum, sum_sq), (out_row, row)| {
                    // Prefix sums in f64: window sums by two lookups.
                    for (j, &v) in row.iter().enumerate() {
                        sum[j + 1] = sum[j] + f64::from(v);
                        sum_sq[j + 1] = sum_sq[j] + f64::from(v) * f64::from(v);
                    }
                    for (j, (o, &v)) in out_row.iter_mut().zip(row).enumerate() {
                        let lo = j.saturating_sub(half_window);
                        let hi = (j + half_window + 1).min(cols);
                        let n = (hi - lo) as f64;
                        let mean = (sum[hi] - sum[lo]) / n;
                        let variance = ((sum_sq[hi] - sum_sq[lo]) / n - mean * mean).max(0.0);
                        let std = variance.sqrt().max(1e-6);
                        let z = ((f64::from(v) - mean) / std) as f32;
                        // Infinite input values have no contrast; keep the matrix NaN-free.
                        *o = if z.is_finite() { z } else { 0.0 };
                    }
                },
            );
    }
    DifferenceMatrix::from_vec(rows, cols, out).unwrap_or_default()
}

/// Single-frame matches: query `i` and reference `j` that are each other's best (row and
/// column minimum), with `D_ij ≤ max_distance` and `D_ij ≤ max_ratio ·` the row's best outside
/// `exclusion_radius` of `j`. In query order.
pub fn single_frame_matches(
    d: &DifferenceMatrix,
    params: &SingleFrameParams,
) -> Result<Vec<SubmapMatch>, AssociationError> {
    params.validate()?;
    let (rows, cols) = (d.rows(), d.cols());
    if rows == 0 || cols == 0 {
        return Ok(Vec::new());
    }
    // Column minima: row blocks folded in parallel, merged keeping the lower row on ties.
    const ROW_BLOCK: usize = 64;
    let column_best = d
        .as_slice()
        .par_chunks(ROW_BLOCK * cols)
        .enumerate()
        .map(|(block, chunk)| {
            let mut best_value = vec![f32::INFINITY; cols];
            let mut best_row = vec![0u32; cols];
            for (r, row) in chunk.chunks_exact(cols).enumerate() {
                let i = (block * ROW_BLOCK + r) as u32;
                for ((bv, br), &v) in best_value.iter_mut().zip(best_row.iter_mut()).zip(row) {
                    if v < *bv {
                        *bv = v;
                        *br = i;
                    }
                }
            }
            (best_value, best_row)
        })
        .reduce_with(|(mut value_a, mut row_a), (value_b, row_b)| {
            for j in 0..value_a.len() {
                if value_b[j] < value_a[j] || (value_b[j] == value_a[j] && row_b[j] < row_a[j]) {
                    value_a[j] = value_b[j];
                    row_a[j] = row_b[j];
                }
            }
            (value_a, row_a)
        });
    let Some((_, column_best_row)) = column_best else {
        return Ok(Vec::new());
    };
    let matches = (0..rows)
        .into_par_iter()
        .filter_map(|i| {
            let row = d.row(i);
            let (j, best) = argmin(row, 0..cols)?;
            if column_best_row[j] as usize != i || best > params.max_distance {
                return None;
            }
            let lo = j.saturating_sub(params.exclusion_radius);
            let hi = (j + params.exclusion_radius + 1).min(cols);
            let second = [argmin(row, 0..lo), argmin(row, hi..cols)]
                .into_iter()
                .flatten()
                .map(|(_, v)| v)
                .fold(f32::INFINITY, f32::min);
            (second.is_finite() && best <= params.max_ratio * second).then_some(SubmapMatch {
                query: i,
                reference: j,
                distance: best,
            })
        })
        .collect();
    Ok(matches)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn matrix(rows: usize, cols: usize, f: impl Fn(usize, usize) -> f32) -> DifferenceMatrix {
        let data = (0..rows * cols).map(|k| f(k / cols, k % cols)).collect();
        DifferenceMatrix::from_vec(rows, cols, data).unwrap()
    }

    #[test]
    fn line_kernel_equals_scalar_line_means() {
        // A deterministic pseudo-random matrix; every column against the scalar definition.
        let (rows, cols) = (12, 150);
        let d = matrix(rows, cols, |i, j| {
            ((i * 7919 + j * 104_729) % 1000) as f32 / 1000.0
        });
        for pattern in [
            vec![-3isize, -2, -1, 0, 1, 2, 4],
            vec![5, 4, 2, 1, 0, -1, -2],
        ] {
            let mut best = vec![f32::INFINITY; cols];
            let window = &d.as_slice()[2 * cols..(2 + pattern.len()) * cols];
            let ds = pattern.len();
            LineKernel::detect().accumulate_lines(window, cols, ds, &pattern, &mut best);
            let mut portable = vec![f32::INFINITY; cols];
            accumulate_lines_generic(window, cols, ds, &pattern, &mut portable);
            for j in 0..cols {
                let want = line_mean(&d, 2, j, &pattern).unwrap_or(f32::INFINITY);
                assert!(want.is_finite() || j < 5 || j >= cols - 5);
                assert!(
                    (best[j] - want).abs() < 1e-5 || best[j] == want,
                    "column {j}"
                );
                assert!((portable[j] - want).abs() < 1e-5 || portable[j] == want);
            }
        }
    }

    #[test]
    fn several_patterns_give_the_minimum_line_mean() {
        let (cols, ds) = (300, 6);
        let d = matrix(ds, cols, |i, j| ((i * 31 + j * 17) % 97) as f32 / 97.0);
        let patterns: Vec<isize> =
            vec![-3, -2, -1, 0, 1, 2, 3, 2, 1, 0, -1, -2, -4, -3, -1, 0, 1, 3];
        let mut best = vec![f32::INFINITY; cols];
        LineKernel::detect().accumulate_lines(d.as_slice(), cols, ds, &patterns, &mut best);
        for (j, &got) in best.iter().enumerate() {
            let want = patterns
                .chunks_exact(ds)
                .filter_map(|p| line_mean(&d, 0, j, p))
                .fold(f32::INFINITY, f32::min);
            assert!(
                (got - want).abs() < 1e-5 || got == want,
                "column {j}: {got} vs {want}"
            );
        }
    }

    #[test]
    fn velocities_are_geometric_and_signed() {
        let params = SequenceParams {
            velocity_steps: 5,
            ..Default::default()
        };
        let v = params.velocities();
        assert_eq!(v.len(), 10);
        assert!((v[0] - 0.8).abs() < 1e-6 && (v[4] - 1.25).abs() < 1e-5);
        assert!((v[2] - 1.0).abs() < 1e-5);
        assert!((v[5] + 0.8).abs() < 1e-6);
        let v = SequenceParams::default().velocities();
        assert_eq!(v.len(), 6);
        assert!((v[1] - 1.0).abs() < 1e-5 && (v[4] + 1.0).abs() < 1e-5);
    }

    #[test]
    fn invalid_params_are_errors() {
        let d = matrix(3, 3, |_, _| 1.0);
        let bad = SequenceParams {
            sequence_length: 0,
            ..Default::default()
        };
        assert!(sequence_matches(&d, &bad).is_err());
        let bad = SequenceParams {
            velocity_max: 0.5,
            ..Default::default()
        };
        assert!(sequence_matches(&d, &bad).is_err());
        let bad = SingleFrameParams {
            max_ratio: f32::NAN,
            ..Default::default()
        };
        assert!(single_frame_matches(&d, &bad).is_err());
    }

    #[test]
    fn contrast_enhancement_standardises_rows() {
        let d = matrix(2, 50, |i, j| (i + 1) as f32 * (j % 5) as f32);
        let e = contrast_enhanced(&d, 100);
        for i in 0..2 {
            let row = e.row(i);
            let mean: f32 = row.iter().sum::<f32>() / 50.0;
            let var: f32 = row.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / 50.0;
            assert!(mean.abs() < 1e-4 && (var - 1.0).abs() < 1e-3);
        }
    }
}
