//! ROC curves and their area for detectors that output a score, higher meaning "positive"
//! (e.g. "this merge is wrong").

use serde::Serialize;

/// One operating point: flag every case whose score is at least `threshold`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RocPoint {
    /// The threshold.
    pub threshold: f64,
    /// Share of negatives flagged.
    pub false_positive_rate: f64,
    /// Share of positives flagged.
    pub true_positive_rate: f64,
}

/// The ROC curve: one point per distinct
/// finite score, highest threshold first, starting at `(0, 0)` (threshold +∞). Non-finite
/// scores are ignored. Empty when either class is empty.
pub fn roc_curve(positive_scores: &[f64], negative_scores: &[f64]) -> Vec<RocPoint> {
    let Some(RocCounts {
        steps,
        positives,
        negatives,
    }) = roc_counts(positive_scores, negative_scores)
    else {
        return Vec::new();
    };
    let rate = |count: usize, of: usize| count as f64 / of as f64;
    std::iter::once(RocPoint {
        threshold: f64::INFINITY,
        false_positive_rate: 0.0,
        true_positive_rate: 0.0,
    })
    .chain(steps.iter().map(|&(threshold, p, n)| RocPoint {
        threshold,
        false_positive_rate: rate(n, negatives),
        true_positive_rate: rate(p, positives),
    }))
    .collect()
}

/// The ROC curve in counts.
struct RocCounts {
    /// Per distinct finite score, highest first: (threshold, positives ≥ it, negatives ≥ it).
    steps: Vec<(f64, usize, usize)>,
    /// Finite positive scores.
    positives: usize,
    /// Finite negative scores.
    negatives: usize,
}

/// The curve in counts; `None` when either class has no finite score.
fn roc_counts(positive_scores: &[f64], negative_scores: &[f64]) -> Option<RocCounts> {
    let finite = |scores: &[f64]| -> Vec<f64> {
        let mut kept: Vec<f64> = scores.iter().copied().filter(|s| s.is_finite()).collect();
        kept.sort_by(|a, b| b.total_cmp(a));
        kept
    };
    let (positive, negative) = (finite(positive_scores), finite(negative_scores));
    if positive.is_empty() || negative.is_empty() {
        return None;
    }
    let mut thresholds: Vec<f64> = positive.iter().chain(&negative).copied().collect();
    thresholds.sort_by(|a, b| b.total_cmp(a));
    thresholds.dedup();
    let (mut p, mut n) = (0usize, 0usize);
    let mut steps = Vec::with_capacity(thresholds.len());
    for threshold in thresholds {
        while positive.get(p).is_some_and(|s| *s >= threshold) {
            p += 1;
        }
        while negative.get(n).is_some_and(|s| *s >= threshold) {
            n += 1;
        }
        steps.push((threshold, p, n));
    }
    Some(RocCounts {
        steps,
        positives: positive.len(),
        negatives: negative.len(),
    })
}

/// Area under the ROC curve: the probability that a random positive scores above a random
/// negative, ties counting half (Mann–Whitney). `None` when either class has no finite score.
/// Counted in whole pairs and divided once, so two rankings that win the same pairs get the
/// same value to the last bit (a ≥ comparison of AUCs is then a comparison of pair counts).
pub fn roc_auc(positive_scores: &[f64], negative_scores: &[f64]) -> Option<f64> {
    let RocCounts {
        steps,
        positives,
        negatives,
    } = roc_counts(positive_scores, negative_scores)?;
    // Twice the area in pairs: trapezoids between consecutive steps count ties as half.
    let mut twice_pairs: u128 = 0;
    let (mut p_before, mut n_before) = (0usize, 0usize);
    for &(_, p, n) in &steps {
        twice_pairs += (n - n_before) as u128 * (p + p_before) as u128;
        (p_before, n_before) = (p, n);
    }
    Some(twice_pairs as f64 / (2 * positives as u128 * negatives as u128) as f64)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use proptest::prelude::*;

    use super::*;

    #[test]
    fn separated_scores_give_one_and_reversed_give_zero() {
        assert_eq!(roc_auc(&[3.0, 4.0], &[1.0, 2.0]), Some(1.0));
        assert_eq!(roc_auc(&[1.0, 2.0], &[3.0, 4.0]), Some(0.0));
        assert_eq!(roc_auc(&[1.0], &[1.0]), Some(0.5));
        assert_eq!(roc_auc(&[], &[1.0]), None);
        assert_eq!(roc_auc(&[f64::NAN], &[1.0]), None);
        let curve = roc_curve(&[3.0, 1.0], &[2.0]);
        assert_eq!(curve.len(), 4);
        assert_eq!(curve[3].true_positive_rate, 1.0);
        assert_eq!(curve[3].false_positive_rate, 1.0);
    }

    proptest! {
        #[test]
        fn auc_is_the_mann_whitney_statistic(
            positive in prop::collection::vec(0u8..20, 1..30),
            negative in prop::collection::vec(0u8..20, 1..30),
        ) {
            let p: Vec<f64> = positive.iter().map(|&v| f64::from(v)).collect();
            let n: Vec<f64> = negative.iter().map(|&v| f64::from(v)).collect();
            // Twice the pairs won (a tie is half a win), divided once: exact, to the bit.
            let mut twice_wins = 0usize;
            for a in &p {
                for b in &n {
                    twice_wins += if a > b { 2 } else if a == b { 1 } else { 0 };
                }
            }
            let expected = twice_wins as f64 / (2 * p.len() * n.len()) as f64;
            prop_assert_eq!(roc_auc(&p, &n).unwrap(), expected);
        }
    }
}
