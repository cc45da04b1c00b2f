//! Seeded k-means on rows of `f64` points of any dimension: k-means++ seeding (Arthur &
//! Vassilvitskii 2007) then Lloyd iterations, several restarts, the lowest inertia kept.
//!
//! AutoMerge uses k-means twice: to cut candidate matches into zones (Sec. V-A) and to cluster
//! the rows of the Laplacian's eigenvectors into groups (Sec. VI-A, Algorithm 1, line 7). Both
//! callers need the same answer for the same input, so every restart draws from its own
//! ChaCha8 stream of `seed` and ties go to the lower restart; labels are renumbered by first
//! appearance, so the result does not depend on which centre a restart happened to seed first.
//!
//! Degenerate input is handled rather than refused: `k ≥ n` or many duplicate points give at
//! most as many clusters as there are distinct points (k-means++ stops when every point already
//! coincides with a centre), and a cluster that loses all its points during Lloyd is re-seeded
//! with the point farthest from its centroid.

use mapmerge_params::{Checker, Validate};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Work (points × clusters × dimension × restarts) above which restarts run on rayon.
const PARALLEL_WORK: usize = 1 << 18;

/// Parameters of [`kmeans`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct KMeansParams {
    /// Independent k-means++ seedings, each refined by Lloyd; the one with the lowest inertia
    /// wins (default: 8). More restarts make a bad local minimum less likely at linear cost.
    /// 0 is treated as 1.
    pub restarts: usize,
    /// Lloyd iterations per restart (default: 100); Lloyd stops earlier when no label changes.
    pub max_iterations: usize,
    /// Seed of the ChaCha8 generator; restart `r` uses stream `r` of this seed (default: 0).
    pub seed: u64,
}

impl Default for KMeansParams {
    fn default() -> Self {
        Self {
            restarts: 8,
            max_iterations: 100,
            seed: 0,
        }
    }
}

impl Validate for KMeansParams {
    fn check(&self, check: &mut Checker) {
        check.size("restarts", self.restarts, 0, 10_000).size(
            "max_iterations",
            self.max_iterations,
            1,
            10_000,
        );
    }
}

/// Why [`kmeans`] refused its input.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum KMeansError {
    /// Points must have at least one coordinate.
    #[error("k-means points need a dimension of at least 1")]
    ZeroDimension,
    /// The flat buffer is not a whole number of rows.
    #[error("{len} values do not form rows of dimension {dim}")]
    RaggedRows { len: usize, dim: usize },
    /// A coordinate is NaN or infinite.
    #[error("k-means point {index} has a non-finite coordinate")]
    NonFinite { index: usize },
    /// `k = 0` was asked for a non-empty point set.
    #[error("k-means needs k ≥ 1 for {points} points")]
    ZeroClusters { points: usize },
}

/// The best clustering over all restarts.
#[derive(Clone, Debug, PartialEq)]
pub struct KMeansResult {
    /// Cluster of every point, `0..clusters()`, numbered by first appearance (point 0 is in
    /// cluster 0).
    pub labels: Vec<usize>,
    /// Centroids, row-major `clusters() × dim`, in label order.
    pub centroids: Vec<f64>,
    /// Dimension of the points.
    pub dim: usize,
    /// Sum of squared distances of the points to their centroids.
    pub inertia: f64,
}

impl KMeansResult {
    /// Number of non-empty clusters; at most the `k` asked for and at most the number of
    /// distinct points.
    pub fn clusters(&self) -> usize {
        self.centroids.len().checked_div(self.dim).unwrap_or(0)
    }

    /// Centroid of cluster `cluster`, or `None` past the last.
    pub fn centroid(&self, cluster: usize) -> Option<&[f64]> {
        let start = cluster.checked_mul(self.dim)?;
        self.centroids.get(start..start + self.dim)
    }

    /// Members of every cluster, each in ascending point order.
    pub fn members(&self) -> Vec<Vec<usize>> {
        let mut members = vec![Vec::new(); self.clusters()];
        for (point, &label) in self.labels.iter().enumerate() {
            if let Some(cluster) = members.get_mut(label) {
                cluster.push(point);
            }
        }
        members
    }
}

/// Clusters the rows of `points` (row-major, `dim` values per point) into at most `k` clusters.
///
/// Deterministic for a given `params.seed`. An empty point set gives an empty result.
pub fn kmeans(
    points: &[f64],
    dim: usize,
    k: usize,
    params: &KMeansParams,
) -> Result<KMeansResult, KMeansError> {
    if dim == 0 {
        return Err(KMeansError::ZeroDimension);
    }
    if points.len() % dim != 0 {
        return Err(KMeansError::RaggedRows {
            len: points.len(),
            dim,
        });
    }
    if let Some(position) = points.iter().position(|value| !value.is_finite()) {
        return Err(KMeansError::NonFinite {
            index: position / dim,
        });
    }
    let point_count = points.len() / dim;
    if point_count == 0 {
        return Ok(KMeansResult {
            labels: Vec::new(),
            centroids: Vec::new(),
            dim,
            inertia: 0.0,
        });
    }
    if k == 0 {
        return Err(KMeansError::ZeroClusters {
            points: point_count,
        });
    }
    let k = k.min(point_count);
    let restarts = params.restarts.max(1);
    let run = |restart: usize| {
        let mut rng = ChaCha8Rng::seed_from_u64(params.seed);
        rng.set_stream(restart as u64);
        lloyd(points, dim, k, params.max_iterations, &mut rng)
    };
    let work = point_count
        .saturating_mul(k)
        .saturating_mul(dim)
        .saturating_mul(restarts);
    let runs: Vec<Restart> = if work >= PARALLEL_WORK && restarts > 1 {
        (0..restarts).into_par_iter().map(run).collect()
    } else {
        (0..restarts).map(run).collect()
    };
    // Lowest inertia; ties go to the earlier restart, so the choice is deterministic.
    let mut best: Option<Restart> = None;
    for candidate in runs {
        if best
            .as_ref()
            .is_none_or(|current| candidate.inertia < current.inertia)
        {
            best = Some(candidate);
        }
    }
    let Some(best) = best else {
        return Err(KMeansError::ZeroClusters {
            points: point_count,
        });
    };
    Ok(canonical(best, dim))
}

/// One restart's outcome before renumbering.
struct Restart {
    labels: Vec<usize>,
    centroids: Vec<f64>,
    inertia: f64,
}

fn squared_distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

fn row(points: &[f64], dim: usize, index: usize) -> &[f64] {
    &points[index * dim..(index + 1) * dim]
}

/// k-means++ seeding then Lloyd. Buffers are allocated once per restart; the loops over points
/// and centroids allocate nothing.
fn lloyd(
    points: &[f64],
    dim: usize,
    k: usize,
    max_iterations: usize,
    rng: &mut ChaCha8Rng,
) -> Restart {
    let point_count = points.len() / dim;
    let mut centroids = Vec::with_capacity(k * dim);
    let mut nearest_sq = vec![f64::INFINITY; point_count];

    // k-means++: first centre uniform, then each next one with probability ∝ D(x)².
    let first = rng.random_range(0..point_count);
    centroids.extend_from_slice(row(points, dim, first));
    update_nearest(points, dim, &centroids[0..dim], &mut nearest_sq);
    while centroids.len() < k * dim {
        let total: f64 = nearest_sq.iter().sum();
        if total <= 0.0 {
            // Every point coincides with a centre: no further distinct centre exists.
            break;
        }
        let target = rng.random::<f64>() * total;
        let mut cumulative = 0.0;
        let mut chosen = None;
        for (index, &d_sq) in nearest_sq.iter().enumerate() {
            if d_sq <= 0.0 {
                continue;
            }
            cumulative += d_sq;
            chosen = Some(index);
            if cumulative > target {
                break;
            }
        }
        let Some(chosen) = chosen else { break };
        let start = centroids.len();
        centroids.extend_from_slice(row(points, dim, chosen));
        update_nearest(points, dim, &centroids[start..start + dim], &mut nearest_sq);
    }
    let k = centroids.len() / dim;

    let mut labels = vec![0usize; point_count];
    let mut sums = vec![0.0; k * dim];
    let mut counts = vec![0usize; k];
    assign(points, dim, &centroids, &mut labels, &mut nearest_sq);
    for _ in 0..max_iterations {
        update_centroids(
            points,
            dim,
            &mut centroids,
            &mut labels,
            &mut nearest_sq,
            &mut sums,
            &mut counts,
        );
        if !assign(points, dim, &centroids, &mut labels, &mut nearest_sq) {
            break;
        }
    }
    let inertia = nearest_sq.iter().sum();
    Restart {
        labels,
        centroids,
        inertia,
    }
}

fn update_nearest(points: &[f64], dim: usize, centre: &[f64], nearest_sq: &mut [f64]) {
    for (point, d_sq) in points.chunks_exact(dim).zip(nearest_sq.iter_mut()) {
        let candidate = squared_distance(point, centre);
        if candidate < *d_sq {
            *d_sq = candidate;
        }
    }
}

/// Assigns every point to its nearest centroid (ties to the lower index); true when a label
/// changed.
fn assign(
    points: &[f64],
    dim: usize,
    centroids: &[f64],
    labels: &mut [usize],
    nearest_sq: &mut [f64],
) -> bool {
    let mut changed = false;
    for ((point, label), d_sq) in points
        .chunks_exact(dim)
        .zip(labels.iter_mut())
        .zip(nearest_sq.iter_mut())
    {
        let mut best = 0;
        let mut best_sq = f64::INFINITY;
        for (cluster, centre) in centroids.chunks_exact(dim).enumerate() {
            let candidate = squared_distance(point, centre);
            if candidate < best_sq {
                best_sq = candidate;
                best = cluster;
            }
        }
        changed |= *label != best;
        *label = best;
        *d_sq = best_sq;
    }
    changed
}

/// Centroids as the means of their points; an empty cluster takes the point farthest from its
/// own centroid (that point's cluster keeps others, since its distance is positive).
fn update_centroids(
    points: &[f64],
    dim: usize,
    centroids: &mut [f64],
    labels: &mut [usize],
    nearest_sq: &mut [f64],
    sums: &mut [f64],
    counts: &mut [usize],
) {
    sums.fill(0.0);
    counts.fill(0);
    for (point, &label) in points.chunks_exact(dim).zip(labels.iter()) {
        counts[label] += 1;
        for (sum, value) in sums[label * dim..(label + 1) * dim].iter_mut().zip(point) {
            *sum += value;
        }
    }
    for cluster in 0..counts.len() {
        if counts[cluster] > 0 {
            continue;
        }
        let mut farthest = None;
        let mut farthest_sq = 0.0;
        for (index, (&d_sq, &label)) in nearest_sq.iter().zip(labels.iter()).enumerate() {
            if d_sq > farthest_sq && counts[label] > 1 {
                farthest_sq = d_sq;
                farthest = Some(index);
            }
        }
        let Some(index) = farthest else { continue };
        let old = labels[index];
        let point = row(points, dim, index);
        for (sum, value) in sums[old * dim..(old + 1) * dim].iter_mut().zip(point) {
            *sum -= value;
        }
        counts[old] -= 1;
        sums[cluster * dim..(cluster + 1) * dim].copy_from_slice(point);
        counts[cluster] = 1;
        labels[index] = cluster;
        nearest_sq[index] = 0.0;
    }
    for ((centre, sum), &count) in centroids
        .chunks_exact_mut(dim)
        .zip(sums.chunks_exact(dim))
        .zip(counts.iter())
    {
        if count > 0 {
            let scale = 1.0 / count as f64;
            for (c, s) in centre.iter_mut().zip(sum) {
                *c = s * scale;
            }
        }
    }
}

/// Renumbers clusters by first appearance and drops clusters left without points.
fn canonical(run: Restart, dim: usize) -> KMeansResult {
    let old_count = run.centroids.len() / dim;
    let mut new_of_old = vec![usize::MAX; old_count];
    let mut centroids = Vec::with_capacity(run.centroids.len());
    let mut labels = run.labels;
    for label in &mut labels {
        if new_of_old[*label] == usize::MAX {
            new_of_old[*label] = centroids.len() / dim;
            centroids.extend_from_slice(row(&run.centroids, dim, *label));
        }
        *label = new_of_old[*label];
    }
    KMeansResult {
        labels,
        centroids,
        dim,
        inertia: run.inertia,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn blobs() -> Vec<f64> {
        // Three tight 2-D blobs, interleaved in input order.
        let centres = [[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]];
        let mut points = Vec::new();
        for i in 0..30 {
            let c = centres[i % 3];
            let jitter = (i as f64 * 0.37).sin() * 0.5;
            points.extend_from_slice(&[c[0] + jitter, c[1] - jitter]);
        }
        points
    }

    #[test]
    fn separates_blobs_and_numbers_by_first_appearance() {
        let result = kmeans(&blobs(), 2, 3, &KMeansParams::default()).unwrap();
        assert_eq!(result.clusters(), 3);
        for (i, &label) in result.labels.iter().enumerate() {
            assert_eq!(label, i % 3, "point {i}");
        }
        assert!(result.inertia < 30.0 * 0.5);
        let c1 = result.centroid(1).unwrap();
        assert!((c1[0] - 10.0).abs() < 0.5 && c1[1].abs() < 0.5);
        assert!(result.centroid(3).is_none());
    }

    #[test]
    fn same_seed_same_answer() {
        let params = KMeansParams {
            seed: 42,
            ..KMeansParams::default()
        };
        let a = kmeans(&blobs(), 3, 4, &params).unwrap();
        let b = kmeans(&blobs(), 3, 4, &params).unwrap();
        assert_eq!(a, b);
    }

    #[test]
    fn k_at_least_n_gives_one_cluster_per_distinct_point() {
        let points = [1.0, 5.0, 1.0, 9.0];
        let result = kmeans(&points, 1, 10, &KMeansParams::default()).unwrap();
        assert_eq!(result.clusters(), 3);
        assert_eq!(result.labels, vec![0, 1, 0, 2]);
        assert_eq!(result.inertia, 0.0);
    }

    #[test]
    fn all_duplicates_give_one_cluster() {
        let points = vec![2.5; 12];
        let result = kmeans(&points, 3, 3, &KMeansParams::default()).unwrap();
        assert_eq!(result.clusters(), 1);
        assert_eq!(result.labels, vec![0; 4]);
    }

    #[test]
    fn empty_cluster_is_reseeded_from_the_farthest_point() {
        // A centre nobody is nearest to leaves cluster 1 empty; it takes the point farthest
        // from its centroid (50).
        let points = [0.0, 1.0, 2.0, 50.0];
        let mut centroids = vec![1.0, 1000.0];
        let mut labels = vec![0; 4];
        let mut nearest_sq = vec![0.0; 4];
        assign(&points, 1, &centroids, &mut labels, &mut nearest_sq);
        assert_eq!(labels, vec![0; 4]);
        let mut sums = vec![0.0; 2];
        let mut counts = vec![0; 2];
        update_centroids(
            &points,
            1,
            &mut centroids,
            &mut labels,
            &mut nearest_sq,
            &mut sums,
            &mut counts,
        );
        assert_eq!(labels, vec![0, 0, 0, 1]);
        assert_eq!(centroids, vec![1.0, 50.0]);
    }

    #[test]
    fn refuses_bad_input() {
        let params = KMeansParams::default();
        assert_eq!(
            kmeans(&[1.0], 0, 1, &params),
            Err(KMeansError::ZeroDimension)
        );
        assert_eq!(
            kmeans(&[1.0, 2.0, 3.0], 2, 1, &params),
            Err(KMeansError::RaggedRows { len: 3, dim: 2 })
        );
        assert_eq!(
            kmeans(&[1.0, 2.0, f64::NAN, 0.0], 2, 1, &params),
            Err(KMeansError::NonFinite { index: 1 })
        );
        assert_eq!(
            kmeans(&[1.0], 1, 0, &params),
            Err(KMeansError::ZeroClusters { points: 1 })
        );
        assert_eq!(kmeans(&[], 2, 3, &params).unwrap().clusters(), 0);
    }
}
