//! Viewpoint-invariant submap descriptors (the role of AutoMerge's fusion-enhanced descriptor,
//! Yin et al., Sec. IV, filled by a handcrafted one) behind [`SubmapDescriptor`], so that a
//! learned descriptor can be plugged in later. They live beside Scan Context because every
//! place search (the SLAM front-end's, the atlas's, assembly's) retrieves with them.
//!
//! Association (Sec. V-A) needs only a fixed-dimension `f32` vector per submap, compared by
//! cosine distance in the difference matrix `D = d(f_i, f_j)`; geometric verification needs a
//! yaw estimate between two submaps to seed the scan matcher. Both are in the trait.
//!
//! **The 2D ring spectrum** ([`RingSpectrumDescriptor`]). Translation is what hurts a
//! handcrafted descriptor most indoors: submap centres of two traversals are up to half the
//! submap spacing apart along the path and a corridor's width across it. So the descriptor
//! describes the submap's 2D power spectrum, which ignores translation, in polar coordinates
//! of the frequency plane (rings = spatial frequencies, sectors = directions), which turns
//! rotation into a circular shift:
//! 1. project the points (tapered to 0 at `max_radius_m`) onto `D` directions over 180°;
//! 2. the magnitude of each projection's FFT is, by the Fourier-slice theorem, the 2D
//!    spectrum's magnitude along that direction: a move of the submap changes only phases;
//! 3. per frequency ring, the profile over directions is shifted circularly by a turn of the
//!    submap (modulo π, `|F(−ω)| = |F(ω)|`), so the magnitudes of its DFT over directions are
//!    **rotation-invariant by construction** (a Fourier–Mellin-style invariant without scale);
//! 4. square-root compression, then the vector is centred and scaled to unit L2 norm, so the
//!    cosine is a correlation: every spectrum falls off with frequency and harmonic, and
//!    without centring that shared shape makes any two places look alike.
//!
//! A first version binned the points in a polar image around the centre (Scan Context,
//! Kim & Kim 2018, Eq. 1–2) and kept the DFT magnitudes over the sectors of each ring, which is
//! rotation-invariant too but egocentric: on 90 synthetic office places seen by a 360° scan it
//! found the right place after a 0.5 / 1 / 2 m move in 58 / 10 / 4 of 90 trials; the
//! translation-invariant spectrum above in 86 / 68 / 24 (the ignored test
//! `translation_retrieval_table` in crates/merge/assemble/tests/descriptor.rs prints the
//! current numbers).
//!
//! Dropping the phase loses the yaw, which is recovered separately
//! ([`SubmapDescriptor::relative_yaw`]) from egocentric polar images (soft-binned counts,
//! `rings × sectors`) by circular cross-correlation of the sector profiles (Scan Context's
//! column shift, Eq. 5–6) computed in the Fourier domain, upsampled 8 times by zero-padding
//! the cross spectrum and refined by a parabola through the peak. A place driven in the
//! opposite direction is the same place turned by π, so the rotation invariance covers
//! reverse traversals (the sequence matcher separately searches both directions along the
//! trajectories); accumulated submaps (`mapmerge_assemble::submap`) give a front laser the rear view.
//!
//! **3D** ([`RingSpectrumDescriptor3`]): outdoors, with 50 m submaps, a few metres of
//! translation matter less, so the 3D descriptor is egocentric: a polar grid in the
//! horizontal plane (rings of range × sectors) with two channels per bin, maximum height above
//! the ground (Scan Context's bin value) and point count (log-compressed), and per ring the
//! DFT magnitudes over the sectors; rotation about `z` only shifts sectors, so they are
//! invariant to it.

use std::sync::Arc;

use mapmerge_params::{Checker, Real, Validate};
use mapmerge_scan::Point2;
use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlanner};
use serde::{Deserialize, Serialize};

pub use mapmerge_geometry::Point3;

/// Largest accepted ring count (bigger values are clamped).
const MAX_RINGS: usize = 256;
/// Largest accepted sector count.
const MAX_SECTORS: usize = 4096;
/// Upsampling factor of the yaw correlation (a 3.75° sector becomes 0.47° steps before the
/// parabola refines further).
const YAW_UPSAMPLING: usize = 8;

/// A yaw estimate between two submaps.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct YawEstimate {
    /// Heading of the query submap's frame in the candidate's frame (rad, in `(−π, π]`): the
    /// rotation part of `candidate_from_query` for two submaps centred at the same place.
    pub yaw_rad: f64,
    /// Normalised correlation of the two polar images at that yaw, in `[0, 1]` (1: identical
    /// up to the rotation).
    pub score: f64,
}

/// A global description of a submap for association and verification.
///
/// Implementations must accept any input (empty, huge, non-finite points) without panicking.
pub trait SubmapDescriptor: Send + Sync {
    /// The point type it describes ([`Point2`] or [`Point3`]).
    type Point;

    /// Length of every descriptor vector.
    fn dim(&self) -> usize;

    /// Writes the descriptor of `points` (in the submap's centre frame) into `out`. Vectors
    /// are meant to be compared by cosine distance: unit L2 norm, or all zeros when nothing
    /// was seen. `out` should have [`dim`](Self::dim) entries; extra entries are zeroed, a
    /// shorter `out` gets the leading part.
    fn describe_into(&self, points: &[Self::Point], out: &mut [f32]);

    /// The descriptor of `points` as a new vector of [`dim`](Self::dim) entries.
    fn describe(&self, points: &[Self::Point]) -> Vec<f32> {
        let mut out = vec![0.0; self.dim()];
        self.describe_into(points, &mut out);
        out
    }

    /// The heading of `query`'s frame in `candidate`'s frame, assuming both see the same
    /// place from nearby centres; `None` when either is empty or the descriptor has no yaw
    /// (a learned descriptor may not; the verifier then searches all headings).
    fn relative_yaw(&self, query: &[Self::Point], candidate: &[Self::Point])
        -> Option<YawEstimate>;
}

/// Descriptors of many submaps: row `i` (of `dim` values) describes submap `i`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DescriptorRows {
    /// Length of one row.
    pub dim: usize,
    /// Row-major values, `len() · dim` of them.
    pub values: Vec<f32>,
}

impl DescriptorRows {
    /// Number of rows.
    pub fn len(&self) -> usize {
        self.values.len().checked_div(self.dim).unwrap_or(0)
    }

    /// True when there is no row.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Row `i`, `None` out of range.
    pub fn row(&self, i: usize) -> Option<&[f32]> {
        self.values.get(i * self.dim..(i + 1) * self.dim)
    }
}

/// Cosine distance `1 − a·b / (|a| |b|)` in `[0, 2]`; 1 when either vector is zero (nothing
/// in common is known).
pub fn cosine_distance(a: &[f32], b: &[f32]) -> f32 {
    let (mut ab, mut aa, mut bb) = (0.0f32, 0.0f32, 0.0f32);
    for (&x, &y) in a.iter().zip(b) {
        ab += x * y;
        aa += x * x;
        bb += y * y;
    }
    let norm = (aa * bb).sqrt();
    if norm > 0.0 && norm.is_finite() {
        1.0 - ab / norm
    } else {
        1.0
    }
}

/// Parameters of the 2D ring-spectrum descriptor.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RingSpectrumParams {
    /// Radius of the described disc (m) (default: 10, as the indoor submap radius). Points
    /// beyond are ignored and points near it are faded out; non-finite or non-positive values
    /// fall back to 10.
    pub max_radius_m: f64,
    /// Projection directions over 180°, the sectors of the frequency plane (default: 64, 2.8°
    /// apart). Clamped to `4..=4096`.
    pub direction_count: usize,
    /// Bins of each projection over the diameter (default: 64, 0.31 m at 10 m). Must resolve
    /// the highest ring: clamped to at least `2 · ring_count + 2`.
    pub projection_bins: usize,
    /// Rings of the frequency plane kept: ring `b` is the spatial frequency
    /// `(b + 1) / (2 · radius)`, a period of `2 · radius / (b + 1)` (default: 16: periods from
    /// 20 m down to 1.25 m). On synthetic offices finer structure made retrieval after a 1 m
    /// move worse: 16 rings found the place among 90 in 68 of 90 trials, 16 rings averaging
    /// two frequencies each (down to 0.6 m) in 59.
    pub ring_count: usize,
    /// DFT harmonics over the directions kept per band, 0 first (default: 16; with 16 bands a
    /// 256-dimensional vector). Clamped to `1..=direction_count / 2 + 1`.
    pub harmonic_count: usize,
    /// Rings of the polar image used only for the yaw (default: 16).
    pub yaw_ring_count: usize,
    /// Sectors of the polar image used only for the yaw (default: 96, 3.75° before the
    /// upsampled, parabola-refined correlation).
    pub yaw_sector_count: usize,
}

impl Default for RingSpectrumParams {
    fn default() -> Self {
        Self {
            max_radius_m: 10.0,
            direction_count: 64,
            projection_bins: 64,
            ring_count: 16,
            harmonic_count: 16,
            yaw_ring_count: 16,
            yaw_sector_count: 96,
        }
    }
}

/// Parameters of the 3D ring-spectrum descriptor (height and density channels).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RingSpectrum3Params {
    /// Number of rings (default: 16). Clamped to `1..=256`.
    pub ring_count: usize,
    /// Number of sectors (default: 96). Clamped to `4..=4096`.
    pub sector_count: usize,
    /// DFT harmonics kept per ring and channel (default: 8; 16 rings × 8 × 2 channels = 256).
    pub harmonic_count: usize,
    /// Radius of the outermost ring (m) (default: 50, as the paper's outdoor submaps).
    pub max_radius_m: f64,
    /// Height of the sensor above the ground (m) (default: 1.73, KITTI's Velodyne): heights
    /// are measured from `z = −sensor_height_m` of the submap frame.
    pub sensor_height_m: f64,
    /// Heights above this (m above the ground) are clipped (default: 10).
    pub max_height_m: f64,
}

impl Default for RingSpectrum3Params {
    fn default() -> Self {
        Self {
            ring_count: 16,
            sector_count: 96,
            harmonic_count: 8,
            max_radius_m: 50.0,
            sensor_height_m: 1.73,
            max_height_m: 10.0,
        }
    }
}

/// How a splatted value combines with a bin's content.
#[derive(Clone, Copy)]
enum Combine {
    /// Sum of weights times value (density).
    Sum,
    /// Maximum of weight times value (height).
    Max,
}

/// The polar grid and the FFT plans shared by the 2D and 3D descriptors.
#[derive(Clone)]
struct PolarSpectrum {
    rings: usize,
    sectors: usize,
    harmonics: usize,
    radius_m: f64,
    ring_width_m: f64,
    sector_rad: f64,
    forward: Arc<dyn Fft<f32>>,
    /// Inverse FFT of length `YAW_UPSAMPLING · sectors` for the upsampled correlation.
    inverse_upsampled: Arc<dyn Fft<f32>>,
}

impl std::fmt::Debug for PolarSpectrum {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PolarSpectrum")
            .field("rings", &self.rings)
            .field("sectors", &self.sectors)
            .field("harmonics", &self.harmonics)
            .field("radius_m", &self.radius_m)
            .finish()
    }
}

impl PolarSpectrum {
    fn new(ring_count: usize, sector_count: usize, harmonic_count: usize, radius_m: f64) -> Self {
        let rings = ring_count.clamp(1, MAX_RINGS);
        let sectors = sector_count.clamp(4, MAX_SECTORS);
        let harmonics = harmonic_count.clamp(1, sectors / 2 + 1);
        let radius_m = if radius_m.is_finite() && radius_m > 0.0 {
            radius_m
        } else {
            10.0
        };
        let mut planner = FftPlanner::<f32>::new();
        Self {
            rings,
            sectors,
            harmonics,
            radius_m,
            ring_width_m: radius_m / rings as f64,
            sector_rad: std::f64::consts::TAU / sectors as f64,
            forward: planner.plan_fft_forward(sectors),
            inverse_upsampled: planner.plan_fft_inverse(sectors * YAW_UPSAMPLING),
        }
    }

    fn image_len(&self) -> usize {
        self.rings * self.sectors
    }

    /// Spreads `value` at polar position `(range_m, angle_rad)` over the four nearest bin
    /// centres of `image` (`[ring][sector]`), bilinearly. Ring centres sit at `(i + ½)·width`
    /// (the innermost and outermost half rings clamp), sector centres at `j·sector` (wrapping).
    #[inline]
    fn splat(&self, image: &mut [f32], range_m: f64, angle_rad: f64, value: f32, how: Combine) {
        if !(range_m < self.radius_m && angle_rad.is_finite()) {
            return;
        }
        let s = angle_rad.rem_euclid(std::f64::consts::TAU) / self.sector_rad;
        let r = (range_m / self.ring_width_m - 0.5).max(0.0);
        let (s0, r0) = (s.floor(), r.floor());
        let (fs, fr) = ((s - s0) as f32, (r - r0) as f32);
        let sector_a = (s0 as usize) % self.sectors;
        let sector_b = (sector_a + 1) % self.sectors;
        let ring_a = (r0 as usize).min(self.rings - 1);
        let ring_b = (ring_a + 1).min(self.rings - 1);
        let cells = [
            (ring_a, sector_a, (1.0 - fr) * (1.0 - fs)),
            (ring_a, sector_b, (1.0 - fr) * fs),
            (ring_b, sector_a, fr * (1.0 - fs)),
            (ring_b, sector_b, fr * fs),
        ];
        for (ring, sector, weight) in cells {
            if let Some(bin) = image.get_mut(ring * self.sectors + sector) {
                match how {
                    Combine::Sum => *bin += weight * value,
                    Combine::Max => *bin = bin.max(weight * value),
                }
            }
        }
    }

    /// The DFT of every ring of `image` (`[ring][sector]`) into `spectrum`.
    fn ring_spectra(&self, image: &[f32], spectrum: &mut Vec<Complex32>) {
        spectrum.clear();
        spectrum.extend(image.iter().map(|&v| Complex32::new(v, 0.0)));
        spectrum.resize(self.image_len(), Complex32::new(0.0, 0.0));
        let mut scratch = vec![Complex32::new(0.0, 0.0); self.forward.get_inplace_scratch_len()];
        self.forward.process_with_scratch(spectrum, &mut scratch);
    }

    /// Square-root compressed magnitudes of harmonics `0..H` of every ring into `out`
    /// (`rings · harmonics` values, ring-major).
    fn harmonic_magnitudes(&self, spectrum: &[Complex32], out: &mut [f32]) {
        let rows = spectrum.chunks_exact(self.sectors);
        for (ring_out, ring_spectrum) in out.chunks_mut(self.harmonics).zip(rows) {
            for (value, coefficient) in ring_out.iter_mut().zip(ring_spectrum) {
                *value = coefficient.norm().sqrt();
            }
        }
    }

    /// Yaw of the query frame in the candidate frame from two ring spectra (module doc).
    fn relative_yaw(
        &self,
        query_spectrum: &[Complex32],
        candidate_spectrum: &[Complex32],
    ) -> Option<YawEstimate> {
        let sectors = self.sectors;
        // Query sector j sees what candidate sector j + s sees when the query is turned by
        // s·sector: corr(s) = Σ_r Σ_j q_rj c_r,j+s = (1/S) Σ_k conj(Q_k) C_k e^{2πiks/S}.
        let mut cross = vec![Complex32::new(0.0, 0.0); sectors];
        let (mut query_energy, mut candidate_energy) = (0.0f64, 0.0f64);
        for (q_ring, c_ring) in query_spectrum
            .chunks_exact(sectors)
            .zip(candidate_spectrum.chunks_exact(sectors))
        {
            for ((sum, q), c) in cross.iter_mut().zip(q_ring).zip(c_ring) {
                *sum += q.conj() * c;
                // Parseval: Σ_j q_j² = (1/S) Σ_k |Q_k|².
                query_energy += f64::from(q.norm_sqr());
                candidate_energy += f64::from(c.norm_sqr());
            }
        }
        let norm = (query_energy * candidate_energy).sqrt() / sectors as f64;
        if !(norm > 0.0 && norm.is_finite()) {
            return None;
        }
        // Zero-pad the cross spectrum to U·S (the Nyquist bin split between both ends).
        let upsampled = sectors * YAW_UPSAMPLING;
        let mut padded = vec![Complex32::new(0.0, 0.0); upsampled];
        let half = sectors / 2;
        for (k, &value) in cross.iter().enumerate() {
            if sectors % 2 == 0 && k == half {
                padded[half] += value * 0.5;
                padded[upsampled - half] += value * 0.5;
            } else if k <= half {
                padded[k] = value;
            } else {
                padded[upsampled - (sectors - k)] = value;
            }
        }
        let mut scratch =
            vec![Complex32::new(0.0, 0.0); self.inverse_upsampled.get_inplace_scratch_len()];
        self.inverse_upsampled
            .process_with_scratch(&mut padded, &mut scratch);
        // Unnormalised inverse: entry m is S · corr(m / U).
        let (best, peak) = padded.iter().enumerate().map(|(m, v)| (m, v.re)).fold(
            (0, f32::NEG_INFINITY),
            |acc, (m, v)| {
                if v > acc.1 {
                    (m, v)
                } else {
                    acc
                }
            },
        );
        let before = padded[(best + upsampled - 1) % upsampled].re;
        let after = padded[(best + 1) % upsampled].re;
        let curvature = before - 2.0 * peak + after;
        let offset = if curvature < 0.0 {
            (0.5 * (before - after) / curvature).clamp(-0.5, 0.5)
        } else {
            0.0
        };
        let shift_sectors = (best as f64 + f64::from(offset)) / YAW_UPSAMPLING as f64;
        let yaw_rad = mapmerge_geometry::wrap_angle_rad(shift_sectors * self.sector_rad);
        let score = (f64::from(peak) / sectors as f64 / norm).clamp(0.0, 1.0);
        Some(YawEstimate { yaw_rad, score })
    }
}

/// The translation-invariant 2D spectrum (module doc), with its FFT plans.
#[derive(Clone)]
struct ProjectionSpectrum {
    directions: usize,
    bins: usize,
    bands: usize,
    harmonics: usize,
    radius_m: f64,
    bin_m: f64,
    /// `(cos φ_d, sin φ_d)` of every direction `φ_d = d · π / directions`.
    axes: Vec<(f64, f64)>,
    along: Arc<dyn Fft<f32>>,
    around: Arc<dyn Fft<f32>>,
}

impl std::fmt::Debug for ProjectionSpectrum {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ProjectionSpectrum")
            .field("directions", &self.directions)
            .field("bins", &self.bins)
            .field("bands", &self.bands)
            .field("harmonics", &self.harmonics)
            .field("radius_m", &self.radius_m)
            .finish()
    }
}

impl ProjectionSpectrum {
    fn new(params: &RingSpectrumParams, radius_m: f64) -> Self {
        let directions = params.direction_count.clamp(4, MAX_SECTORS);
        let bands = params.ring_count.clamp(1, MAX_SECTORS / 2 - 1);
        let bins = params.projection_bins.clamp(2 * bands + 2, MAX_SECTORS);
        let harmonics = params.harmonic_count.clamp(1, directions / 2 + 1);
        let mut planner = FftPlanner::<f32>::new();
        let axes = (0..directions)
            .map(|d| (d as f64 * std::f64::consts::PI / directions as f64).sin_cos())
            .map(|(sin, cos)| (cos, sin))
            .collect();
        Self {
            directions,
            bins,
            bands,
            harmonics,
            radius_m,
            bin_m: 2.0 * radius_m / bins as f64,
            axes,
            along: planner.plan_fft_forward(bins),
            around: planner.plan_fft_forward(directions),
        }
    }

    fn dim(&self) -> usize {
        self.bands * self.harmonics
    }

    /// Writes the `bands × harmonics` invariants of `points` (uncompressed, not normalised)
    /// into `out` (at least `dim()` long).
    fn describe(&self, points: &[Point2], out: &mut [f32]) {
        let (directions, bins) = (self.directions, self.bins);
        // 1. Projections p_d(s) = Σ w · δ(s − x·u_d), linearly splatted into bins.
        let mut projections = vec![Complex32::new(0.0, 0.0); directions * bins];
        let radius_sq = self.radius_m * self.radius_m;
        for p in points {
            let range_sq = p.norm_squared();
            if !range_sq.is_finite() || range_sq >= radius_sq {
                continue;
            }
            // A smooth taper to 0 at the radius, so points entering or leaving the disc (a
            // move of the centre) change the spectrum gradually.
            let taper = 1.0 - range_sq / radius_sq;
            let weight = (taper * taper) as f32;
            for (row, &(cos, sin)) in projections.chunks_exact_mut(bins).zip(&self.axes) {
                let x = (p.x * cos + p.y * sin + self.radius_m) / self.bin_m - 0.5;
                let x0 = x.floor();
                let f = (x - x0) as f32;
                let i = x0 as isize;
                if let Some(v) = usize::try_from(i).ok().and_then(|i| row.get_mut(i)) {
                    v.re += weight * (1.0 - f);
                }
                if let Some(v) = usize::try_from(i + 1).ok().and_then(|i| row.get_mut(i)) {
                    v.re += weight * f;
                }
            }
        }
        let scratch_len = self
            .along
            .get_inplace_scratch_len()
            .max(self.around.get_inplace_scratch_len());
        let mut scratch = vec![Complex32::new(0.0, 0.0); scratch_len];
        // 2. |FFT| along each projection (Fourier slice: the 2D spectrum on the line at φ_d;
        //    its magnitude ignores where the points are, only their layout counts).
        self.along
            .process_with_scratch(&mut projections, &mut scratch);
        // 3. Per band, the profile over directions; a turn of the submap shifts it circularly
        //    (modulo π: |F(−ω)| = |F(ω)|), so its DFT magnitudes ignore the turn.
        let mut around = vec![Complex32::new(0.0, 0.0); self.bands * directions];
        for (d, row) in projections.chunks_exact(bins).enumerate() {
            for (band, coefficient) in row.iter().skip(1).take(self.bands).enumerate() {
                if let Some(slot) = around.get_mut(band * directions + d) {
                    *slot = Complex32::new(coefficient.norm(), 0.0);
                }
            }
        }
        self.around.process_with_scratch(&mut around, &mut scratch);
        for (band_out, band) in out
            .chunks_mut(self.harmonics)
            .zip(around.chunks_exact(directions))
        {
            for (o, v) in band_out.iter_mut().zip(band) {
                // Square-root compression: long walls do not drown the rest.
                *o = v.norm().sqrt();
            }
        }
    }
}

/// Subtracts the mean entry, then scales to unit L2 norm, so the cosine between two vectors is
/// their correlation coefficient: all magnitudes are positive and fall off with the harmonic
/// in every place, and without centring that shared shape makes any two places look alike.
fn center_and_normalize(values: &mut [f32]) {
    if values.iter().all(|&v| v == 0.0) {
        return;
    }
    let mean = values.iter().sum::<f32>() / values.len().max(1) as f32;
    for v in values.iter_mut() {
        *v -= mean;
    }
    normalize(values);
}

/// Scales `values` to unit L2 norm (all zeros stay zeros).
fn normalize(values: &mut [f32]) {
    let norm = values.iter().map(|v| v * v).sum::<f32>().sqrt();
    if norm > 0.0 && norm.is_finite() {
        for v in values {
            *v /= norm;
        }
    } else {
        values.fill(0.0);
    }
}

/// The 2D projection-spectrum descriptor (module doc): translation-invariant spectrum for
/// association, polar image for the yaw. Building one plans its FFTs; share it.
#[derive(Clone, Debug)]
pub struct RingSpectrumDescriptor {
    params: RingSpectrumParams,
    projection: ProjectionSpectrum,
    polar: PolarSpectrum,
}

impl RingSpectrumDescriptor {
    /// A descriptor with `params` (clamped to valid values, see their docs).
    pub fn new(params: &RingSpectrumParams) -> Self {
        let radius_m = if params.max_radius_m.is_finite() && params.max_radius_m > 0.0 {
            params.max_radius_m
        } else {
            10.0
        };
        let projection = ProjectionSpectrum::new(params, radius_m);
        // The yaw image needs no harmonics beyond the first.
        let polar = PolarSpectrum::new(params.yaw_ring_count, params.yaw_sector_count, 1, radius_m);
        Self {
            params: RingSpectrumParams {
                max_radius_m: radius_m,
                direction_count: projection.directions,
                projection_bins: projection.bins,
                ring_count: projection.bands,
                harmonic_count: projection.harmonics,
                yaw_ring_count: polar.rings,
                yaw_sector_count: polar.sectors,
            },
            projection,
            polar,
        }
    }

    /// The parameters in use (after clamping).
    pub fn params(&self) -> &RingSpectrumParams {
        &self.params
    }

    /// The polar occupancy image of `points` used for the yaw (`[ring][sector]`, soft-binned
    /// point counts; sector 0 starts at the x axis, counter-clockwise).
    pub fn polar_image(&self, points: &[Point2]) -> Vec<f32> {
        let mut image = vec![0.0f32; self.polar.image_len()];
        for p in points {
            let range_m = p.norm();
            if range_m.is_finite() {
                self.polar
                    .splat(&mut image, range_m, p.y.atan2(p.x), 1.0, Combine::Sum);
            }
        }
        image
    }

    fn polar_spectrum(&self, points: &[Point2]) -> Vec<Complex32> {
        let image = self.polar_image(points);
        let mut spectrum = Vec::with_capacity(image.len());
        self.polar.ring_spectra(&image, &mut spectrum);
        spectrum
    }
}

impl Default for RingSpectrumDescriptor {
    fn default() -> Self {
        Self::new(&RingSpectrumParams::default())
    }
}

impl SubmapDescriptor for RingSpectrumDescriptor {
    type Point = Point2;

    fn dim(&self) -> usize {
        self.projection.dim()
    }

    fn describe_into(&self, points: &[Point2], out: &mut [f32]) {
        out.fill(0.0);
        let dim = self.dim();
        if out.len() >= dim {
            let row = &mut out[..dim];
            self.projection.describe(points, row);
            center_and_normalize(row);
        } else {
            let mut full = vec![0.0f32; dim];
            self.projection.describe(points, &mut full);
            center_and_normalize(&mut full);
            for (o, v) in out.iter_mut().zip(&full) {
                *o = *v;
            }
        }
    }

    fn relative_yaw(&self, query: &[Point2], candidate: &[Point2]) -> Option<YawEstimate> {
        if query.is_empty() || candidate.is_empty() {
            return None;
        }
        self.polar
            .relative_yaw(&self.polar_spectrum(query), &self.polar_spectrum(candidate))
    }
}

/// The 3D ring-spectrum descriptor: height and density channels (module doc).
#[derive(Clone, Debug)]
pub struct RingSpectrumDescriptor3 {
    params: RingSpectrum3Params,
    polar: PolarSpectrum,
}

impl RingSpectrumDescriptor3 {
    /// A descriptor with `params` (clamped to valid values).
    pub fn new(params: &RingSpectrum3Params) -> Self {
        let polar = PolarSpectrum::new(
            params.ring_count,
            params.sector_count,
            params.harmonic_count,
            if params.max_radius_m.is_finite() && params.max_radius_m > 0.0 {
                params.max_radius_m
            } else {
                50.0
            },
        );
        let finite_or = |v: f64, fallback: f64| if v.is_finite() { v } else { fallback };
        Self {
            params: RingSpectrum3Params {
                ring_count: polar.rings,
                sector_count: polar.sectors,
                harmonic_count: polar.harmonics,
                max_radius_m: polar.radius_m,
                sensor_height_m: finite_or(params.sensor_height_m, 1.73),
                max_height_m: finite_or(params.max_height_m, 10.0).max(1e-3),
            },
            polar,
        }
    }

    /// The parameters in use (after clamping).
    pub fn params(&self) -> &RingSpectrum3Params {
        &self.params
    }

    /// The two polar images (`[ring][sector]` each): maximum height above the ground (m,
    /// clipped to `[0, max_height_m]`) and soft-binned point count.
    pub fn polar_images(&self, points: &[Point3]) -> (Vec<f32>, Vec<f32>) {
        let mut height = vec![0.0f32; self.polar.image_len()];
        let mut count = vec![0.0f32; self.polar.image_len()];
        for p in points {
            let range_m = p.x.hypot(p.y);
            let height_m = (p.z + self.params.sensor_height_m).clamp(0.0, self.params.max_height_m);
            if !(range_m.is_finite() && height_m.is_finite()) {
                continue;
            }
            let angle_rad = p.y.atan2(p.x);
            self.polar.splat(
                &mut height,
                range_m,
                angle_rad,
                height_m as f32,
                Combine::Max,
            );
            self.polar
                .splat(&mut count, range_m, angle_rad, 1.0, Combine::Sum);
        }
        (height, count)
    }

    /// Ring spectra of both channels (height first), the count channel log-compressed.
    fn spectra(&self, points: &[Point3]) -> (Vec<Complex32>, Vec<Complex32>) {
        let (height, mut count) = self.polar_images(points);
        for c in &mut count {
            *c = c.ln_1p();
        }
        let mut height_spectrum = Vec::with_capacity(height.len());
        let mut count_spectrum = Vec::with_capacity(count.len());
        self.polar.ring_spectra(&height, &mut height_spectrum);
        self.polar.ring_spectra(&count, &mut count_spectrum);
        (height_spectrum, count_spectrum)
    }
}

impl Default for RingSpectrumDescriptor3 {
    fn default() -> Self {
        Self::new(&RingSpectrum3Params::default())
    }
}

impl SubmapDescriptor for RingSpectrumDescriptor3 {
    type Point = Point3;

    fn dim(&self) -> usize {
        2 * self.polar.rings * self.polar.harmonics
    }

    fn describe_into(&self, points: &[Point3], out: &mut [f32]) {
        out.fill(0.0);
        let (height_spectrum, count_spectrum) = self.spectra(points);
        let half = self.polar.rings * self.polar.harmonics;
        let mut full = vec![0.0f32; 2 * half];
        let (height_out, count_out) = full.split_at_mut(half);
        self.polar.harmonic_magnitudes(&height_spectrum, height_out);
        self.polar.harmonic_magnitudes(&count_spectrum, count_out);
        // Each channel to unit norm, then the whole: both channels weigh the same.
        center_and_normalize(height_out);
        center_and_normalize(count_out);
        normalize(&mut full);
        for (o, v) in out.iter_mut().zip(&full) {
            *o = *v;
        }
    }

    fn relative_yaw(&self, query: &[Point3], candidate: &[Point3]) -> Option<YawEstimate> {
        if query.is_empty() || candidate.is_empty() {
            return None;
        }
        // The height channel carries the structure (Scan Context's bin value).
        let (query_height, _) = self.spectra(query);
        let (candidate_height, _) = self.spectra(candidate);
        self.polar.relative_yaw(&query_height, &candidate_height)
    }
}

impl Validate for RingSpectrumParams {
    fn check(&self, check: &mut Checker) {
        check
            .real(
                "max_radius_m",
                self.max_radius_m,
                Real::positive_up_to(1000.0),
            )
            .size("direction_count", self.direction_count, 4, 4096)
            .size("ring_count", self.ring_count, 1, 1024)
            .size(
                "projection_bins",
                self.projection_bins,
                2 * self.ring_count.min(1024) as u64 + 2,
                65_536,
            )
            .size(
                "harmonic_count",
                self.harmonic_count,
                1,
                self.direction_count.min(4096) as u64 / 2 + 1,
            )
            .size("yaw_ring_count", self.yaw_ring_count, 1, 1024)
            .size("yaw_sector_count", self.yaw_sector_count, 1, 4096);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cosine_distance_of_zero_vectors_is_one() {
        assert_eq!(cosine_distance(&[0.0, 0.0], &[1.0, 0.0]), 1.0);
        assert!(cosine_distance(&[1.0, 2.0], &[2.0, 4.0]).abs() < 1e-6);
    }

    #[test]
    fn rows_index_and_short_outputs_do_not_panic() {
        let descriptor = RingSpectrumDescriptor::default();
        let points = [Point2::new(1.0, 2.0), Point2::new(-3.0, 0.5)];
        let mut short = [0.0f32; 5];
        descriptor.describe_into(&points, &mut short);
        let mut long = vec![9.0f32; descriptor.dim() + 3];
        descriptor.describe_into(&points, &mut long);
        assert_eq!(&long[descriptor.dim()..], &[0.0; 3]);
        let rows = DescriptorRows {
            dim: 2,
            values: vec![1.0, 2.0, 3.0, 4.0],
        };
        assert_eq!(rows.len(), 2);
        assert_eq!(rows.row(1), Some(&[3.0f32, 4.0][..]));
        assert_eq!(rows.row(2), None);
        assert!(DescriptorRows::default().is_empty());
    }

    #[test]
    fn silly_params_are_clamped() {
        let descriptor = RingSpectrumDescriptor::new(&RingSpectrumParams {
            max_radius_m: f64::NAN,
            direction_count: 1,
            projection_bins: 3,
            ring_count: 4,
            harmonic_count: 100,
            yaw_ring_count: 0,
            yaw_sector_count: 0,
        });
        let p = descriptor.params();
        assert_eq!(
            (
                p.direction_count,
                p.projection_bins,
                p.ring_count,
                p.harmonic_count
            ),
            (4, 10, 4, 3)
        );
        assert_eq!((p.yaw_ring_count, p.yaw_sector_count), (1, 4));
        assert_eq!(p.max_radius_m, 10.0);
        assert_eq!(descriptor.dim(), 12);
        let v = descriptor.describe(&[Point2::new(f64::NAN, 1.0), Point2::new(1.0, 1.0)]);
        assert!(v.iter().all(|x| x.is_finite()));
    }
}
