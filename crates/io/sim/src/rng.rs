//! Seeded randomness: ChaCha8 (reproducible across platforms), independent streams derived
//! from one seed, and the samplers (normal, uniform, exponential; rand 0.9 has no normal without
//! `rand_distr`), which `mapmerge-eval` draws with too.
//!
//! Every random decision of the simulator draws from a stream named by what it is for
//! (world, session route, odometry noise, one scan's range noise, ...), so changing one
//! parameter (say the lidar's noise) leaves every other stream, and so the route, unchanged.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The generator every seeded function of this crate (and of `mapmerge-eval`) uses.
pub type SimRng = ChaCha8Rng;

/// What a derived stream is for (mixed into its seed).
#[derive(Clone, Copy, Debug)]
pub(crate) enum Stream {
    World = 1,
    Changes = 2,
    Route = 3,
    Odometry = 4,
    Lidar = 5,
    Kidnap = 6,
    Furniture = 7,
}

/// SplitMix64's finaliser (Steele, Lea & Flood 2014): a bijective 64-bit mix.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The seed of stream `stream` number `index` under `seed`.
pub(crate) fn derive_seed(seed: u64, stream: Stream, index: u64) -> u64 {
    mix(mix(mix(seed) ^ (stream as u64)) ^ index)
}

/// A generator for stream `stream` number `index` under `seed`.
pub(crate) fn stream_rng(seed: u64, stream: Stream, index: u64) -> SimRng {
    SimRng::seed_from_u64(derive_seed(seed, stream, index))
}

/// A generator seeded directly.
pub fn seeded(seed: u64) -> SimRng {
    SimRng::seed_from_u64(seed)
}

/// A standard normal sample (Box–Muller, the cosine of the pair; the sine discarded).
pub fn gaussian<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    gaussian_pair(rng).0
}

/// Two independent standard normal samples (Box–Muller): `(cosine, sine)`.
pub fn gaussian_pair<R: Rng + ?Sized>(rng: &mut R) -> (f64, f64) {
    // u1 in (0, 1] so that ln(u1) is finite.
    let u1 = 1.0 - rng.random::<f64>();
    let u2 = rng.random::<f64>();
    let radius = (-2.0 * u1.ln()).sqrt();
    let (s, c) = (std::f64::consts::TAU * u2).sin_cos();
    (radius * c, radius * s)
}

/// A uniform sample from `[lo, hi]`; `lo` when the range is empty, without drawing.
pub fn uniform<R: Rng + ?Sized>(rng: &mut R, lo: f64, hi: f64) -> f64 {
    if hi > lo {
        uniform_drawn(rng, lo, hi)
    } else {
        lo
    }
}

/// A uniform sample from `[lo, hi]` that draws even when the range is empty (and then gives
/// `lo`), so that the stream after it does not depend on the range.
pub fn uniform_drawn<R: Rng + ?Sized>(rng: &mut R, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.random::<f64>()
}

/// An exponential sample with mean `mean`.
pub fn exponential<R: Rng + ?Sized>(rng: &mut R, mean: f64) -> f64 {
    // 1 − u in (0, 1], so the logarithm is finite.
    -mean * (1.0 - rng.random::<f64>()).ln()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_pairs_have_unit_variance() {
        let mut rng = seeded(7);
        let n = 100_000;
        let mut samples = Vec::with_capacity(2 * n);
        for _ in 0..n {
            let (a, b) = gaussian_pair(&mut rng);
            samples.push(a);
            samples.push(b);
        }
        let count = samples.len() as f64;
        let mean = samples.iter().sum::<f64>() / count;
        let var = samples.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / count;
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.02, "variance {var}");
    }

    #[test]
    fn streams_differ() {
        let a = derive_seed(1, Stream::Lidar, 0);
        assert_ne!(a, derive_seed(1, Stream::Lidar, 1));
        assert_ne!(a, derive_seed(1, Stream::Route, 0));
        assert_ne!(a, derive_seed(2, Stream::Lidar, 0));
        assert_eq!(a, derive_seed(1, Stream::Lidar, 0));
    }
}
