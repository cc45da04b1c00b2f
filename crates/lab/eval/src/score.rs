//! How well a robust back-end separated false loop closures from true ones.

use std::collections::BTreeSet;

use mapmerge_posegraph::EdgeId;
use serde::{Deserialize, Serialize};

/// Outlier rejection scored against the known false edges. "Positive" means "rejected".
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RejectionScore {
    /// False edges that were rejected.
    pub true_positives: usize,
    /// Rejected edges that are not false (true loop closures, or odometry).
    pub false_positives: usize,
    /// False edges that were kept.
    pub false_negatives: usize,
    /// `tp / (tp + fp)`: share of the rejected edges that are false; 1 when nothing was
    /// rejected.
    pub precision: f64,
    /// `tp / (tp + fn)`: share of the false edges that were rejected; 1 when there were none.
    pub recall: f64,
    /// Share of the true loop closures that were kept: `1 − fp / true_loops` (clamped at 0; an
    /// odometry edge rejected counts against it too); 1 when there are no true loop closures.
    pub true_loops_kept: f64,
}

/// Scores the `rejected` edges against the known `false_edges`; `true_loops` is the number of
/// genuine loop closures in the graph (before corruption). Duplicates in either list count once.
pub fn precision_recall(
    rejected: &[EdgeId],
    false_edges: &[EdgeId],
    true_loops: usize,
) -> RejectionScore {
    let rejected: BTreeSet<EdgeId> = rejected.iter().copied().collect();
    let false_edges: BTreeSet<EdgeId> = false_edges.iter().copied().collect();
    let tp = rejected.intersection(&false_edges).count();
    let fp = rejected.len() - tp;
    let fn_ = false_edges.len() - tp;
    let ratio = |num: usize, den: usize| {
        if den == 0 {
            1.0
        } else {
            num as f64 / den as f64
        }
    };
    let true_loops_kept = if true_loops == 0 {
        1.0
    } else {
        (1.0 - fp as f64 / true_loops as f64).max(0.0)
    };
    RejectionScore {
        true_positives: tp,
        false_positives: fp,
        false_negatives: fn_,
        precision: ratio(tp, tp + fp),
        recall: ratio(tp, tp + fn_),
        true_loops_kept,
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;

    fn ids(v: &[u64]) -> Vec<EdgeId> {
        v.iter().map(|&i| EdgeId(i)).collect()
    }

    #[test]
    fn perfect_rejection() {
        let s = precision_recall(&ids(&[10, 11, 12]), &ids(&[12, 11, 10]), 20);
        assert_eq!(
            (s.true_positives, s.false_positives, s.false_negatives),
            (3, 0, 0)
        );
        assert_eq!((s.precision, s.recall, s.true_loops_kept), (1.0, 1.0, 1.0));
    }

    #[test]
    fn mixed_rejection() {
        // Rejected: two false (10, 11), two true (3, 4); missed false: 12, 13.
        let s = precision_recall(&ids(&[3, 4, 10, 11, 11]), &ids(&[10, 11, 12, 13]), 8);
        assert_eq!(
            (s.true_positives, s.false_positives, s.false_negatives),
            (2, 2, 2)
        );
        assert!((s.precision - 0.5).abs() < 1e-15);
        assert!((s.recall - 0.5).abs() < 1e-15);
        assert!((s.true_loops_kept - 0.75).abs() < 1e-15);
    }

    #[test]
    fn empty_conventions() {
        let s = precision_recall(&[], &[], 0);
        assert_eq!((s.precision, s.recall, s.true_loops_kept), (1.0, 1.0, 1.0));
        let s = precision_recall(&[], &ids(&[5]), 3);
        assert_eq!((s.precision, s.recall), (1.0, 0.0));
        let s = precision_recall(&ids(&[1, 2, 3, 4]), &[], 2);
        assert_eq!((s.precision, s.true_loops_kept), (0.0, 0.0));
    }
}
