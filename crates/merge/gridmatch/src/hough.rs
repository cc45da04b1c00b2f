//! Rotation hypotheses from Hough spectra (Carpin 2008, "Fast and accurate map merging for
//! multi-robot systems", Sec. 3): the spectrum `HS(θ) = Σ_ρ H(θ, ρ)²` of a map's occupied
//! cells is invariant to translation and shifted by a rotation, so the peaks of the circular
//! cross-correlation of two spectra are the candidate rotations (π-periodic).

use std::f64::consts::PI;

use mapmerge_grid::Point2;
use rayon::prelude::*;

/// The Hough spectrum of `points` over `angle_bins` angles in [0, π), with ρ bins of
/// `rho_bin_m`. Points are taken relative to their centroid (the spectrum does not depend
/// on it; this keeps the ρ range small).
pub(crate) fn hough_spectrum(points: &[Point2], rho_bin_m: f64, angle_bins: usize) -> Vec<f64> {
    if points.is_empty() || angle_bins == 0 {
        return vec![0.0; angle_bins];
    }
    let centroid = points.iter().sum::<Point2>() / points.len() as f64;
    let inverse_bin = 1.0 / rho_bin_m;
    let scaled: Vec<(f32, f32)> = points
        .iter()
        .map(|p| {
            let d = (p - centroid) * inverse_bin;
            (d.x as f32, d.y as f32)
        })
        .collect();
    let reach = scaled
        .iter()
        .map(|&(x, y)| x.abs() + y.abs())
        .fold(0.0f32, f32::max)
        .ceil() as usize
        + 1;
    let bins = 2 * reach + 1;
    let offset = reach as f32 + 0.5;
    (0..angle_bins)
        .into_par_iter()
        .map_init(
            || vec![0u32; bins],
            |histogram, k| {
                // Carpin 2008, Eq. 2: HS(θ) = Σ_ρ H(θ, ρ)², accumulated as counts grow
                // ((c + 1)² − c² = 2c + 1).
                histogram.fill(0);
                let (sin, cos) = (PI * k as f64 / angle_bins as f64).sin_cos();
                let (sin, cos) = (sin as f32, cos as f32);
                let mut sum = 0u64;
                for &(x, y) in &scaled {
                    let rho = (x * cos + y * sin + offset) as usize;
                    if let Some(count) = histogram.get_mut(rho) {
                        sum += 2 * u64::from(*count) + 1;
                        *count += 1;
                    }
                }
                sum as f64
            },
        )
        .collect()
}

/// Carpin 2008, Eq. 3: the circular cross-correlation `CC(k) = Σ_i HS_a(i + k) · HS_b(i)`;
/// a peak at `k` means A's structure is B's turned by `k · π / n` (mod π).
pub(crate) fn spectrum_correlation(spectrum_a: &[f64], spectrum_b: &[f64]) -> Vec<f64> {
    let n = spectrum_a.len().min(spectrum_b.len());
    (0..n)
        .map(|k| {
            (0..n)
                .map(|i| spectrum_a[(i + k) % n] * spectrum_b[i])
                .sum()
        })
        .collect()
}

/// The `count` highest local maxima of the circular `correlation` (at least `separation`
/// bins apart), as rotations in [0, π) refined by a parabola through the peak and its two
/// neighbours, best first. Ties go to the smaller bin (deterministic).
pub(crate) fn rotation_peaks(
    correlation: &[f64],
    count: usize,
    separation: usize,
) -> Vec<(f64, f64)> {
    let n = correlation.len();
    if n == 0 {
        return Vec::new();
    }
    let at = |i: isize| correlation[i.rem_euclid(n as isize) as usize];
    let mut maxima: Vec<usize> = (0..n)
        .filter(|&i| {
            let v = correlation[i];
            let i = i as isize;
            v >= at(i - 1) && v > at(i + 1)
        })
        .collect();
    maxima.sort_by(|&l, &r| correlation[r].total_cmp(&correlation[l]).then(l.cmp(&r)));
    let mut chosen: Vec<usize> = Vec::new();
    for i in maxima {
        let far = chosen.iter().all(|&c| {
            let d = i.abs_diff(c);
            d.min(n - d) >= separation
        });
        if far {
            chosen.push(i);
        }
        if chosen.len() == count {
            break;
        }
    }
    let step = PI / n as f64;
    chosen
        .into_iter()
        .map(|i| {
            let (l, c, r) = (at(i as isize - 1), at(i as isize), at(i as isize + 1));
            let curvature = l - 2.0 * c + r;
            let shift = if curvature < 0.0 {
                (0.5 * (l - r) / curvature).clamp(-0.5, 0.5)
            } else {
                0.0
            };
            ((i as f64 + shift) * step, c)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spectrum_peak_follows_rotation() {
        // An L of two walls and a slanted wall, turned by 30°.
        let mut points = Vec::new();
        for k in 0..200 {
            let t = f64::from(k) * 0.05;
            points.push(Point2::new(t, 0.0));
            points.push(Point2::new(0.0, t * 0.5));
            points.push(Point2::new(3.0 + t * 0.3, 1.0 + t * 0.2));
        }
        let angle = 30f64.to_radians();
        let (s, c) = angle.sin_cos();
        let turned: Vec<Point2> = points
            .iter()
            .map(|p| Point2::new(c * p.x - s * p.y + 4.0, s * p.x + c * p.y - 2.0))
            .collect();
        let a = hough_spectrum(&turned, 0.05, 360);
        let b = hough_spectrum(&points, 0.05, 360);
        let peaks = rotation_peaks(&spectrum_correlation(&a, &b), 3, 4);
        assert!(
            (peaks[0].0 - angle).abs() < 0.5f64.to_radians(),
            "{peaks:?}"
        );
    }
}
