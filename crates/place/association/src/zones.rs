//! Zones + RANSAC with the edge-length consistency test (Yin et al., AutoMerge, Sec. V-A, Eq. 7).
//!
//! Candidate matches between segment A (query) and segment B (reference) come from sequence
//! matching and single-frame matching on the difference matrix and still contain aliases
//! (look-alike places). They are checked against the submap positions, each segment in its own
//! odometry frame (z = 0 in 2D, so the 3D path shares this), which are unknown to each other:
//! only distances can be compared. Two matches (a₁, b₁), (a₂, b₂) agree when the edge
//! a₁–a₂ in A and the edge b₁–b₂ in B have about the same length (Eq. 7).
//!
//! 1. **Zones.** The matches are cut into `k` zones by k-means. The paper clusters on the feature
//!    distance ([`ZoneClustering::FeatureDistance`]). The default here is the query index
//!    ([`ZoneClustering::QueryIndex`]), so a zone is one contiguous stretch of A: one place where
//!    the segments overlap, which is what a loop edge is. Its edges are short, so odometry drift
//!    along A hardly stretches them, while a zone by feature distance mixes matches from the
//!    whole segment and its long edges need the whole slack of β. Both cut true matches apart
//!    from scattered aliases; both are kept.
//! 2. **RANSAC per zone.** Draw `sample_size` matches; accept the sample when every pair passes
//!    Eq. 7; its inliers are the zone's matches that pass Eq. 7 with every sample member; keep
//!    the largest set (ties: lower summed feature distance). Small zones are enumerated
//!    exhaustively. The consensus is then pruned until every pair of inliers agrees (the match
//!    with most disagreements goes first), and a zone survives with ≥ `min_inliers`.
//! 3. **Cross-check.** Surviving zones that claim different relative placements of the two
//!    segments cannot all be right: zones are taken largest first, and a zone whose inliers
//!    agree (Eq. 7) with fewer than `min_cross_agreement` of the pairs it forms with an already
//!    accepted zone is rejected as aliasing.
//!
//! Eq. 7 alone is `‖e_A‖ ≥ β‖e_B‖ ∧ ‖e_B‖ ≥ β‖e_A‖`, i.e. `|‖e_A‖ − ‖e_B‖| ≤ (1 − β) max`;
//! short edges would then need sub-metre agreement that submap spacing and descriptor
//! tolerance cannot give, so the slack is `max((1 − β) max, edge_tolerance_m)`.

use mapmerge_params::{Checker, Real, Validate};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::kmeans::{kmeans, KMeansError, KMeansParams};
use crate::SubmapMatch;

/// What the zones' k-means clusters on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ZoneClustering {
    /// The match's query (segment A) submap index: a zone is a contiguous stretch of A.
    QueryIndex,
    /// The match's descriptor distance, as the paper (Sec. V-A).
    FeatureDistance,
}

/// Parameters of [`verify_zones`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ZoneParams {
    /// What zones are clustered on (default: `query_index`; see the module doc).
    pub clustering: ZoneClustering,
    /// Number of zones k (default: 4). Lowered to `matches / min_inliers` when there are few
    /// matches, so a zone can reach `min_inliers`. More zones isolate more overlaps from each
    /// other but split long overlaps into pieces that must each survive alone.
    pub zones: usize,
    /// β of Eq. 7 in [0, 1] (default: 0.9): two edges agree when the shorter is at least β
    /// times the longer. Higher is stricter and rejects more aliases, but also true matches
    /// whose odometry drifted by more than 1 − β of the edge length.
    pub beta: f64,
    /// Additive slack for edge lengths in metres (default: 2.0): edges that differ by at most
    /// this always agree. Covers submap spacing and the metres of translation a descriptor
    /// tolerates; larger values let more aliases through on short edges.
    pub edge_tolerance_m: f64,
    /// Matches per RANSAC sample, at least 2 (default: 3). Larger samples pin the placement
    /// down better but are less likely to be outlier-free.
    pub sample_size: usize,
    /// RANSAC samples per zone (default: 200). Zones whose samples can all be listed in this
    /// many draws are enumerated instead.
    pub iterations: usize,
    /// Inliers a zone needs to survive, at least `sample_size` (default: 4).
    pub min_inliers: usize,
    /// Fraction in [0, 1] of inlier pairs between two zones that must agree for the later
    /// (smaller) zone to be kept (default: 0.9). Lower tolerates more drift between distant
    /// overlaps but lets an aliased zone survive next to a true one.
    pub min_cross_agreement: f64,
    /// k-means restarts for the zones (default: 4).
    pub kmeans_restarts: usize,
    /// Seed of k-means and of the RANSAC samples (ChaCha8; zone `z` uses stream `z`)
    /// (default: 0).
    pub seed: u64,
}

impl Default for ZoneParams {
    fn default() -> Self {
        Self {
            clustering: ZoneClustering::QueryIndex,
            zones: 4,
            beta: 0.9,
            edge_tolerance_m: 2.0,
            sample_size: 3,
            iterations: 200,
            min_inliers: 4,
            min_cross_agreement: 0.9,
            kmeans_restarts: 4,
            seed: 0,
        }
    }
}

impl Validate for ZoneParams {
    fn check(&self, check: &mut Checker) {
        check
            .size("zones", self.zones, 1, 10_000)
            .real("beta", self.beta, Real::fraction())
            .real(
                "edge_tolerance_m",
                self.edge_tolerance_m,
                Real::non_negative(),
            )
            .size("sample_size", self.sample_size, 2, 100)
            .size("iterations", self.iterations, 1, 100_000)
            .size("min_inliers", self.min_inliers, 1, 10_000)
            .rule(
                "min_inliers",
                self.min_inliers,
                self.min_inliers >= self.sample_size,
                "must be ≥ sample_size",
            )
            .real(
                "min_cross_agreement",
                self.min_cross_agreement,
                Real::fraction(),
            )
            .size("kmeans_restarts", self.kmeans_restarts, 1, 10_000);
    }
}

/// Why [`verify_zones`] refused its input.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ZoneError {
    /// A match names a submap that has no position.
    #[error("match {match_index}: {segment} submap {submap} is out of range ({len} positions)")]
    SubmapOutOfRange {
        match_index: usize,
        segment: &'static str,
        submap: usize,
        len: usize,
    },
    /// A position used by a match, or a match's distance, is NaN or infinite.
    #[error("match {match_index}: non-finite {what}")]
    NonFinite {
        match_index: usize,
        what: &'static str,
    },
    /// A parameter is outside its range.
    #[error(transparent)]
    InvalidParams(#[from] mapmerge_params::ParamError),
    /// k-means refused the zone features (cannot happen after the checks above).
    #[error("zone clustering failed: {0}")]
    KMeans(#[from] KMeansError),
}

/// What became of one zone.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ZoneOutcome {
    /// The zone's consensus set is part of the output.
    Accepted,
    /// RANSAC found fewer than `min_inliers` mutually consistent matches.
    TooFewInliers,
    /// The zone is consistent on its own but places the segments differently from the larger
    /// zone `better_zone`: aliasing.
    Aliased { better_zone: usize },
}

/// One zone: its candidates, its consensus set and the verdict.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ZoneInfo {
    /// Indices into the input matches, ascending.
    pub candidates: Vec<usize>,
    /// Indices into the input matches of the pruned consensus set, ascending (empty when
    /// RANSAC found nothing).
    pub inliers: Vec<usize>,
    pub outcome: ZoneOutcome,
}

/// Result of [`verify_zones`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ZoneVerification {
    /// The accepted matches, in input order.
    pub inliers: Vec<SubmapMatch>,
    /// Their indices into the input matches, ascending.
    pub inlier_indices: Vec<usize>,
    /// Every zone, ordered by its smallest clustering feature (query index or distance).
    pub zones: Vec<ZoneInfo>,
}

/// Eq. 7 with an additive slack: edges of lengths `edge_a_m` (in A) and `edge_b_m` (in B)
/// agree when `|edge_a_m − edge_b_m| ≤ max((1 − β)·max(edge_a_m, edge_b_m), tolerance_m)`,
/// i.e. `‖e_A‖ ≥ β‖e_B‖ ∧ ‖e_B‖ ≥ β‖e_A‖` for long edges.
pub fn edge_lengths_consistent(edge_a_m: f64, edge_b_m: f64, beta: f64, tolerance_m: f64) -> bool {
    let longer = edge_a_m.max(edge_b_m);
    (edge_a_m - edge_b_m).abs() <= ((1.0 - beta) * longer).max(tolerance_m)
}

/// Zones + RANSAC + cross-check over candidate matches between segments A and B.
///
/// `positions_a[q]` is submap `q` of A in A's odometry frame (m), `positions_b[r]` submap `r` of
/// B in B's frame; every `SubmapMatch` pairs `query` in A with `reference` in B.
pub fn verify_zones(
    matches: &[SubmapMatch],
    positions_a: &[[f64; 3]],
    positions_b: &[[f64; 3]],
    params: &ZoneParams,
) -> Result<ZoneVerification, ZoneError> {
    validate(params)?;
    let mut ends = Vec::with_capacity(matches.len());
    for (match_index, m) in matches.iter().enumerate() {
        let a = position(positions_a, m.query, match_index, "query (A)")?;
        let b = position(positions_b, m.reference, match_index, "reference (B)")?;
        if !m.distance.is_finite() {
            return Err(ZoneError::NonFinite {
                match_index,
                what: "descriptor distance",
            });
        }
        ends.push(MatchEnds {
            a,
            b,
            distance: f64::from(m.distance),
        });
    }
    if matches.is_empty() {
        return Ok(ZoneVerification::default());
    }

    // 1. Zones: k-means on a 1-D feature of every match.
    let features: Vec<f64> = matches
        .iter()
        .map(|m| match params.clustering {
            ZoneClustering::QueryIndex => m.query as f64,
            ZoneClustering::FeatureDistance => f64::from(m.distance),
        })
        .collect();
    let zone_count = params.zones.min(matches.len() / params.min_inliers).max(1);
    let clustering = kmeans(
        &features,
        1,
        zone_count,
        &KMeansParams {
            restarts: params.kmeans_restarts,
            max_iterations: 100,
            seed: params.seed,
        },
    )?;
    let mut zone_members = clustering.members();
    zone_members.sort_by(|x, y| {
        let key = |members: &[usize]| {
            members
                .iter()
                .map(|&i| features[i])
                .fold(f64::INFINITY, f64::min)
        };
        key(x).total_cmp(&key(y)).then(x.first().cmp(&y.first()))
    });

    // 2. RANSAC per zone, each zone on its own ChaCha8 stream.
    let consensus: Vec<Vec<usize>> = zone_members
        .par_iter()
        .enumerate()
        .map(|(zone, members)| {
            let mut rng = ChaCha8Rng::seed_from_u64(params.seed);
            rng.set_stream(zone as u64);
            ransac_zone(members, &ends, params, &mut rng)
        })
        .collect();

    // 3. Cross-check: largest zones first (ties: lower mean distance, then zone order).
    let mut order: Vec<usize> = (0..zone_members.len())
        .filter(|&zone| consensus[zone].len() >= params.min_inliers)
        .collect();
    let mean_distance = |zone: usize| {
        consensus[zone]
            .iter()
            .map(|&i| ends[i].distance)
            .sum::<f64>()
            / consensus[zone].len() as f64
    };
    order.sort_by(|&x, &y| {
        consensus[y]
            .len()
            .cmp(&consensus[x].len())
            .then(mean_distance(x).total_cmp(&mean_distance(y)))
            .then(x.cmp(&y))
    });
    let mut outcomes = vec![ZoneOutcome::TooFewInliers; zone_members.len()];
    let mut accepted: Vec<usize> = Vec::new();
    for &zone in &order {
        let mut worst: Option<(f64, usize)> = None;
        for &other in &accepted {
            let agreement = cross_agreement(&consensus[zone], &consensus[other], &ends, params);
            if agreement < params.min_cross_agreement
                && worst.is_none_or(|(lowest, _)| agreement < lowest)
            {
                worst = Some((agreement, other));
            }
        }
        outcomes[zone] = match worst {
            Some((_, better_zone)) => ZoneOutcome::Aliased { better_zone },
            None => {
                accepted.push(zone);
                ZoneOutcome::Accepted
            }
        };
    }

    let mut inlier_indices: Vec<usize> = accepted
        .iter()
        .flat_map(|&zone| consensus[zone].iter().copied())
        .collect();
    inlier_indices.sort_unstable();
    let zones = zone_members
        .into_iter()
        .zip(consensus)
        .zip(outcomes)
        .map(|((candidates, inliers), outcome)| ZoneInfo {
            candidates,
            inliers,
            outcome,
        })
        .collect();
    Ok(ZoneVerification {
        inliers: inlier_indices.iter().map(|&i| matches[i]).collect(),
        inlier_indices,
        zones,
    })
}

/// Both ends of a match in their segments' frames, and its descriptor distance.
#[derive(Clone, Copy)]
struct MatchEnds {
    a: [f64; 3],
    b: [f64; 3],
    distance: f64,
}

fn validate(params: &ZoneParams) -> Result<(), ZoneError> {
    Ok(Validate::validate(params)?)
}

fn position(
    positions: &[[f64; 3]],
    submap: usize,
    match_index: usize,
    segment: &'static str,
) -> Result<[f64; 3], ZoneError> {
    let p = *positions.get(submap).ok_or(ZoneError::SubmapOutOfRange {
        match_index,
        segment,
        submap,
        len: positions.len(),
    })?;
    if p.iter().all(|c| c.is_finite()) {
        Ok(p)
    } else {
        Err(ZoneError::NonFinite {
            match_index,
            what: "submap position",
        })
    }
}

fn distance_m(p: &[f64; 3], q: &[f64; 3]) -> f64 {
    let (dx, dy, dz) = (p[0] - q[0], p[1] - q[1], p[2] - q[2]);
    (dx * dx + dy * dy + dz * dz).sqrt()
}

/// Eq. 7 between two matches: the edge between their A ends against the edge between their B
/// ends.
fn agree(x: &MatchEnds, y: &MatchEnds, params: &ZoneParams) -> bool {
    edge_lengths_consistent(
        distance_m(&x.a, &y.a),
        distance_m(&x.b, &y.b),
        params.beta,
        params.edge_tolerance_m,
    )
}

/// Number of ways to choose `s` of `m`, saturating at `usize::MAX`.
fn binomial(m: usize, s: usize) -> usize {
    if s > m {
        return 0;
    }
    let s = s.min(m - s);
    let mut ways = 1usize;
    for i in 0..s {
        // C(m, i + 1) = C(m, i) · (m − i) / (i + 1), exact in integers.
        match ways.checked_mul(m - i) {
            Some(product) => ways = product / (i + 1),
            None => return usize::MAX,
        }
    }
    ways
}

/// Advances `sample` (strictly increasing indices below `m`) to the next combination; false
/// after the last.
fn next_combination(sample: &mut [usize], m: usize) -> bool {
    let s = sample.len();
    for position in (0..s).rev() {
        if sample[position] < m - s + position {
            sample[position] += 1;
            for later in position + 1..s {
                sample[later] = sample[later - 1] + 1;
            }
            return true;
        }
    }
    false
}

/// RANSAC over one zone (indices into `ends`); returns the pruned consensus set, ascending, or
/// nothing when it has fewer than `min_inliers` matches.
fn ransac_zone(
    members: &[usize],
    ends: &[MatchEnds],
    params: &ZoneParams,
    rng: &mut ChaCha8Rng,
) -> Vec<usize> {
    let m = members.len();
    if m < params.min_inliers {
        return Vec::new();
    }
    let zone: Vec<MatchEnds> = members.iter().map(|&i| ends[i]).collect();
    let s = params.sample_size;
    let exhaustive = binomial(m, s) <= params.iterations.max(1);
    let mut sample: Vec<usize> = (0..s).collect();
    let mut best_sample: Vec<usize> = Vec::with_capacity(s);
    let mut best_count = 0usize;
    let mut best_distance = f64::INFINITY;
    let mut draws = 0usize;
    loop {
        if exhaustive {
            if draws > 0 && !next_combination(&mut sample, m) {
                break;
            }
        } else {
            if draws >= params.iterations {
                break;
            }
            // s distinct indices (s ≤ min_inliers ≤ m, so this ends).
            let mut filled = 0;
            while filled < s {
                let candidate = rng.random_range(0..m);
                if !sample[..filled].contains(&candidate) {
                    sample[filled] = candidate;
                    filled += 1;
                }
            }
        }
        draws += 1;
        // Eq. 7 between every pair of sample members.
        let consistent =
            (0..s).all(|i| (i + 1..s).all(|j| agree(&zone[sample[i]], &zone[sample[j]], params)));
        if !consistent {
            continue;
        }
        let mut count = 0usize;
        let mut distance = 0.0;
        for candidate in &zone {
            if sample.iter().all(|&i| agree(&zone[i], candidate, params)) {
                count += 1;
                distance += candidate.distance;
            }
        }
        if count > best_count || (count == best_count && distance < best_distance) {
            best_count = count;
            best_distance = distance;
            best_sample.clear();
            best_sample.extend_from_slice(&sample);
        }
        if best_count == m {
            break;
        }
    }
    if best_count < params.min_inliers {
        return Vec::new();
    }
    let mut consensus: Vec<usize> = (0..m)
        .filter(|&j| {
            best_sample
                .iter()
                .all(|&i| agree(&zone[i], &zone[j], params))
        })
        .collect();
    prune_to_pairwise_consistent(&mut consensus, &zone, params);
    if consensus.len() < params.min_inliers {
        return Vec::new();
    }
    let mut inliers: Vec<usize> = consensus.iter().map(|&j| members[j]).collect();
    inliers.sort_unstable();
    inliers
}

/// Drops the match with most disagreements (ties: larger distance, then later) until every
/// pair in `set` passes Eq. 7.
fn prune_to_pairwise_consistent(set: &mut Vec<usize>, zone: &[MatchEnds], params: &ZoneParams) {
    let n = set.len();
    let mut disagreements = vec![0usize; n];
    for i in 0..n {
        for j in i + 1..n {
            if !agree(&zone[set[i]], &zone[set[j]], params) {
                disagreements[i] += 1;
                disagreements[j] += 1;
            }
        }
    }
    let mut alive = vec![true; n];
    loop {
        let mut worst: Option<usize> = None;
        for i in (0..n).filter(|&i| alive[i] && disagreements[i] > 0) {
            let worse = worst.is_none_or(|w| {
                (disagreements[i], zone[set[i]].distance)
                    > (disagreements[w], zone[set[w]].distance)
                    || (disagreements[i] == disagreements[w]
                        && zone[set[i]].distance == zone[set[w]].distance)
            });
            if worse {
                worst = Some(i);
            }
        }
        let Some(w) = worst else { break };
        alive[w] = false;
        for j in (0..n).filter(|&j| alive[j]) {
            if !agree(&zone[set[w]], &zone[set[j]], params) {
                disagreements[j] -= 1;
            }
        }
    }
    let mut index = 0;
    set.retain(|_| {
        index += 1;
        alive[index - 1]
    });
}

/// Fraction of the pairs (one match of each zone) that pass Eq. 7.
fn cross_agreement(
    zone: &[usize],
    other: &[usize],
    ends: &[MatchEnds],
    params: &ZoneParams,
) -> f64 {
    let total = zone.len() * other.len();
    if total == 0 {
        return 1.0;
    }
    let agreeing: usize = zone
        .iter()
        .map(|&i| {
            other
                .iter()
                .filter(|&&j| agree(&ends[i], &ends[j], params))
                .count()
        })
        .sum();
    agreeing as f64 / total as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eq7_with_slack() {
        // Long edges: relative (β = 0.9 allows 10 % of the longer).
        assert!(edge_lengths_consistent(100.0, 91.0, 0.9, 2.0));
        assert!(!edge_lengths_consistent(100.0, 89.0, 0.9, 2.0));
        assert!(!edge_lengths_consistent(89.0, 100.0, 0.9, 2.0));
        // Short edges: the additive slack.
        assert!(edge_lengths_consistent(0.5, 2.4, 0.9, 2.0));
        assert!(!edge_lengths_consistent(0.5, 2.6, 0.9, 2.0));
        assert!(edge_lengths_consistent(0.0, 0.0, 1.0, 0.0));
    }

    #[test]
    fn combinations_are_all_listed_once() {
        let mut sample = vec![0, 1, 2];
        let mut count = 1;
        while next_combination(&mut sample, 6) {
            assert!(sample.windows(2).all(|w| w[0] < w[1]) && sample[2] < 6);
            count += 1;
        }
        assert_eq!(count, 20);
        assert_eq!(binomial(6, 3), 20);
        assert_eq!(binomial(3, 3), 1);
        assert_eq!(binomial(2, 3), 0);
        assert_eq!(binomial(40, 3), 9880);
        assert_eq!(binomial(200, 100), usize::MAX);
    }
}
