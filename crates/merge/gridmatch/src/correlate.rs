//! Translation for a given rotation by FFT cross-correlation of coarse class rasters over the
//! whole overlap (Carpin 2008, Sec. 4: the translation is the peak of the correlation of the
//! rotated map with the other; here one correlation also penalises occupied-vs-free cells).

use std::sync::Arc;

use mapmerge_geometry::Se2;
use mapmerge_grid::Point2;
use rayon::prelude::*;
use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlanner};

use crate::raster::{ClassRaster, FREE, OCCUPIED, UNKNOWN};

/// A class raster pooled into `factor × factor` blocks: occupied when any cell is, free when
/// at least half the block is free, else unknown (as `OccupancyGrid::resample`).
#[derive(Clone, Debug)]
pub(crate) struct CoarseMap {
    pub width: usize,
    pub height: usize,
    /// Corner of cell (0, 0) (m), in the frame the map is expressed in.
    pub origin_m: Point2,
    pub cell_m: f64,
    pub codes: Vec<u8>,
}

impl CoarseMap {
    pub fn pool(raster: &ClassRaster, factor: usize) -> Self {
        let factor = factor.max(1);
        let width = raster.width().div_ceil(factor);
        let height = raster.height().div_ceil(factor);
        let mut occupied = vec![0u32; width];
        let mut free = vec![0u32; width];
        let mut codes = Vec::with_capacity(width * height);
        let half_block = (factor * factor).div_ceil(2) as u32;
        for by in 0..height {
            occupied.fill(0);
            free.fill(0);
            let rows = by * factor..((by + 1) * factor).min(raster.height());
            for y in rows {
                let row = &raster.cells[y * raster.width()..(y + 1) * raster.width()];
                for (x, &c) in row.iter().enumerate() {
                    let bx = x / factor;
                    if c == OCCUPIED {
                        occupied[bx] += 1;
                    } else if c == FREE {
                        free[bx] += 1;
                    }
                }
            }
            codes.extend(occupied.iter().zip(&free).map(|(&o, &f)| {
                if o > 0 {
                    OCCUPIED
                } else if f >= half_block {
                    FREE
                } else {
                    UNKNOWN
                }
            }));
        }
        Self {
            width,
            height,
            origin_m: raster.geometry.origin_m,
            cell_m: raster.geometry.resolution_m * factor as f64,
            codes,
        }
    }

    /// This map turned by `theta_rad` about its frame's origin (`p_r = R(θ) · p`), resampled
    /// (nearest cell) on an axis-aligned lattice of the same cell size.
    pub fn rotated(&self, theta_rad: f64) -> Self {
        let (sin, cos) = theta_rad.sin_cos();
        let c = self.cell_m;
        let lo = self.origin_m;
        let hi = lo + Point2::new(self.width as f64, self.height as f64) * c;
        let corners = [(lo.x, lo.y), (hi.x, lo.y), (lo.x, hi.y), (hi.x, hi.y)]
            .map(|(x, y)| Point2::new(cos * x - sin * y, sin * x + cos * y));
        let min_x = corners.iter().map(|p| p.x).fold(f64::MAX, f64::min);
        let min_y = corners.iter().map(|p| p.y).fold(f64::MAX, f64::min);
        let max_x = corners.iter().map(|p| p.x).fold(f64::MIN, f64::max);
        let max_y = corners.iter().map(|p| p.y).fold(f64::MIN, f64::max);
        let width = ((max_x - min_x) / c).ceil() as usize;
        let height = ((max_y - min_y) / c).ceil() as usize;
        let origin_m = Point2::new(min_x, min_y);
        let mut codes = Vec::with_capacity(width * height);
        // p = R(−θ) · p_r, in source cells, walked along each row.
        let inverse_c = 1.0 / c;
        let (wx, wy) = (self.width as f64, self.height as f64);
        for j in 0..height {
            let p_r = origin_m + Point2::new(0.5, j as f64 + 0.5) * c;
            let mut u = ((cos * p_r.x + sin * p_r.y) - lo.x) * inverse_c;
            let mut v = ((-sin * p_r.x + cos * p_r.y) - lo.y) * inverse_c;
            for _ in 0..width {
                let code = if u >= 0.0 && v >= 0.0 && u < wx && v < wy {
                    self.codes
                        .get(v as usize * self.width + u as usize)
                        .copied()
                        .unwrap_or(UNKNOWN)
                } else {
                    UNKNOWN
                };
                codes.push(code);
                u += cos;
                v -= sin;
            }
        }
        Self {
            width,
            height,
            origin_m,
            cell_m: c,
            codes,
        }
    }
}

/// A rotation with a translation found by correlation.
#[derive(Clone, Copy, Debug)]
pub(crate) struct CoarseCandidate {
    /// Index of the rotation hypothesis.
    pub rotation: usize,
    pub a_from_b: Se2,
    /// Correlation value (weighted agreements minus disagreements, coarse cells).
    pub score: f64,
}

/// A's coarse raster in the frequency domain, ready to be correlated with rotated B's.
pub(crate) struct TranslationSearch {
    a: CoarseMap,
    nx: usize,
    ny: usize,
    /// conj(FFT(A)), transposed layout (nx rows of ny).
    a_spectrum: Vec<Complex32>,
    occupied_weight: f32,
    row_forward: Arc<dyn Fft<f32>>,
    column_forward: Arc<dyn Fft<f32>>,
    row_inverse: Arc<dyn Fft<f32>>,
    column_inverse: Arc<dyn Fft<f32>>,
}

/// The smallest 2^a·3^b·5^c ≥ n (sizes rustfft handles fastest).
fn smooth_size(n: usize) -> usize {
    let mut m = n.max(1);
    loop {
        let mut k = m;
        for p in [2, 3, 5] {
            while k % p == 0 {
                k /= p;
            }
        }
        if k == 1 {
            return m;
        }
        m += 1;
    }
}

fn value(code: u8, occupied_weight: f32) -> f32 {
    match code {
        OCCUPIED => occupied_weight,
        FREE => -1.0,
        _ => 0.0,
    }
}

/// Blocked transpose of `rows × columns` `src` into `dst` (`columns × rows`).
fn transpose(src: &[Complex32], dst: &mut [Complex32], rows: usize, columns: usize) {
    const BLOCK: usize = 32;
    for r0 in (0..rows).step_by(BLOCK) {
        for c0 in (0..columns).step_by(BLOCK) {
            for r in r0..(r0 + BLOCK).min(rows) {
                for c in c0..(c0 + BLOCK).min(columns) {
                    dst[c * rows + r] = src[r * columns + c];
                }
            }
        }
    }
}

impl TranslationSearch {
    /// Prepares A; `max_b_extent` (coarse cells) bounds the size of any rotated B.
    pub fn new(a: CoarseMap, max_b_extent: usize, occupied_weight: f64) -> Self {
        let nx = smooth_size(a.width + max_b_extent);
        let ny = smooth_size(a.height + max_b_extent);
        let mut planner = FftPlanner::<f32>::new();
        let mut search = Self {
            nx,
            ny,
            a_spectrum: Vec::new(),
            occupied_weight: occupied_weight as f32,
            row_forward: planner.plan_fft_forward(nx),
            column_forward: planner.plan_fft_forward(ny),
            row_inverse: planner.plan_fft_inverse(nx),
            column_inverse: planner.plan_fft_inverse(ny),
            a,
        };
        let mut data = vec![Complex32::new(0.0, 0.0); nx * ny];
        for (y, row) in search
            .a
            .codes
            .chunks_exact(search.a.width.max(1))
            .enumerate()
        {
            for (x, &code) in row.iter().enumerate() {
                data[y * nx + x] = Complex32::new(value(code, search.occupied_weight), 0.0);
            }
        }
        let mut spectrum = vec![Complex32::new(0.0, 0.0); nx * ny];
        search.forward(&mut data, &mut spectrum);
        for v in &mut spectrum {
            *v = v.conj();
        }
        search.a_spectrum = spectrum;
        search
    }

    /// 2D FFT of `data` (ny rows of nx) into `spectrum` (transposed: nx rows of ny).
    fn forward(&self, data: &mut [Complex32], spectrum: &mut [Complex32]) {
        let mut scratch = vec![Complex32::new(0.0, 0.0); self.scratch_len()];
        self.row_forward.process_with_scratch(data, &mut scratch);
        transpose(data, spectrum, self.ny, self.nx);
        self.column_forward
            .process_with_scratch(spectrum, &mut scratch);
    }

    /// Inverse of [`Self::forward`] (unnormalised).
    fn inverse(&self, spectrum: &mut [Complex32], data: &mut [Complex32]) {
        let mut scratch = vec![Complex32::new(0.0, 0.0); self.scratch_len()];
        self.column_inverse
            .process_with_scratch(spectrum, &mut scratch);
        transpose(spectrum, data, self.nx, self.ny);
        self.row_inverse.process_with_scratch(data, &mut scratch);
    }

    fn scratch_len(&self) -> usize {
        [
            &self.row_forward,
            &self.column_forward,
            &self.row_inverse,
            &self.column_inverse,
        ]
        .iter()
        .map(|f| f.get_inplace_scratch_len())
        .max()
        .unwrap_or(0)
    }

    /// For every rotation `(index, θ)`, the `peaks` best translations of coarse B turned by
    /// θ (non-maximum suppressed within `separation_cells`). Two rotations share one complex
    /// FFT (real and imaginary parts), since A's raster is real.
    pub fn search(
        &self,
        b: &CoarseMap,
        rotations: &[f64],
        peaks: usize,
        separation_cells: usize,
    ) -> Vec<CoarseCandidate> {
        let pairs: Vec<Vec<(usize, f64)>> = rotations
            .iter()
            .copied()
            .enumerate()
            .collect::<Vec<_>>()
            .chunks(2)
            .map(<[_]>::to_vec)
            .collect();
        pairs
            .par_iter()
            .flat_map_iter(|pair| self.search_pair(b, pair, peaks, separation_cells))
            .collect()
    }

    fn search_pair(
        &self,
        b: &CoarseMap,
        pair: &[(usize, f64)],
        peaks: usize,
        separation_cells: usize,
    ) -> Vec<CoarseCandidate> {
        let (nx, ny) = (self.nx, self.ny);
        let zero = Complex32::new(0.0, 0.0);
        let mut data = vec![zero; nx * ny];
        let rotated: Vec<CoarseMap> = pair.iter().map(|&(_, theta)| b.rotated(theta)).collect();
        for (k, r) in rotated.iter().enumerate() {
            for (y, row) in r.codes.chunks_exact(r.width.max(1)).enumerate().take(ny) {
                for (x, &code) in row.iter().enumerate().take(nx) {
                    let v = value(code, self.occupied_weight);
                    let slot = &mut data[y * nx + x];
                    if k == 0 {
                        slot.re = v;
                    } else {
                        slot.im = v;
                    }
                }
            }
        }
        let mut spectrum = vec![zero; nx * ny];
        self.forward(&mut data, &mut spectrum);
        // IFFT(conj(FA) · F(R₁ + i R₂)) = (A ⋆ R₁) + i (A ⋆ R₂), d[s] = Σ_q A[q] · R[q + s].
        for (s, a) in spectrum.iter_mut().zip(&self.a_spectrum) {
            *s *= *a;
        }
        self.inverse(&mut spectrum, &mut data);
        let scale = 1.0 / (nx * ny) as f64;
        let mut out = Vec::new();
        for (k, (&(rotation, theta), r)) in pair.iter().zip(&rotated).enumerate() {
            let read = |i: usize| -> f32 {
                let v = data[i];
                if k == 0 {
                    v.re
                } else {
                    v.im
                }
            };
            for (score, sx, sy) in self.peaks(r, &read, peaks, separation_cells) {
                // A cell = R cell − s, so p_a = p_r + (o_a − o_r − s · c).
                let c = self.a.cell_m;
                let t = self.a.origin_m - r.origin_m - Point2::new(sx as f64, sy as f64) * c;
                out.push(CoarseCandidate {
                    rotation,
                    a_from_b: Se2::new(t.x, t.y, theta),
                    score: f64::from(score) * scale,
                });
            }
        }
        out
    }

    /// The best local maxima of the correlation over shifts where A and R overlap.
    fn peaks(
        &self,
        r: &CoarseMap,
        read: &dyn Fn(usize) -> f32,
        count: usize,
        separation_cells: usize,
    ) -> Vec<(f32, i64, i64)> {
        let (nx, ny) = (self.nx as i64, self.ny as i64);
        let shift_range =
            |extent_a: usize, extent_r: usize| (-(extent_a as i64) + 1)..(extent_r as i64);
        let at = |sx: i64, sy: i64| read((sy.rem_euclid(ny) * nx + sx.rem_euclid(nx)) as usize);
        let mut maxima = Vec::new();
        for sy in shift_range(self.a.height, r.height) {
            for sx in shift_range(self.a.width, r.width) {
                let v = at(sx, sy);
                if v <= 0.0 {
                    continue;
                }
                let is_max = (-1..=1).all(|dy| {
                    (-1..=1).all(|dx| {
                        let w = at(sx + dx, sy + dy);
                        (dx, dy) == (0, 0) || w < v || (w == v && (dy, dx) > (0, 0))
                    })
                });
                if is_max {
                    maxima.push((v, sx, sy));
                }
            }
        }
        maxima.sort_by(|l, r| r.0.total_cmp(&l.0).then((l.2, l.1).cmp(&(r.2, r.1))));
        let mut chosen: Vec<(f32, i64, i64)> = Vec::new();
        let separation = separation_cells as i64;
        for m in maxima {
            if chosen
                .iter()
                .all(|c| (c.1 - m.1).abs().max((c.2 - m.2).abs()) > separation)
            {
                chosen.push(m);
                if chosen.len() == count {
                    break;
                }
            }
        }
        chosen
    }
}
