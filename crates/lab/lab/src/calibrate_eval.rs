//! `mapmerge eval calibrate`: the invalid-merge decision calibrated without in-sample tuning.
//!
//! Input: results files of `mapmerge eval invalid-merge` (every case scored by every
//! detector: its highest ratio after the merge and whether it was ever supported). For each
//! log in turn, everything is fitted on the *other* logs and scored on it (leave one log
//! out):
//! - each single detector's decision: a logistic regression on its ratio and its
//!   "unsupported" flag ([`LearnedModel`] with one component), so an unsupported merge is
//!   placed where such merges fell in the other logs instead of at 0; its threshold is
//!   probability 0.5 at equal priors;
//! - the learned combination: the same regression on several detectors at once, or with
//!   `--model forest` a random forest on the same features (`mapmerge_verify::RandomForest`).
//!
//! The regressions' L2 weight is chosen inside each fold, by leave-one-log-out over its
//! training logs only (nested), unless `--alpha` fixes it; the forest's settings are fixed
//! (`--trees`, `--min-leaf`, `--seed`). Reported per held-out log: each single detector's AUC (calibrated), the best of them, the
//! learned combination's AUC and its hit rates at the threshold; pooled over the held-out
//! predictions: AUC per invalid kind. Finally the model fitted on every log is written
//! (`-o`), the one the engine embeds (`mapmerge_verify::LearnedModel::calibrated`).

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::{Args, ValueEnum};
use mapmerge_eval::roc_auc;
use mapmerge_verify::{ForestParams, LearnedModel, LearnedSample, RatioTransform};
use serde::Serialize;

use crate::invalid_merge_eval::{log_name, Label, MergeResult};
use crate::{bad_input, print_json};

/// Detectors the learned model combines by default: the appearance detectors and better
/// hypothesis (entropy is left out: as one more input it made the learned combination worse
/// on the tuning logs).
const DEFAULT_FEATURES: &str = "change_detection,gridmap,histogram,sm,dm,better_hypothesis";

/// Methods that are combinations, not single detectors.
const COMBINATIONS: [&str; 2] = ["combined", "learned"];

/// `mapmerge eval calibrate`.
#[derive(Args, Debug)]
pub struct CalibrateArgs {
    /// Results of `mapmerge eval invalid-merge` (JSON lines); several files are pooled, a
    /// case being a file's case id.
    #[arg(long = "results", required = true, num_args = 1..)]
    pub results: Vec<PathBuf>,
    /// Detectors the learned model combines (comma-separated names from the results).
    #[arg(long, value_delimiter = ',', default_value = DEFAULT_FEATURES)]
    pub features: Vec<String>,
    /// L2 weight of the logistic regressions (on standardised features); default: chosen
    /// per fold from 0.01, 0.1, 1, 10, 100 by leave-one-log-out on its training logs.
    #[arg(long)]
    pub alpha: Option<f64>,
    /// The learned combination's model (single detectors are always logistic).
    #[arg(long, value_enum, default_value_t = ModelKind::Logistic)]
    pub model: ModelKind,
    /// How the ratios enter the learned logistic combination (single detectors always take
    /// them as they are: a monotone transform of one ratio ranks the cases the same).
    /// Logit by default: on the tuning logs it raised the learned AUC under both odometry
    /// settings (docs/benchmarks.md, "Invalid-merge detection"). The embedded model, the
    /// engine's default decision, is fitted on it.
    #[arg(long, value_enum, default_value_t = TransformKind::Logit)]
    pub ratio_transform: TransformKind,
    /// Trees of `--model forest`.
    #[arg(long, default_value_t = 200)]
    pub trees: usize,
    /// Fewest samples in a leaf of `--model forest`.
    #[arg(long, default_value_t = 1)]
    pub min_leaf: usize,
    /// Seed of `--model forest` (bootstrap and feature sampling).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Sets the written model's threshold to the lowest probability (rounded up to 0.01)
    /// that at most this share of the valid cases exceed, in sample (default: 0.5, equal
    /// priors): a false-alarm budget for a decision that meets fewer invalid merges than
    /// valid ones.
    #[arg(long)]
    pub false_alarm_budget: Option<f64>,
    /// A held-out log counts towards the targets with at least this many valid and this many
    /// invalid cases.
    #[arg(long, default_value_t = 10)]
    pub min_cases: usize,
    /// The written model joins its probability with better hypothesis's ratio by a noisy-or
    /// (`LearnedModel::or_better_hypothesis`), as the engine's default decision does; the
    /// tables score the fitted model alone.
    #[arg(long)]
    pub or_better_hypothesis: bool,
    /// Writes the model fitted on every log (JSON).
    #[arg(short = 'o', long)]
    pub output: Option<PathBuf>,
    /// Writes the tables (Markdown).
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// One JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

/// The learned combination's model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ModelKind {
    /// L2-regularised logistic regression (weights say what each detector is worth).
    Logistic,
    /// Random forest (per-split feature sampling, mean leaf share).
    Forest,
}

/// How ratios enter the learned logistic combination ([`RatioTransform`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum TransformKind {
    /// As they are.
    Identity,
    /// Their logit, clamped to [0.001, 0.999].
    Logit,
}

impl From<TransformKind> for RatioTransform {
    fn from(kind: TransformKind) -> Self {
        match kind {
            TransformKind::Identity => RatioTransform::Identity,
            TransformKind::Logit => RatioTransform::Logit,
        }
    }
}

/// How the learned combination is fitted: a logistic regression with its L2 weight and
/// ratio transform, or a forest.
#[derive(Clone, Debug)]
enum Fit {
    Logistic(f64, RatioTransform),
    Forest(ForestParams),
}

impl Fit {
    fn model(
        &self,
        methods: &[String],
        samples: &[LearnedSample],
        fitted_on: String,
    ) -> Option<LearnedModel> {
        match self {
            Fit::Logistic(alpha, transform) => {
                LearnedModel::fit_transformed(methods, samples, *alpha, *transform, fitted_on).ok()
            }
            Fit::Forest(params) => {
                LearnedModel::fit_forest(methods, samples, params.clone(), fitted_on).ok()
            }
        }
    }

    fn describe(&self) -> String {
        match self {
            Fit::Logistic(alpha, transform) => format!("alpha {alpha}, ratios {transform:?}"),
            Fit::Forest(p) => format!(
                "random forest of {} trees, min leaf {}, seed {}",
                p.trees, p.min_leaf, p.seed
            ),
        }
    }
}

/// One labelled case with every method's score.
#[derive(Clone, Debug)]
struct Case {
    log: String,
    kind: String,
    invalid: bool,
    /// Method → (highest ratio, never supported).
    scores: BTreeMap<String, (f64, bool)>,
}

impl Case {
    fn sample(&self, methods: &[String]) -> Option<LearnedSample> {
        let mut ratios = Vec::with_capacity(methods.len());
        let mut unsupported = Vec::with_capacity(methods.len());
        for m in methods {
            let (r, u) = self.scores.get(m)?;
            ratios.push(*r);
            unsupported.push(*u);
        }
        Some(LearnedSample {
            ratios,
            unsupported,
            invalid: self.invalid,
        })
    }
}

/// The held-out result of one decision on one log.
#[derive(Clone, Debug, Serialize)]
struct HeldOut {
    method: String,
    /// AUC of the calibrated scores.
    auc: Option<f64>,
    /// AUC of the raw highest ratios (unsupported = 0), for comparison.
    raw_auc: Option<f64>,
    /// Invalid cases above the threshold (caught) and valid ones above it (undone).
    caught: usize,
    false_alarms: usize,
}

/// One held-out log.
#[derive(Clone, Debug, Serialize)]
struct LogRow {
    log: String,
    valid: usize,
    invalid: usize,
    /// Counts towards the targets (enough cases of both labels).
    eligible: bool,
    singles: Vec<HeldOut>,
    best_single: Option<(String, f64)>,
    learned: Option<HeldOut>,
    learned_at_least_best: Option<bool>,
    /// The learned model fitted on every log (this one included) scored on this log: the
    /// in-sample figure beside the held-out one.
    learned_in_sample_auc: Option<f64>,
}

#[derive(Serialize)]
struct CalibrateReport<'a> {
    results: &'a [PathBuf],
    cases: usize,
    features: &'a [String],
    logs: &'a [LogRow],
    /// Pooled held-out AUC per invalid kind: method → kind → AUC.
    auc_by_kind: &'a BTreeMap<String, BTreeMap<String, Option<f64>>>,
    model: Option<&'a LearnedModel>,
    seconds: f64,
}

fn read_cases(paths: &[PathBuf]) -> anyhow::Result<Vec<Case>> {
    let mut cases: BTreeMap<(usize, String), Case> = BTreeMap::new();
    for (file, path) in paths.iter().enumerate() {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        for (line, content) in text.lines().enumerate() {
            if content.trim().is_empty() {
                continue;
            }
            let r: MergeResult = serde_json::from_str(content).map_err(|e| {
                bad_input(format!(
                    "{}:{}: not a result: {e}",
                    path.display(),
                    line + 1
                ))
            })?;
            let Some(label) = r.label else {
                continue;
            };
            let unsupported = r.unsupported();
            let case = cases.entry((file, r.id.clone())).or_insert_with(|| Case {
                log: log_name(&r.log),
                kind: r.kind.clone(),
                invalid: label == Label::Invalid,
                scores: BTreeMap::new(),
            });
            case.scores
                .insert(r.method.clone(), (r.max_invalidity, unsupported));
        }
    }
    Ok(cases.into_values().collect())
}

/// The L2 weights tried when `--alpha` is not given.
const ALPHAS: [f64; 5] = [0.01, 0.1, 1.0, 10.0, 100.0];

/// The L2 weight for `methods` on `train`: `fixed`, else the one of [`ALPHAS`] with the best
/// mean AUC leaving one of `train`'s logs out at a time (logs with both labels).
fn choose_alpha(
    methods: &[String],
    train: &[&Case],
    fixed: Option<f64>,
    transform: RatioTransform,
) -> f64 {
    if let Some(alpha) = fixed {
        return alpha;
    }
    let logs: BTreeSet<&String> = train.iter().map(|c| &c.log).collect();
    let mut best = (f64::NEG_INFINITY, 1.0);
    for alpha in ALPHAS {
        let (mut sum, mut folds) = (0.0, 0usize);
        for log in &logs {
            let (test, inner): (Vec<&Case>, Vec<&Case>) =
                train.iter().copied().partition(|c| &&c.log == log);
            let Some((_, scores)) =
                fit_and_score(methods, &inner, &test, &Fit::Logistic(alpha, transform))
            else {
                continue;
            };
            let (invalid, valid) = by_label(&test, scores.iter().map(|s| Some(*s)));
            if let Some(auc) = roc_auc(&invalid, &valid) {
                sum += auc;
                folds += 1;
            }
        }
        let mean = if folds > 0 { sum / folds as f64 } else { 0.0 };
        if mean > best.0 {
            best = (mean, alpha);
        }
    }
    best.1
}

/// Fits `methods` on `train` and scores `test` (`None` when the fit fails, e.g. one class).
fn fit_and_score(
    methods: &[String],
    train: &[&Case],
    test: &[&Case],
    fit: &Fit,
) -> Option<(LearnedModel, Vec<f64>)> {
    let samples: Vec<LearnedSample> = train.iter().filter_map(|c| c.sample(methods)).collect();
    let model = fit.model(methods, &samples, "leave-one-log-out fold".to_owned())?;
    let scores = test
        .iter()
        .map(|c| {
            c.sample(methods)
                .map_or(f64::NAN, |s| model.probability(&s.ratios, &s.unsupported))
        })
        .collect();
    Some((model, scores))
}

/// `values` (one per case of `cases`, finite ones kept) split into those of invalid and of
/// valid cases.
fn by_label(cases: &[&Case], values: impl Iterator<Item = Option<f64>>) -> (Vec<f64>, Vec<f64>) {
    let (mut invalid, mut valid) = (Vec::new(), Vec::new());
    for (c, v) in cases.iter().zip(values) {
        if let Some(v) = v.filter(|v| v.is_finite()) {
            if c.invalid {
                invalid.push(v);
            } else {
                valid.push(v);
            }
        }
    }
    (invalid, valid)
}

fn held_out(method: &str, test: &[&Case], scores: &[f64], threshold: f64) -> HeldOut {
    let (invalid, valid) = by_label(test, scores.iter().map(|s| Some(*s)));
    let raw = test.iter().map(|c| c.scores.get(method).map(|s| s.0));
    let (raw_invalid, raw_valid) = by_label(test, raw);
    HeldOut {
        method: method.to_owned(),
        auc: roc_auc(&invalid, &valid),
        raw_auc: roc_auc(&raw_invalid, &raw_valid),
        caught: invalid.iter().filter(|&&s| s > threshold).count(),
        false_alarms: valid.iter().filter(|&&s| s > threshold).count(),
    }
}

/// Runs `mapmerge eval calibrate`.
pub fn calibrate(args: &CalibrateArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    if let Some(budget) = args.false_alarm_budget {
        if !(0.0..1.0).contains(&budget) {
            return Err(bad_input(format!(
                "--false-alarm-budget {budget} is not a share in [0, 1)"
            )));
        }
    }
    if args.model == ModelKind::Forest && (args.trees == 0 || args.min_leaf == 0) {
        return Err(bad_input(format!(
            "--trees {} and --min-leaf {} must both be at least 1",
            args.trees, args.min_leaf
        )));
    }
    let cases = read_cases(&args.results)?;
    if cases.is_empty() {
        return Err(bad_input("no labelled cases in the results".to_owned()));
    }
    let present: BTreeSet<String> = cases
        .iter()
        .flat_map(|c| c.scores.keys().cloned())
        .collect();
    let features: Vec<String> = args.features.iter().map(|f| f.trim().to_owned()).collect();
    for f in &features {
        if !present.contains(f) || COMBINATIONS.contains(&f.as_str()) {
            return Err(bad_input(format!(
                "feature `{f}` is not a single detector in the results (have: {})",
                present.iter().cloned().collect::<Vec<_>>().join(", ")
            )));
        }
    }
    let singles: Vec<String> = present
        .iter()
        .filter(|m| !COMBINATIONS.contains(&m.as_str()))
        .cloned()
        .collect();
    let logs: BTreeSet<String> = cases.iter().map(|c| c.log.clone()).collect();
    // The learned combination's fit on `train`.
    let learned_fit = |train: &[&Case]| match args.model {
        ModelKind::Logistic => {
            let transform = RatioTransform::from(args.ratio_transform);
            Fit::Logistic(
                choose_alpha(&features, train, args.alpha, transform),
                transform,
            )
        }
        ModelKind::Forest => Fit::Forest(ForestParams {
            trees: args.trees,
            min_leaf: args.min_leaf,
            seed: args.seed,
            ..ForestParams::default()
        }),
    };
    let mut rows = Vec::new();
    // Held-out scores per method, pooled over the logs, with each case's kind and label.
    let mut pooled: BTreeMap<String, Vec<(String, bool, f64)>> = BTreeMap::new();
    for log in &logs {
        let (test, train): (Vec<&Case>, Vec<&Case>) = cases.iter().partition(|c| &c.log == log);
        let valid = test.iter().filter(|c| !c.invalid).count();
        let invalid = test.len() - valid;
        let mut record = |method: &str, scores: &[f64]| {
            let entry = pooled.entry(method.to_owned()).or_default();
            for (c, s) in test.iter().zip(scores) {
                entry.push((c.kind.clone(), c.invalid, *s));
            }
        };
        let mut single_rows = Vec::new();
        for m in &singles {
            let methods = std::slice::from_ref(m);
            let identity = RatioTransform::Identity;
            let fit = Fit::Logistic(
                choose_alpha(methods, &train, args.alpha, identity),
                identity,
            );
            if let Some((model, scores)) = fit_and_score(methods, &train, &test, &fit) {
                record(m, &scores);
                single_rows.push(held_out(m, &test, &scores, model.threshold));
            }
        }
        let learned =
            fit_and_score(&features, &train, &test, &learned_fit(&train)).map(|(model, scores)| {
                record("learned", &scores);
                held_out("learned", &test, &scores, model.threshold)
            });
        let best_single = single_rows
            .iter()
            .filter_map(|h| Some((h.method.clone(), h.auc?)))
            .max_by(|a, b| a.1.total_cmp(&b.1));
        let learned_at_least_best = match (&learned, &best_single) {
            (Some(l), Some((_, best))) => l.auc.map(|a| a >= *best),
            _ => None,
        };
        rows.push(LogRow {
            log: log.clone(),
            valid,
            invalid,
            eligible: valid >= args.min_cases && invalid >= args.min_cases,
            singles: single_rows,
            best_single,
            learned,
            learned_at_least_best,
            learned_in_sample_auc: None,
        });
    }
    let mut auc_by_kind: BTreeMap<String, BTreeMap<String, Option<f64>>> = BTreeMap::new();
    for (method, scores) in &pooled {
        let valid: Vec<f64> = scores
            .iter()
            .filter(|s| !s.1 && s.2.is_finite())
            .map(|s| s.2)
            .collect();
        let kinds: BTreeSet<&String> = scores.iter().filter(|s| s.1).map(|s| &s.0).collect();
        let row = auc_by_kind.entry(method.clone()).or_default();
        for kind in kinds {
            let of_kind: Vec<f64> = scores
                .iter()
                .filter(|s| s.1 && &s.0 == kind && s.2.is_finite())
                .map(|s| s.2)
                .collect();
            row.insert(kind.clone(), roc_auc(&of_kind, &valid));
        }
    }
    // The model on every log.
    let all: Vec<LearnedSample> = cases.iter().filter_map(|c| c.sample(&features)).collect();
    let every: Vec<&Case> = cases.iter().collect();
    let fit = learned_fit(&every);
    let names: Vec<String> = args
        .results
        .iter()
        .map(|p| p.display().to_string())
        .collect();
    // Many files (e.g. one per simulator run): the count, the first and the last.
    let files = match names.as_slice() {
        [first, .., last] if names.len() > 4 => format!("{} files: {first} … {last}", names.len()),
        _ => names.join(", "),
    };
    let provenance = format!(
        "mapmerge eval calibrate ({}) --features {} on {} cases of {} logs ({files})",
        fit.describe(),
        features.join(","),
        all.len(),
        logs.len(),
    );
    let mut model = fit.model(&features, &all, provenance);
    if let (Some(model), Some(budget)) = (model.as_mut(), args.false_alarm_budget) {
        let valid: Vec<f64> = all
            .iter()
            .filter(|s| !s.invalid)
            .map(|s| model.probability(&s.ratios, &s.unsupported))
            .collect();
        model.threshold = threshold_for_budget(valid, budget);
    }
    if let Some(model) = &model {
        for row in &mut rows {
            let of_log: Vec<&Case> = cases.iter().filter(|c| c.log == row.log).collect();
            let scores = of_log.iter().map(|c| {
                c.sample(&features)
                    .map(|s| model.probability(&s.ratios, &s.unsupported))
            });
            let (invalid, valid) = by_label(&of_log, scores);
            row.learned_in_sample_auc = roc_auc(&invalid, &valid);
        }
    }
    if let Some(path) = &args.output {
        let mut model = model
            .clone()
            .ok_or_else(|| anyhow::anyhow!("the model could not be fitted on every case"))?;
        model.or_better_hypothesis = args.or_better_hypothesis;
        let text = serde_json::to_string_pretty(&model)?;
        std::fs::write(path, text + "\n").with_context(|| format!("writing {}", path.display()))?;
    }
    let markdown = calibrate_markdown(&rows, &auc_by_kind, model.as_ref(), &fit);
    if let Some(report) = &args.report {
        std::fs::write(report, &markdown)
            .with_context(|| format!("writing {}", report.display()))?;
    }
    if args.json {
        print_json(&CalibrateReport {
            results: &args.results,
            cases: cases.len(),
            features: &features,
            logs: &rows,
            auc_by_kind: &auc_by_kind,
            model: model.as_ref(),
            seconds: started.elapsed().as_secs_f64(),
        })
    } else {
        print!("{markdown}");
        Ok(())
    }
}

/// The lowest threshold, rounded up to 0.01, that at most `budget` of the `valid` scores
/// exceed (0.5 without valid scores).
fn threshold_for_budget(mut valid: Vec<f64>, budget: f64) -> f64 {
    valid.retain(|v| v.is_finite());
    valid.sort_by(f64::total_cmp);
    let allowed = (budget * valid.len() as f64).floor() as usize;
    match valid
        .len()
        .checked_sub(allowed + 1)
        .and_then(|k| valid.get(k).copied())
    {
        Some(score) => ((score * 100.0).ceil() / 100.0).min(1.0),
        None => 0.5,
    }
}

fn calibrate_markdown(
    rows: &[LogRow],
    auc_by_kind: &BTreeMap<String, BTreeMap<String, Option<f64>>>,
    model: Option<&LearnedModel>,
    fit: &Fit,
) -> String {
    let f3 = |v: Option<f64>| v.map_or("–".to_owned(), |v| format!("{v:.3}"));
    let mut md = String::new();
    let singles: Vec<String> = rows
        .iter()
        .flat_map(|r| r.singles.iter().map(|h| h.method.clone()))
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    let _ = writeln!(
        md,
        "Leave one log out: every decision fitted on the other logs, scored on this one \
         (calibrated AUC; raw ratio AUC in brackets where it differs)."
    );
    let _ = writeln!(md);
    let _ = writeln!(
        md,
        "| log | valid / invalid | {} | best single | learned | learned ≥ best | learned caught / false alarms at p > 0.5 | learned in sample |",
        singles.join(" | ")
    );
    let _ = writeln!(md, "|{}", "---|".repeat(singles.len() + 7));
    for row in rows {
        let cells: Vec<String> = singles
            .iter()
            .map(|m| {
                row.singles
                    .iter()
                    .find(|h| &h.method == m)
                    .map_or("–".to_owned(), |h| {
                        // The raw AUC where it differs in the shown digits.
                        let differs = h.raw_auc.is_some() && f3(h.raw_auc) != f3(h.auc);
                        let raw = if differs {
                            format!(" ({})", f3(h.raw_auc))
                        } else {
                            String::new()
                        };
                        format!("{}{raw}", f3(h.auc))
                    })
            })
            .collect();
        let best = row
            .best_single
            .as_ref()
            .map_or("–".to_owned(), |(m, a)| format!("{a:.3} ({m})"));
        let learned = row.learned.as_ref();
        let _ = writeln!(
            md,
            "| {}{} | {} / {} | {} | {best} | {} | {} | {} | {} |",
            row.log,
            if row.eligible { "" } else { " (too few cases)" },
            row.valid,
            row.invalid,
            cells.join(" | "),
            f3(learned.and_then(|l| l.auc)),
            row.learned_at_least_best
                .map_or("–", |b| if b { "yes" } else { "no" }),
            learned.map_or("–".to_owned(), |l| format!(
                "{} / {} of {} / {}",
                l.caught, l.false_alarms, row.invalid, row.valid
            )),
            f3(row.learned_in_sample_auc),
        );
    }
    let kinds: BTreeSet<&String> = auc_by_kind.values().flat_map(|k| k.keys()).collect();
    let _ = writeln!(md);
    let _ = writeln!(
        md,
        "Held-out scores pooled over the logs, AUC of the valid cases against each kind:"
    );
    let _ = writeln!(md);
    let _ = writeln!(
        md,
        "| method | {} |",
        kinds
            .iter()
            .map(|k| k.as_str())
            .collect::<Vec<_>>()
            .join(" | ")
    );
    let _ = writeln!(md, "|---|{}", "---|".repeat(kinds.len()));
    for (method, by_kind) in auc_by_kind {
        let cells: Vec<String> = kinds
            .iter()
            .map(|k| f3(by_kind.get(*k).copied().flatten()))
            .collect();
        let _ = writeln!(md, "| {method} | {} |", cells.join(" | "));
    }
    if let Some(model) = model.filter(|m| m.forest.is_some()) {
        let _ = writeln!(md);
        let _ = writeln!(
            md,
            "Model on every log ({}): threshold {}",
            fit.describe(),
            model.threshold
        );
    } else if let Some(model) = model {
        let _ = writeln!(md);
        let _ = writeln!(
            md,
            "Model on every log ({}): intercept {:.3}, threshold {}; {}",
            fit.describe(),
            model.intercept,
            model.threshold,
            model
                .methods
                .iter()
                .zip(&model.ratio_weights)
                .zip(&model.unsupported_weights)
                .map(|((m, w), u)| format!("{m} ratio {w:.3} / unsupported {u:.3}"))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    md
}

#[cfg(test)]
mod tests {
    use super::threshold_for_budget;

    #[test]
    fn the_budget_threshold_lets_at_most_that_share_of_valid_scores_above_it() {
        let valid: Vec<f64> = (0..100).map(|k| f64::from(k) / 100.0 + 0.001).collect();
        for budget in [0.0, 0.033, 0.1, 0.5] {
            let t = threshold_for_budget(valid.clone(), budget);
            let above = valid.iter().filter(|&&v| v > t).count();
            assert!(
                above as f64 <= budget * 100.0,
                "{budget}: {t} lets {above} above"
            );
            // …and is the lowest such threshold at 0.01 steps.
            let lower = t - 0.01;
            let above_lower = valid.iter().filter(|&&v| v > lower).count();
            assert!(above_lower as f64 > budget * 100.0, "{budget}: {lower}");
        }
        assert_eq!(threshold_for_budget(vec![f64::NAN], 0.1), 0.5);
        assert_eq!(threshold_for_budget(Vec::new(), 0.1), 0.5);
    }
}
