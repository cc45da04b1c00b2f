//! Rotation hypotheses from local wall orientations: a second source beside the Hough
//! spectrum. Each occupied cell's wall direction is the principal axis of the occupied cells
//! around it (the structure tensor / PCA of the neighbourhood); the histogram of those
//! directions over [0, π), weighted by how line-like the neighbourhood is, turns with the map
//! and does not depend on where the walls are. Two partial crops of one building see
//! different walls, so the Hough spectra (Carpin 2008, Eq. 2: long collinear runs) of the two
//! can peak at different angles, while every wall segment, short or long, votes here for its
//! direction; for rectilinear buildings both histograms peak at the same two perpendicular
//! directions. Cross-correlated like the spectra (Carpin 2008, Eq. 3).

use std::f64::consts::PI;

use rayon::prelude::*;

use crate::raster::{ClassRaster, OCCUPIED};

/// Rows of the raster per parallel chunk: fixed, so that the sum is the same on any number
/// of threads.
const ROWS_PER_CHUNK: usize = 64;

/// The local-orientation histogram of `raster`'s occupied cells over `angle_bins` bins of
/// [0, π). Each occupied cell whose `(2·radius + 1)²` neighbourhood holds at least
/// `radius + 1` occupied cells votes for the principal direction of those cells,
/// `φ = ½·atan2(2·c_xy, c_xx − c_yy)` of their covariance, weighted by the squared coherence
/// `(λ₁ − λ₂)² / (λ₁ + λ₂)²` (1 on a straight wall, 0 at a corner or blob), split linearly
/// between the two nearest bins. At most `max_samples` cells (evenly strided) vote.
pub(crate) fn orientation_histogram(
    raster: &ClassRaster,
    radius: usize,
    angle_bins: usize,
    max_samples: usize,
) -> Vec<f64> {
    let (w, h) = (raster.width(), raster.height());
    if angle_bins == 0 || w == 0 || h == 0 {
        return vec![0.0; angle_bins];
    }
    let occupied = raster.cells.iter().filter(|&&c| c == OCCUPIED).count();
    let stride = occupied.div_ceil(max_samples.max(1)).max(1);
    // The k-th occupied cell votes when k % stride == 0; count per chunk to find each
    // chunk's first index.
    let chunks: Vec<(usize, usize)> = (0..h)
        .step_by(ROWS_PER_CHUNK)
        .map(|y0| (y0, (y0 + ROWS_PER_CHUNK).min(h)))
        .collect();
    let mut firsts = Vec::with_capacity(chunks.len());
    let mut seen = 0usize;
    for &(y0, y1) in &chunks {
        firsts.push(seen);
        seen += raster.cells[y0 * w..y1 * w]
            .iter()
            .filter(|&&c| c == OCCUPIED)
            .count();
    }
    let r = radius as i64;
    let r2 = r * r + r;
    let min_neighbours = radius as u32 + 1;
    let bin_rad = PI / angle_bins as f64;
    let partial: Vec<Vec<f64>> = chunks
        .par_iter()
        .zip(&firsts)
        .map(|(&(y0, y1), &first)| {
            let mut histogram = vec![0.0; angle_bins];
            let mut k = first;
            for y in y0..y1 {
                for x in 0..w {
                    if raster.cells[y * w + x] != OCCUPIED {
                        continue;
                    }
                    k += 1;
                    if (k - 1) % stride != 0 {
                        continue;
                    }
                    let (mut n, mut sx, mut sy, mut sxx, mut syy, mut sxy) =
                        (0u32, 0i64, 0i64, 0i64, 0i64, 0i64);
                    let ys = (y as i64 - r).max(0)..=(y as i64 + r).min(h as i64 - 1);
                    let xs =
                        (x as i64 - r).max(0) as usize..=(x as i64 + r).min(w as i64 - 1) as usize;
                    for v in ys {
                        let row = &raster.cells[v as usize * w..(v as usize + 1) * w];
                        let dy = v - y as i64;
                        for u in xs.clone() {
                            let dx = u as i64 - x as i64;
                            // A round window: a square one clips a slanted wall
                            // asymmetrically and pulls its axis towards the square's.
                            if row[u] == OCCUPIED && dx * dx + dy * dy <= r2 {
                                n += 1;
                                sx += dx;
                                sy += dy;
                                sxx += dx * dx;
                                syy += dy * dy;
                                sxy += dx * dy;
                            }
                        }
                    }
                    if n < min_neighbours {
                        continue;
                    }
                    // Covariance of the neighbourhood (structure tensor of the wall).
                    let nf = f64::from(n);
                    let (mx, my) = (sx as f64 / nf, sy as f64 / nf);
                    let cxx = sxx as f64 / nf - mx * mx;
                    let cyy = syy as f64 / nf - my * my;
                    let cxy = sxy as f64 / nf - mx * my;
                    let trace = cxx + cyy;
                    if trace <= 0.0 {
                        continue;
                    }
                    let spread = ((cxx - cyy).powi(2) + 4.0 * cxy * cxy).sqrt();
                    let coherence = spread / trace;
                    let phi = (0.5 * (2.0 * cxy).atan2(cxx - cyy)).rem_euclid(PI);
                    let position = phi / bin_rad - 0.5;
                    let lower = position.floor();
                    let fraction = position - lower;
                    let weight = coherence * coherence;
                    let i = (lower as i64).rem_euclid(angle_bins as i64) as usize;
                    histogram[i] += weight * (1.0 - fraction);
                    histogram[(i + 1) % angle_bins] += weight * fraction;
                }
            }
            histogram
        })
        .collect();
    let mut histogram = vec![0.0; angle_bins];
    for part in partial {
        for (total, v) in histogram.iter_mut().zip(part) {
            *total += v;
        }
    }
    histogram
}

/// Circular Gaussian smoothing of a histogram with `sigma_bins` (3σ support).
pub(crate) fn smooth_circular(histogram: &[f64], sigma_bins: f64) -> Vec<f64> {
    let n = histogram.len();
    if n == 0 || sigma_bins <= 0.0 {
        return histogram.to_vec();
    }
    let reach = (3.0 * sigma_bins).ceil() as i64;
    let kernel: Vec<f64> = (-reach..=reach)
        .map(|d| (-0.5 * (d as f64 / sigma_bins).powi(2)).exp())
        .collect();
    (0..n as i64)
        .map(|i| {
            kernel
                .iter()
                .zip(-reach..=reach)
                .map(|(k, d)| k * histogram[(i + d).rem_euclid(n as i64) as usize])
                .sum()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use mapmerge_grid::{GridGeometry, Point2};

    use super::*;
    use crate::raster::FREE;

    /// A raster with straight walls at `angle_rad` and perpendicular to it.
    fn walls(angle_rad: f64) -> ClassRaster {
        let n = 200;
        let mut cells = vec![FREE; n * n];
        let (s, c) = angle_rad.sin_cos();
        for k in -60..60 {
            for offset in [-40.0, 0.0, 40.0] {
                let t = f64::from(k);
                for (x, y) in [
                    (100.0 + c * t - s * offset, 100.0 + s * t + c * offset),
                    (100.0 - s * t + c * offset, 100.0 + c * t + s * offset),
                ] {
                    cells[y as usize * n + x as usize] = OCCUPIED;
                }
            }
        }
        ClassRaster {
            geometry: GridGeometry {
                resolution_m: 0.05,
                origin_m: Point2::zeros(),
                width: n,
                height: n,
            },
            cells,
        }
    }

    #[test]
    fn histogram_peaks_at_the_wall_directions() {
        for degrees in [0.0f64, 17.0, 45.0, 71.5] {
            let bins = 360;
            let histogram = orientation_histogram(&walls(degrees.to_radians()), 4, bins, 8000);
            let peak = histogram
                .iter()
                .enumerate()
                .max_by(|l, r| l.1.total_cmp(r.1))
                .map_or(0, |(i, _)| i);
            let found = (peak as f64 + 0.5) * 180.0 / bins as f64;
            let error = (found - degrees).rem_euclid(90.0);
            assert!(
                error.min(90.0 - error) < 1.5,
                "{degrees}°: peak at {found}°"
            );
        }
    }
}
