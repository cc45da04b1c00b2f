//! Confidences between segments (Yin et al., AutoMerge, Sec. VI-A, Eq. 9) and spectral grouping
//! by the normalised cut (Algorithm 1), offline ([`spectral_groups`]) and as segments arrive
//! ([`IncrementalGrouping`], Sec. VI-B).
//!
//! Algorithm 1 as implemented, on a symmetric weight matrix W (ω_ij ≥ 0, diagonal ignored):
//!
//! 1. Weights below `connection_floor` are no connection. The graph is split into connected
//!    components first. L = I − D^{-1/2} W D^{-1/2} is block diagonal over components, so its
//!    eigenvalues are the union of the components' and counting eigenvalues ≤ θ per component
//!    gives the same total k; running the rest per component keeps k-means from mixing two
//!    components, and the O(m³) eigen-decomposition runs on each component's m instead of n.
//!    Isolated vertices (degree 0) are groups of their own.
//! 2. Per component: the normalised Laplacian (the paper writes `W − D`; Ncut, Eq. 11, is the
//!    normalised one, Ng–Jordan–Weiss / Shi–Malik), its eigen-decomposition (nalgebra's dense
//!    `SymmetricEigen`, O(m³): a few ms for m = 200, fine to a few hundred segments; beyond that
//!    a Lanczos solver for the smallest eigenpairs would be needed), k = the number of
//!    eigenvalues ≤ θ (at least 1).
//! 3. With k > 1: the rows of the first k eigenvectors, normalised to unit length (NJW), are
//!    clustered by k-means into k groups.
//! 4. k-means on the embedding can put two parts into one group that touch only through
//!    another group; every group is split into its connected pieces (edges ≥ the floor) so a
//!    group is always a connected set of segments, which is what one pose graph needs.
//! 5. Canonical order: members ascending, groups by smallest member, so the result is a
//!    function of the weights only, not of how segments were numbered (up to k-means on a
//!    degenerate embedding, which well-separated groups do not have).

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::fmt::Debug;

use mapmerge_params::{Checker, Real, Validate};
use nalgebra::{DMatrix, SymmetricEigen};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::kmeans::{kmeans, KMeansError, KMeansParams};

/// ε of Eq. 9.
const CONFIDENCE_EPSILON: f64 = 1e-4;

/// Eq. 9: the confidence ω_ij ∈ [0, 1] that segments i and j overlap,
/// `exp(−(‖F_i − F_j‖² + C_ω) / (2 L_ij² + ε))`, ε = 1e-4.
///
/// `feature_distance_sq` is ‖F_i − F_j‖² of the overlap's place features, `overlap_length_m`
/// the overlap length L_ij (m), `c_omega` C_ω (m², how strongly ω depends on the overlap length:
/// an overlap of √C_ω m gives at most e^{-1/2}). No overlap (L ≤ 0) or non-finite input gives 0;
/// negative distances and C_ω count as 0.
pub fn confidence(feature_distance_sq: f64, overlap_length_m: f64, c_omega: f64) -> f64 {
    let valid = overlap_length_m > 0.0
        && overlap_length_m.is_finite()
        && feature_distance_sq.is_finite()
        && c_omega.is_finite();
    if !valid {
        return 0.0;
    }
    let numerator = feature_distance_sq.max(0.0) + c_omega.max(0.0);
    (-numerator / (2.0 * overlap_length_m * overlap_length_m + CONFIDENCE_EPSILON)).exp()
}

/// Parameters of [`spectral_groups`] and [`IncrementalGrouping`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GroupingParams {
    /// θ of Algorithm 1 (default: 0.02): the number of groups of a component is the number of
    /// eigenvalues of its normalised Laplacian ≤ θ. A cut between two parts costs about
    /// `cut · (1/vol₁ + 1/vol₂)` (Ncut), so θ is the relative weight below which a connection
    /// is cut. Lower keeps weakly linked parts together (a plain chain of m equally weighted
    /// segments has λ₂ = 1 − cos(π/(m − 1)), so θ = 0.02 keeps chains of up to 16 together);
    /// higher cuts more readily.
    pub theta: f64,
    /// Weights below this are no connection at all (default: 1e-3). The normalised Laplacian
    /// is scale free, so without a floor a segment tied to the others only by negligible
    /// weights would still be pulled into their group; Eq. 9 gives ω < 1e-3 for overlaps
    /// shorter than about √(C_ω / 13.8).
    pub connection_floor: f64,
    /// k-means on the eigenvector rows (default: 8 restarts, 100 iterations, seed 0).
    pub kmeans: KMeansParams,
}

impl Default for GroupingParams {
    fn default() -> Self {
        Self {
            theta: 0.02,
            connection_floor: 1e-3,
            kmeans: KMeansParams::default(),
        }
    }
}

impl Validate for GroupingParams {
    fn check(&self, check: &mut Checker) {
        // Eigenvalues of a normalised Laplacian lie in [0, 2]; weights (Eq. 9) in [0, 1].
        check
            .real("theta", self.theta, Real::within(0.0, 2.0))
            .real(
                "connection_floor",
                self.connection_floor,
                Real::positive_up_to(1.0),
            )
            .nested("kmeans", &self.kmeans);
    }
}

/// Why grouping refused its input.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum GroupingError {
    /// The weights are not an n × n matrix.
    #[error("{len} weights do not form a square matrix")]
    NotSquare { len: usize },
    /// A weight is negative, NaN or infinite.
    #[error("weight ({row}, {col}) = {value} is not a finite non-negative number")]
    InvalidWeight { row: usize, col: usize, value: f64 },
    /// W is not symmetric.
    #[error("weights ({row}, {col}) and ({col}, {row}) differ")]
    Asymmetric { row: usize, col: usize },
    /// A parameter is outside its range.
    #[error(transparent)]
    InvalidParams(#[from] mapmerge_params::ParamError),
    /// The symmetric eigen-decomposition did not converge.
    #[error("eigen-decomposition of a {size}-segment component did not converge")]
    EigenFailed { size: usize },
    /// `set_weight` named a segment that was never added.
    #[error("unknown segment {0}")]
    UnknownSegment(String),
    /// `set_weight` between a segment and itself (Eq. 9: ω_ii = 0).
    #[error("a segment has no weight to itself: {0}")]
    SelfWeight(String),
    #[error("k-means on the spectral embedding failed: {0}")]
    KMeans(#[from] KMeansError),
}

/// Algorithm 1 on the row-major n × n symmetric `weights`: groups of segment indices, each
/// ascending, ordered by smallest member (see the module doc for the steps).
pub fn spectral_groups(
    weights: &[f64],
    params: GroupingParams,
) -> Result<Vec<Vec<usize>>, GroupingError> {
    Validate::validate(&params)?;
    let n = weights.len().isqrt();
    if n * n != weights.len() {
        return Err(GroupingError::NotSquare { len: weights.len() });
    }
    for row in 0..n {
        for col in 0..n {
            let value = weights[row * n + col];
            if !(value.is_finite() && value >= 0.0) {
                return Err(GroupingError::InvalidWeight { row, col, value });
            }
            let mirrored = weights[col * n + row];
            if col > row && (value - mirrored).abs() > 1e-9 * value.max(mirrored).max(1.0) {
                return Err(GroupingError::Asymmetric { row, col });
            }
        }
    }
    let connected = |i: usize, j: usize| i != j && weights[i * n + j] >= params.connection_floor;

    // 1. Connected components (breadth first, vertices in index order).
    let mut component_of = vec![usize::MAX; n];
    let mut components: Vec<Vec<usize>> = Vec::new();
    let mut queue = VecDeque::new();
    for start in 0..n {
        if component_of[start] != usize::MAX {
            continue;
        }
        let id = components.len();
        component_of[start] = id;
        queue.push_back(start);
        let mut members = Vec::new();
        while let Some(v) = queue.pop_front() {
            members.push(v);
            for (u, component) in component_of.iter_mut().enumerate() {
                if *component == usize::MAX && connected(v, u) {
                    *component = id;
                    queue.push_back(u);
                }
            }
        }
        members.sort_unstable();
        components.push(members);
    }

    // 2–4. Per component.
    let per_component: Vec<Result<Vec<Vec<usize>>, GroupingError>> = components
        .par_iter()
        .map(|members| group_component(weights, n, members, &params))
        .collect();
    let mut groups = Vec::with_capacity(n);
    for result in per_component {
        groups.extend(result?);
    }

    // 5. Canonical order.
    for group in &mut groups {
        group.sort_unstable();
    }
    groups.sort_unstable_by_key(|group| group.first().copied());
    Ok(groups)
}

/// Steps 2–4 on one connected component (`members` ascending, global indices).
fn group_component(
    weights: &[f64],
    n: usize,
    members: &[usize],
    params: &GroupingParams,
) -> Result<Vec<Vec<usize>>, GroupingError> {
    let m = members.len();
    // A single edge's normalised Laplacian has eigenvalues {0, 2}: one group.
    if m <= 2 {
        return Ok(vec![members.to_vec()]);
    }
    let local = |i: usize, j: usize| {
        let w = weights[members[i] * n + members[j]];
        if i != j && w >= params.connection_floor {
            w
        } else {
            0.0
        }
    };
    let degree: Vec<f64> = (0..m).map(|i| (0..m).map(|j| local(i, j)).sum()).collect();
    let inv_sqrt_degree: Vec<f64> = degree.iter().map(|d| 1.0 / d.sqrt()).collect();
    // L = I − D^{-1/2} W D^{-1/2} (every degree > 0 inside a component of ≥ 2 vertices).
    let laplacian = DMatrix::from_fn(m, m, |i, j| {
        let identity = if i == j { 1.0 } else { 0.0 };
        identity - inv_sqrt_degree[i] * local(i, j) * inv_sqrt_degree[j]
    });
    let eigen = SymmetricEigen::try_new(laplacian, f64::EPSILON, 1000 * m.max(10))
        .ok_or(GroupingError::EigenFailed { size: m })?;
    let mut order: Vec<usize> = (0..m).collect();
    order.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
    let k = order
        .iter()
        .filter(|&&i| eigen.eigenvalues[i] <= params.theta)
        .count()
        .max(1);
    if k == 1 {
        return Ok(vec![members.to_vec()]);
    }

    // Rows of the first k eigenvectors, each normalised to unit length (Ng–Jordan–Weiss).
    let mut embedding = vec![0.0; m * k];
    for (row, values) in embedding.chunks_exact_mut(k).enumerate() {
        for (value, &column) in values.iter_mut().zip(&order) {
            *value = eigen.eigenvectors[(row, column)];
        }
        let norm = values.iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm > 0.0 {
            values.iter_mut().for_each(|v| *v /= norm);
        }
    }
    let clustering = kmeans(&embedding, k, k, &params.kmeans)?;

    // Split every k-means group into its connected pieces.
    Ok(connected_pieces(members, &clustering.labels, |v, u| {
        local(v, u) > 0.0
    }))
}

/// Groups of `members` (global indices) such that each is one label's connected piece under
/// `adjacent` (local indices). Breadth first from the lowest unvisited vertex.
fn connected_pieces(
    members: &[usize],
    labels: &[usize],
    adjacent: impl Fn(usize, usize) -> bool,
) -> Vec<Vec<usize>> {
    let m = members.len();
    let mut groups = Vec::new();
    let mut seen = vec![false; m];
    let mut queue = VecDeque::new();
    for start in 0..m {
        if seen[start] {
            continue;
        }
        seen[start] = true;
        queue.push_back(start);
        let mut group = Vec::new();
        while let Some(v) = queue.pop_front() {
            group.push(members[v]);
            for u in 0..m {
                if !seen[u] && labels[u] == labels[v] && adjacent(v, u) {
                    seen[u] = true;
                    queue.push_back(u);
                }
            }
        }
        groups.push(group);
    }
    groups
}

/// Spectral grouping as segments arrive one at a time, in any order (Sec. VI-B, Fig. 6).
///
/// Segments are named by a caller key `K`; weights are set (raised or lowered) as evidence
/// arrives. [`groups`](Self::groups) regroups from scratch over all weights, so a wrong early
/// connection is dropped once later evidence makes the cut through it cheap (Fig. 13's
/// recovery). The matrix is built in key order, so the groups depend only on the final keys
/// and weights, never on the order they were added in. The result is cached until a segment or
/// a weight changes.
#[derive(Clone, Debug)]
pub struct IncrementalGrouping<K> {
    params: GroupingParams,
    segments: BTreeSet<K>,
    /// ω per unordered pair, keyed (smaller, larger); zero weights are not stored.
    weights: BTreeMap<(K, K), f64>,
    cached: Option<Vec<Vec<K>>>,
}

impl<K: Ord + Clone + Debug> IncrementalGrouping<K> {
    pub fn new(params: GroupingParams) -> Self {
        Self {
            params,
            segments: BTreeSet::new(),
            weights: BTreeMap::new(),
            cached: None,
        }
    }

    /// Adds a segment (a group of its own until weights connect it); false if already known.
    pub fn add_segment(&mut self, key: K) -> bool {
        let added = self.segments.insert(key);
        if added {
            self.cached = None;
        }
        added
    }

    /// Sets ω between two known segments (0 removes the connection).
    pub fn set_weight(&mut self, a: &K, b: &K, weight: f64) -> Result<(), GroupingError> {
        for key in [a, b] {
            if !self.segments.contains(key) {
                return Err(GroupingError::UnknownSegment(format!("{key:?}")));
            }
        }
        if a == b {
            return Err(GroupingError::SelfWeight(format!("{a:?}")));
        }
        if !(weight.is_finite() && weight >= 0.0) {
            return Err(GroupingError::InvalidWeight {
                row: 0,
                col: 1,
                value: weight,
            });
        }
        let pair = ordered(a, b);
        let previous = if weight > 0.0 {
            self.weights.insert(pair, weight)
        } else {
            self.weights.remove(&pair)
        };
        if previous.unwrap_or(0.0) != weight {
            self.cached = None;
        }
        Ok(())
    }

    /// ω between two segments (0 when unset or unknown).
    pub fn weight(&self, a: &K, b: &K) -> f64 {
        self.weights.get(&ordered(a, b)).copied().unwrap_or(0.0)
    }

    /// The segments, in key order.
    pub fn segments(&self) -> impl Iterator<Item = &K> {
        self.segments.iter()
    }

    pub fn len(&self) -> usize {
        self.segments.len()
    }

    pub fn is_empty(&self) -> bool {
        self.segments.is_empty()
    }

    /// The current groups: keys ascending within a group, groups by smallest key.
    pub fn groups(&mut self) -> Result<&[Vec<K>], GroupingError> {
        if self.cached.is_none() {
            self.cached = Some(self.regroup()?);
        }
        Ok(self.cached.as_deref().unwrap_or(&[]))
    }

    fn regroup(&self) -> Result<Vec<Vec<K>>, GroupingError> {
        let keys: Vec<&K> = self.segments.iter().collect();
        let n = keys.len();
        let index = |key: &K| keys.binary_search(&key).ok();
        let mut matrix = vec![0.0; n * n];
        for ((a, b), &w) in &self.weights {
            if let (Some(i), Some(j)) = (index(a), index(b)) {
                matrix[i * n + j] = w;
                matrix[j * n + i] = w;
            }
        }
        let groups = spectral_groups(&matrix, self.params)?;
        Ok(groups
            .into_iter()
            .map(|group| group.into_iter().map(|i| keys[i].clone()).collect())
            .collect())
    }
}

impl<K: Ord + Clone + Debug> Default for IncrementalGrouping<K> {
    fn default() -> Self {
        Self::new(GroupingParams::default())
    }
}

fn ordered<K: Ord + Clone>(a: &K, b: &K) -> (K, K) {
    if a <= b {
        (a.clone(), b.clone())
    } else {
        (b.clone(), a.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_label_joining_disconnected_parts_is_split() {
        // k-means put 10, 11 and 13 together, but 13 touches them only through 12.
        let members = [10, 11, 12, 13];
        let labels = [0, 0, 1, 0];
        let edges = [(0, 1), (1, 2), (2, 3)];
        let adjacent = |v: usize, u: usize| edges.contains(&(v, u)) || edges.contains(&(u, v));
        let groups = connected_pieces(&members, &labels, adjacent);
        assert_eq!(groups, vec![vec![10, 11], vec![12], vec![13]]);
    }
}
