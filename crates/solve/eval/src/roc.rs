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
    let finite = |scores: &[f64]| -> Vec<f64> {
        let mut kept: Vec<f64> = scores.iter().copied().filter(|s| s.is_finite()).collect();
        kept.sort_by(|a, b| b.total_cmp(a));
        kept
    };
    let (positive, negative) = (finite(positive_scores), finite(negative_scores));
    if positive.is_empty() || negative.is_empty() {
        return Vec::new();
    }
    let mut thresholds: Vec<f64> = positive.iter().chain(&negative).copied().collect();
    thresholds.sort_by(|a, b| b.total_cmp(a));
    thresholds.dedup();
    let (mut p, mut n) = (0usize, 0usize);
    let mut curve = vec![RocPoint {
        threshold: f64::INFINITY,
        false_positive_rate: 0.0,
        true_positive_rate: 0.0,
    }];
    for threshold in thresholds {
        while positive.get(p).is_some_and(|s| *s >= threshold) {
            p += 1;
        }
        while negative.get(n).is_some_and(|s| *s >= threshold) {
            n += 1;
        }
        curve.push(RocPoint {
            threshold,
            false_positive_rate: n as f64 / negative.len() as f64,
            true_positive_rate: p as f64 / positive.len() as f64,
        });
    }
    curve
}

/// Area under the ROC curve: the probability that a random positive scores above a random
/// negative, ties counting half (Mann–Whitney). `None` when either class has no finite score.
pub fn roc_auc(positive_scores: &[f64], negative_scores: &[f64]) -> Option<f64> {
    let curve = roc_curve(positive_scores, negative_scores);
    if curve.is_empty() {
        return None;
    }
    // Trapezoids between consecutive points count ties as half.
    Some(
        curve
            .windows(2)
            .map(|w| {
                (w[1].false_positive_rate - w[0].false_positive_rate)
                    * (w[1].true_positive_rate + w[0].true_positive_rate)
                    / 2.0
            })
            .sum(),
    )
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
            let mut wins = 0.0;
            for a in &p {
                for b in &n {
                    wins += if a > b { 1.0 } else if a == b { 0.5 } else { 0.0 };
                }
            }
            let expected = wins / (p.len() * n.len()) as f64;
            prop_assert!((roc_auc(&p, &n).unwrap() - expected).abs() < 1e-12);
        }
    }
}
