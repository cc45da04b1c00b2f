//! A random forest of classification trees (Breiman 2001) for the learned decision: each
//! tree is grown on a bootstrap sample of the labelled merges, each split chosen by weighted
//! Gini impurity among a fresh random subset of the features (√d by default), and the
//! forest's probability is the mean of its leaves' invalid shares. Classes are weighted to
//! equal totals, so that 0.5 means "as likely invalid as valid" however many invalid cases
//! the training set had (as the logistic model's intercept correction does).
//!
//! Why our own and not smartcore's or linfa's: smartcore 0.4's forest has no probabilities
//! (majority vote only) and its trees' per-split feature sampling is crate-private; linfa's
//! ensemble samples features per tree, not per split, and votes by majority. A ranking (AUC)
//! needs a score, and on the tuning logs bagging without per-split sampling ranked merges
//! worse.
//!
//! A tree is stored flat: node `k` is a split on `feature[k]` at `value[k]` with children
//! `child[k]` (≤) and `child[k] + 1` (>), or a leaf (`feature[k] < 0`) whose invalid share is
//! `value[k]`. Children always follow their parent, so evaluation ends in at most as many
//! steps as there are nodes, whatever a model file says.

use mapmerge_params::{Checker, Real, Validate};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// How a [`RandomForest`] is grown.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForestParams {
    /// Trees.
    pub trees: usize,
    /// Fewest (bootstrap) samples in a leaf.
    pub min_leaf: usize,
    /// Deepest split level (the root is level 0).
    pub max_depth: usize,
    /// Features tried per split (0: ⌊√d⌋, at least 1).
    pub features_per_split: usize,
    /// Seed of the bootstrap and feature sampling (tree `t` uses `seed + t`).
    pub seed: u64,
}

impl Default for ForestParams {
    fn default() -> Self {
        Self {
            trees: 200,
            min_leaf: 1,
            max_depth: 24,
            features_per_split: 0,
            seed: 0,
        }
    }
}

impl Validate for ForestParams {
    fn check(&self, check: &mut Checker) {
        check
            .size("trees", self.trees, 1, MAX_TREES)
            .size("min_leaf", self.min_leaf, 1, 1_000_000)
            .size("max_depth", self.max_depth, 0, 64)
            .size("features_per_split", self.features_per_split, 0, 4_096);
    }
}

/// Most trees a forest grows or holds.
const MAX_TREES: u64 = 10_000;

/// One tree, stored flat (see the module documentation).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Tree {
    /// Split feature per node; negative for a leaf.
    pub feature: Vec<i16>,
    /// Split threshold (go left when `x ≤ value`) or, at a leaf, its invalid share.
    pub value: Vec<f64>,
    /// Index of the left child (the right one follows it); 0 at a leaf.
    pub child: Vec<u32>,
}

impl Tree {
    /// The leaf share for the features `x(k)`; 0.5 for a malformed tree.
    fn share(&self, x: &impl Fn(usize) -> f64) -> f64 {
        let mut k = 0usize;
        // Children follow parents: at most `len` steps.
        for _ in 0..self.feature.len() {
            let (Some(&feature), Some(&value), Some(&child)) =
                (self.feature.get(k), self.value.get(k), self.child.get(k))
            else {
                break;
            };
            if feature < 0 {
                return if value.is_finite() {
                    value.clamp(0.0, 1.0)
                } else {
                    0.5
                };
            }
            let next = (child as usize).saturating_add(usize::from(x(feature as usize) > value));
            if next <= k {
                break;
            }
            k = next;
        }
        0.5
    }
}

/// A fitted forest over `width` features.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RandomForest {
    /// How it was grown.
    pub params: ForestParams,
    /// Its trees.
    pub trees: Vec<Tree>,
}

impl Validate for Tree {
    /// As many split features, values and children; finite values.
    fn check(&self, check: &mut Checker) {
        let nodes = self.feature.len();
        check
            .rule(
                "value",
                self.value.len(),
                self.value.len() == nodes,
                "must have one entry per node",
            )
            .rule(
                "child",
                self.child.len(),
                self.child.len() == nodes,
                "must have one entry per node",
            );
        if let Some((k, v)) = self.value.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            check.real(&format!("value[{k}]"), *v, Real::finite());
        }
    }
}

impl Validate for RandomForest {
    fn check(&self, check: &mut Checker) {
        check
            .nested("params", &self.params)
            .size("trees", self.trees.len(), 0, MAX_TREES);
        for (t, tree) in self.trees.iter().enumerate() {
            check.nested(&format!("trees[{t}]"), tree);
        }
    }
}

/// One training row: features and label (true = invalid).
struct Row<'a> {
    x: &'a [f64],
    invalid: bool,
}

impl RandomForest {
    /// Mean leaf share over the trees for the features `x(k)` (non-finite features read as
    /// 0); 0.5 without trees.
    pub fn probability(&self, x: impl Fn(usize) -> f64) -> f64 {
        if self.trees.is_empty() {
            return 0.5;
        }
        let read = |k: usize| {
            let v = x(k);
            if v.is_finite() {
                v
            } else {
                0.0
            }
        };
        let sum: f64 = self.trees.iter().map(|t| t.share(&read)).sum();
        sum / self.trees.len() as f64
    }

    /// Grows a forest on `rows` (each of the same width) labelled `invalid`. Both classes must
    /// be present (the caller checks).
    /// Rows of unequal width are used up to the shortest; labels beyond the rows are ignored.
    pub fn fit(rows: &[Vec<f64>], invalid: &[bool], params: ForestParams) -> Self {
        let width = rows.iter().map(Vec::len).min().unwrap_or(0);
        let data: Vec<Row<'_>> = rows
            .iter()
            .zip(invalid)
            .map(|(x, &invalid)| Row { x, invalid })
            .collect();
        if data.is_empty() {
            return Self {
                params,
                trees: Vec::new(),
            };
        }
        let invalid_count = data.iter().filter(|r| r.invalid).count();
        let n_invalid = invalid_count.max(1);
        let n_valid = (data.len() - invalid_count).max(1);
        // Equal class totals.
        let weights = [0.5 / n_valid as f64, 0.5 / n_invalid as f64];
        let per_split = if params.features_per_split == 0 {
            ((width as f64).sqrt().floor() as usize).max(1)
        } else {
            params.features_per_split
        }
        .min(width.max(1));
        let trees = (0..params.trees)
            .map(|t| {
                let mut rng = ChaCha8Rng::seed_from_u64(params.seed.wrapping_add(t as u64));
                let mut sample: Vec<usize> = (0..data.len())
                    .map(|_| rng.random_range(0..data.len()))
                    .collect();
                let mut grower = Grower {
                    data: &data,
                    weights,
                    width,
                    per_split,
                    params: &params,
                    rng,
                    tree: Tree::default(),
                    pairs: Vec::with_capacity(data.len()),
                    order: Vec::with_capacity(width),
                };
                grower.push_leaf();
                grower.grow(0, &mut sample, 0);
                grower.tree
            })
            .collect();
        Self { params, trees }
    }
}

/// Grows one tree.
struct Grower<'a> {
    data: &'a [Row<'a>],
    /// Class weights [valid, invalid].
    weights: [f64; 2],
    width: usize,
    per_split: usize,
    params: &'a ForestParams,
    rng: ChaCha8Rng,
    tree: Tree,
    /// Scratch: (feature value, row) pairs of a node.
    pairs: Vec<(f64, usize)>,
    /// Scratch: the order in which a node tries the features.
    order: Vec<usize>,
}

/// The best split found at a node.
struct Split {
    feature: usize,
    threshold: f64,
    /// Weighted Gini impurity of the children (lower is better).
    impurity: f64,
}

impl Grower<'_> {
    fn push_leaf(&mut self) -> usize {
        self.tree.feature.push(-1);
        self.tree.value.push(0.5);
        self.tree.child.push(0);
        self.tree.feature.len() - 1
    }

    /// Weighted (valid, invalid) totals of `rows`.
    fn totals(&self, rows: &[usize]) -> [f64; 2] {
        let mut w = [0.0; 2];
        for &r in rows {
            let class = usize::from(self.data[r].invalid);
            w[class] += self.weights[class];
        }
        w
    }

    /// Makes node `node` (already pushed as a leaf) a leaf or a split of `rows`.
    fn grow(&mut self, node: usize, rows: &mut [usize], depth: usize) {
        let w = self.totals(rows);
        let total = w[0] + w[1];
        self.tree.value[node] = if total > 0.0 { w[1] / total } else { 0.5 };
        let pure = w[0] == 0.0 || w[1] == 0.0;
        if pure || depth >= self.params.max_depth || rows.len() < 2 * self.params.min_leaf.max(1) {
            return;
        }
        let Some(split) = self.best_split(rows, w) else {
            return;
        };
        // Partition: left = x ≤ threshold.
        let mut left = 0;
        for k in 0..rows.len() {
            if self.data[rows[k]].x[split.feature] <= split.threshold {
                rows.swap(left, k);
                left += 1;
            }
        }
        let child = self.push_leaf();
        self.push_leaf();
        self.tree.feature[node] = split.feature as i16;
        self.tree.value[node] = split.threshold;
        self.tree.child[node] = child as u32;
        let (l, r) = rows.split_at_mut(left);
        self.grow(child, l, depth + 1);
        self.grow(child + 1, r, depth + 1);
    }

    /// The lowest-impurity split among `per_split` non-constant features drawn at random
    /// (more are drawn while those drawn are constant here, as Breiman's and scikit-learn's
    /// forests do); `None` when no allowed split lowers the impurity.
    fn best_split(&mut self, rows: &[usize], w: [f64; 2]) -> Option<Split> {
        // The same order as a fresh 0..width shuffled: the scratch only saves the allocation.
        let mut features = std::mem::take(&mut self.order);
        features.clear();
        features.extend(0..self.width);
        features.shuffle(&mut self.rng);
        let gini = |a: f64, b: f64| {
            let t = a + b;
            if t > 0.0 {
                t * (1.0 - (a / t).powi(2) - (b / t).powi(2))
            } else {
                0.0
            }
        };
        let parent = gini(w[0], w[1]);
        let min_leaf = self.params.min_leaf.max(1);
        let mut best: Option<Split> = None;
        let mut tried = 0;
        for &feature in &features {
            if tried >= self.per_split {
                break;
            }
            self.pairs.clear();
            self.pairs
                .extend(rows.iter().map(|&r| (self.data[r].x[feature], r)));
            self.pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
            let (Some(first), Some(last)) = (self.pairs.first(), self.pairs.last()) else {
                continue;
            };
            if first.0 >= last.0 {
                continue;
            }
            tried += 1;
            let mut left = [0.0; 2];
            for k in 0..self.pairs.len() - 1 {
                let (value, r) = self.pairs[k];
                let class = usize::from(self.data[r].invalid);
                left[class] += self.weights[class];
                let next = self.pairs[k + 1].0;
                if next <= value || k + 1 < min_leaf || self.pairs.len() - (k + 1) < min_leaf {
                    continue;
                }
                let impurity = gini(left[0], left[1]) + gini(w[0] - left[0], w[1] - left[1]);
                if impurity < best.as_ref().map_or(parent - 1e-12, |b| b.impurity) {
                    best = Some(Split {
                        feature,
                        threshold: value + 0.5 * (next - value),
                        impurity,
                    });
                }
            }
        }
        self.order = features;
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Invalid when x0 + x1 > 1 (a diagonal no single axis split separates), x2 noise.
    fn diagonal(n: usize) -> (Vec<Vec<f64>>, Vec<bool>) {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let rows: Vec<Vec<f64>> = (0..n)
            .map(|_| (0..3).map(|_| rng.random::<f64>()).collect())
            .collect();
        let labels = rows.iter().map(|x| x[0] + x[1] > 1.0).collect();
        (rows, labels)
    }

    fn auc(scores: &[f64], labels: &[bool]) -> f64 {
        let (mut hits, mut pairs) = (0.0, 0.0);
        for (s, l) in scores.iter().zip(labels) {
            for (t, m) in scores.iter().zip(labels) {
                if *l && !*m {
                    pairs += 1.0;
                    hits += if s > t {
                        1.0
                    } else if s == t {
                        0.5
                    } else {
                        0.0
                    };
                }
            }
        }
        hits / pairs
    }

    #[test]
    fn a_forest_ranks_unseen_points_of_a_diagonal_boundary() {
        let (rows, labels) = diagonal(400);
        let forest = RandomForest::fit(&rows, &labels, ForestParams::default());
        let (test, truth) = {
            let mut rng = ChaCha8Rng::seed_from_u64(99);
            let rows: Vec<Vec<f64>> = (0..300)
                .map(|_| (0..3).map(|_| rng.random::<f64>()).collect())
                .collect();
            let labels: Vec<bool> = rows.iter().map(|x| x[0] + x[1] > 1.0).collect();
            (rows, labels)
        };
        let scores: Vec<f64> = test.iter().map(|x| forest.probability(|k| x[k])).collect();
        assert!(auc(&scores, &truth) > 0.97, "{}", auc(&scores, &truth));
        // Far from the boundary it is sure.
        assert!(forest.probability(|k| [0.95, 0.95, 0.5][k]) > 0.8);
        assert!(forest.probability(|k| [0.05, 0.05, 0.5][k]) < 0.2);
    }

    #[test]
    fn equal_class_weights_put_one_half_between_unbalanced_classes() {
        // One feature; invalid (x > 0.5) four times as often; a noisy band in the middle.
        let mut rows = Vec::new();
        let mut labels = Vec::new();
        for k in 0..500 {
            let x = k as f64 / 500.0;
            let invalid = if (0.4..0.6).contains(&x) {
                k % 2 == 0
            } else {
                x > 0.5
            };
            rows.push(vec![x]);
            labels.push(invalid);
            if invalid {
                for _ in 0..3 {
                    rows.push(vec![x]);
                    labels.push(true);
                }
            }
        }
        let params = ForestParams {
            min_leaf: 20,
            ..ForestParams::default()
        };
        let forest = RandomForest::fit(&rows, &labels, params);
        assert!(forest.probability(|_| 0.2) < 0.5);
        assert!(forest.probability(|_| 0.8) > 0.5);
    }

    #[test]
    fn fitting_is_deterministic_and_survives_a_json_round_trip() {
        let (rows, labels) = diagonal(150);
        let params = ForestParams {
            trees: 20,
            seed: 3,
            ..ForestParams::default()
        };
        let a = RandomForest::fit(&rows, &labels, params.clone());
        let b = RandomForest::fit(&rows, &labels, params);
        assert_eq!(a, b);
        let text = serde_json::to_string(&a).unwrap();
        let back: RandomForest = serde_json::from_str(&text).unwrap();
        for x in &rows {
            assert_eq!(a.probability(|k| x[k]), back.probability(|k| x[k]));
        }
    }

    #[test]
    fn malformed_trees_and_inputs_give_probabilities_not_panics() {
        let cyclic = Tree {
            feature: vec![0, 0, -1],
            value: vec![0.5, 0.5, 0.9],
            child: vec![0, 0, 0],
        };
        let out_of_range = Tree {
            feature: vec![5, -1],
            value: vec![f64::NAN, f64::INFINITY],
            child: vec![u32::MAX, 0],
        };
        let forest = RandomForest {
            params: ForestParams::default(),
            trees: vec![cyclic, out_of_range, Tree::default()],
        };
        for x in [f64::NAN, f64::NEG_INFINITY, 0.0, 1e300] {
            let p = forest.probability(|_| x);
            assert!((0.0..=1.0).contains(&p), "{p}");
        }
        assert_eq!(RandomForest::default().probability(|_| 1.0), 0.5);
        // Ragged or empty training sets grow what they can, without panicking.
        let ragged = RandomForest::fit(
            &[vec![0.1, 0.2], vec![0.9], vec![0.8, 0.1]],
            &[false, true, true],
            ForestParams::default(),
        );
        assert!(ragged.probability(|_| 0.9) > 0.5);
        let empty = RandomForest::fit(&[], &[], ForestParams::default());
        assert_eq!(empty.probability(|_| 0.0), 0.5);
    }
}
