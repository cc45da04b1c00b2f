//! `mapmerge eval grid-merge`: Andersone's experiment (Sec. 4.2–4.3, Tables 1–4) on a
//! corrected laser log, plus ROC/AUC of every metric for telling wrong merges from correct ones.
//!
//! For each resolution combination (own–other: 0.07–0.07, 0.07–0.10, 0.10–0.07 by default):
//! 1. Partial maps of `--scans` consecutive scans from random starts, built with the log's
//!    corrected poses (Binary Bayes scan updates). The own map A is in the log's frame; the
//!    other robot's map B is built in a random frame (uniform heading, ±20 m), so nothing
//!    about the relative pose is given away. Pairs come from different passes (starts at
//!    least `--min-gap-scans` apart) whose first poses lie within `--pair-radius` metres.
//! 2. A *correct* merge: `match_grids` (no initial guess) accepts a transform within 0.2 m
//!    and 2° of the truth. A *wrong* merge: a transform at least 1 m or 10° from the truth
//!    that still passes the paper's acceptance, SM ≥ 0.9 — one of the matcher's own
//!    runner-up hypotheses when one qualifies, else the best of random perturbations of the
//!    truth. (The paper's wrong merges were its matcher's failures; ours fails too rarely to
//!    collect 20, so plausible ones are made, as Holoch et al. do for their invalid merges.)
//! 3. B is fused into A (`mapmerge_gridmerge::fuse`, quality-weighted), and mapping goes on
//!    with the next `--further-scans` scans in 1M and 2M (`ReversibleMapper`). SM and DM are
//!    measured right after the merge and after those scans: in 2M between the own map and
//!    B, in 1M between the merged map and B (Sec. 4.2). One more 1M measure, ours: between
//!    B and the merged map with every cell the robot did not update itself reset to
//!    unknown (the map the 1M undo would leave, Sec. 3.2) — it sees what the robot saw, as
//!    2M does, without keeping a second map.
//! 4. Update times are the mean wall time per further scan of all maps the mode keeps.
//!
//! DM is in cells of the coarser resolution (as the paper's tables).

use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use mapmerge_eval::roc_auc;
use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_grid::{ClassThresholds, InsertParams, OccupancyGrid};
use mapmerge_gridmatch::{map_metrics, match_grids, GridMatchParams, MapMetrics};
use mapmerge_gridmerge::{
    KeepMerge, MetricsCheck, ReversibleMapper, ReversibleMode, ReversibleParams,
};
use mapmerge_scan::LaserScan;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::{bad_input, print_json};

/// Arguments of `mapmerge eval grid-merge`.
#[derive(Args, Debug)]
pub struct GridMergeEvalArgs {
    /// Corrected CARMEN logs (`.xz` accepted); each scan's pose is taken as the truth.
    #[arg(required = true)]
    pub logs: Vec<PathBuf>,
    /// Correct and wrong merges per resolution combination (each).
    #[arg(long, default_value_t = 20)]
    pub merges: usize,
    /// Scans per partial map.
    #[arg(long, default_value_t = 30)]
    pub scans: usize,
    /// Scans mapped after the merge.
    #[arg(long, default_value_t = 10)]
    pub further_scans: usize,
    /// The two resolutions (m): combinations r1–r1, r1–r2, r2–r1.
    #[arg(long, num_args = 2, default_values_t = [0.07, 0.10])]
    pub resolutions: Vec<f64>,
    /// The two partial maps start at least this many scans apart (different passes; a
    /// quarter of the log at most).
    #[arg(long, default_value_t = 200)]
    pub min_gap_scans: usize,
    /// … and their first poses within this distance (m).
    #[arg(long, default_value_t = 2.0)]
    pub pair_radius: f64,
    /// … and their true overlap at least this fraction of the smaller map's known cells.
    #[arg(long, default_value_t = 0.3)]
    pub min_overlap: f64,
    /// Pairs tried per combination before giving up on reaching `--merges`.
    #[arg(long, default_value_t = 400)]
    pub max_pairs: usize,
    /// Seed of the pair sampling and of B's frames (ChaCha8).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Write the Markdown tables here (default: only printed without `--json`).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Print one JSON object instead of the tables.
    #[arg(long)]
    pub json: bool,
}

/// A correct merge is within this of the truth (m, rad).
const CORRECT_WITHIN: (f64, f64) = (0.2, 0.035);
/// A wrong merge is at least this far from the truth (m, or rad).
const WRONG_BEYOND: (f64, f64) = (1.0, 0.175);
/// The paper's acceptance: SM ≥ 0.9 (Sec. 4.2).
const ACCEPT_SM: f64 = 0.9;
/// Random perturbations of the truth tried for a wrong merge.
const WRONG_TRIALS: usize = 200;

/// The metrics one merge case records.
#[derive(Clone, Copy, Debug, Serialize)]
struct CaseMetrics {
    initial: MapMetrics,
    end: MapMetrics,
    /// Mean map update time per further scan (ms).
    update_ms: f64,
    /// Whether the periodic check (`MetricsCheck`, default thresholds) undid the merge after
    /// the further scans.
    undone: bool,
}

/// One merge, followed in both modes.
#[derive(Clone, Debug, Serialize)]
struct Case {
    wrong: bool,
    own_start: usize,
    other_start: usize,
    /// The merge transform (B's frame in A's) and the truth.
    a_from_b: [f64; 3],
    truth_a_from_b: [f64; 3],
    /// How the wrong transform was found (`runner_up` or `perturbed`); `matcher` for correct.
    source: &'static str,
    single_map: CaseMetrics,
    multi_map: CaseMetrics,
    /// 1M, ours: the merged map restricted to the robot's own updates, against B.
    single_map_local: CaseMetrics,
}

/// Means (and ranges) of one column of the paper's tables.
#[derive(Clone, Copy, Debug, Default, Serialize)]
struct Column {
    cases: usize,
    initial_sm: f64,
    end_sm: f64,
    initial_dm: f64,
    end_dm: f64,
    update_ms: f64,
    end_sm_range: [f64; 2],
    end_dm_range: [f64; 2],
    /// Merges the check undid.
    undone: usize,
}

/// AUC of telling wrong merges from correct ones by one end metric (wrong = positive; low SM
/// or high DM flags).
#[derive(Clone, Copy, Debug, Serialize)]
struct Separation {
    measure: &'static str,
    auc: Option<f64>,
}

/// One resolution combination of one log.
#[derive(Clone, Debug, Serialize)]
struct Combination {
    own_resolution_m: f64,
    other_resolution_m: f64,
    pairs_tried: usize,
    /// Pairs with enough true overlap (the ones matched).
    pairs_used: usize,
    /// Pairs whose matcher result was accepted, and of those within the truth's tolerance.
    matcher_accepted: usize,
    matcher_correct: usize,
    /// Accepted transforms outside the tolerance: their error (m, deg) and overlap, as a
    /// fraction of the smaller map's known cells.
    matcher_wrong: Vec<[f64; 3]>,
    correct_1m: Column,
    correct_2m: Column,
    wrong_1m: Column,
    wrong_2m: Column,
    correct_1m_local: Column,
    wrong_1m_local: Column,
    separation: Vec<Separation>,
    cases: Vec<Case>,
}

#[derive(Serialize)]
struct LogReport {
    log: PathBuf,
    scans: usize,
    combinations: Vec<Combination>,
}

#[derive(Serialize)]
struct Report {
    seed: u64,
    merges: usize,
    scans: usize,
    further_scans: usize,
    logs: Vec<LogReport>,
    seconds: f64,
}

/// Runs `mapmerge eval grid-merge`.
pub fn run(args: &GridMergeEvalArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    let [r1, r2] = <[f64; 2]>::try_from(args.resolutions.as_slice())
        .map_err(|_| bad_input("--resolutions takes two values"))?;
    for r in [r1, r2] {
        crate::check_resolution(r)?;
    }
    if args.scans == 0 || args.merges == 0 {
        return Err(bad_input("--scans and --merges must be positive"));
    }
    let mut logs = Vec::new();
    for path in &args.logs {
        let posed = crate::load_posed_log(path, None, &crate::BagTopics::default())?;
        let mut combinations = Vec::new();
        for (k, (own_m, other_m)) in [(r1, r1), (r1, r2), (r2, r1)].into_iter().enumerate() {
            if !args.json {
                eprintln!(
                    "{}: {own_m}–{other_m} m …",
                    path.file_name().unwrap_or_default().to_string_lossy()
                );
            }
            let seed = args.seed ^ ((k as u64 + 1) << 32);
            combinations.push(run_combination(&posed, own_m, other_m, seed, args)?);
        }
        logs.push(LogReport {
            log: path.clone(),
            scans: posed.poses.len(),
            combinations,
        });
    }
    let report = Report {
        seed: args.seed,
        merges: args.merges,
        scans: args.scans,
        further_scans: args.further_scans,
        logs,
        seconds: started.elapsed().as_secs_f64(),
    };
    let markdown = tables(&report);
    if let Some(out) = &args.output {
        if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        std::fs::write(out, &markdown).with_context(|| format!("writing {}", out.display()))?;
    }
    if args.json {
        print_json(&report)
    } else {
        print!("{markdown}");
        Ok(())
    }
}

/// A partial map from scans `start..start + count` placed by `frame_from_log · pose`.
fn partial_map(
    posed: &crate::PosedLog,
    start: usize,
    count: usize,
    resolution_m: f64,
    frame_from_log: &Se2,
) -> anyhow::Result<OccupancyGrid> {
    let scans = posed
        .poses
        .iter()
        .zip(&posed.log.scans)
        .skip(start)
        .take(count)
        .map(|(pose, record)| (frame_from_log.compose(pose), &record.scan));
    let (grid, _) = OccupancyGrid::from_scans(resolution_m, scans, &InsertParams::default())?;
    Ok(grid)
}

fn far_from(a: &Se2, b: &Se2, (m, rad): (f64, f64)) -> bool {
    let d = a.between(b);
    d.translation().norm() >= m || wrap_angle_rad(d.theta_rad).abs() >= rad
}

fn near(a: &Se2, b: &Se2, (m, rad): (f64, f64)) -> bool {
    let d = a.between(b);
    d.translation().norm() <= m && wrap_angle_rad(d.theta_rad).abs() <= rad
}

fn run_combination(
    posed: &crate::PosedLog,
    own_m: f64,
    other_m: f64,
    seed: u64,
    args: &GridMergeEvalArgs,
) -> anyhow::Result<Combination> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = posed.poses.len();
    let span = args.scans + args.further_scans;
    let thresholds = ClassThresholds::default();
    let params = GridMatchParams::default();
    let mut combination = Combination {
        own_resolution_m: own_m,
        other_resolution_m: other_m,
        pairs_tried: 0,
        pairs_used: 0,
        matcher_accepted: 0,
        matcher_correct: 0,
        matcher_wrong: Vec::new(),
        correct_1m: Column::default(),
        correct_2m: Column::default(),
        wrong_1m: Column::default(),
        wrong_2m: Column::default(),
        correct_1m_local: Column::default(),
        wrong_1m_local: Column::default(),
        separation: Vec::new(),
        cases: Vec::new(),
    };
    // Short logs (a few hundred scans) get a proportionally shorter gap between the passes.
    let min_gap = args.min_gap_scans.min(n / 4);
    if n < span + min_gap + args.scans {
        return Err(bad_input(format!(
            "the log has {n} scans, too few for partial maps of {} + {} scans {min_gap} apart",
            args.scans, args.further_scans
        )));
    }
    let (mut correct, mut wrong) = (0usize, 0usize);
    while (correct < args.merges || wrong < args.merges) && combination.pairs_tried < args.max_pairs
    {
        combination.pairs_tried += 1;
        let own_start = rng.random_range(0..n - span);
        let anchor = posed.poses[own_start].translation();
        let partners: Vec<usize> = (0..n - args.scans)
            .filter(|&k| k.abs_diff(own_start) >= min_gap)
            .filter(|&k| (posed.poses[k].translation() - anchor).norm() <= args.pair_radius)
            .collect();
        if partners.is_empty() {
            continue;
        }
        let other_start = partners[rng.random_range(0..partners.len())];
        let b_from_log = Se2::new(
            rng.random_range(-20.0..20.0),
            rng.random_range(-20.0..20.0),
            rng.random_range(-std::f64::consts::PI..std::f64::consts::PI),
        );
        let truth = b_from_log.inverse();
        let own = partial_map(posed, own_start, args.scans, own_m, &Se2::identity())?;
        let other = partial_map(posed, other_start, args.scans, other_m, &b_from_log)?;
        // Only pairs that show one place: the true overlap is at least `--min-overlap` of the
        // smaller map's known cells.
        let known = |g: &OccupancyGrid| g.log_odds().iter().filter(|l| **l != 0.0).count();
        let smaller = known(&own).min(known(&other)).max(1);
        let Ok(true_metrics) = map_metrics(&own, &other, &truth, &thresholds) else {
            continue;
        };
        if (true_metrics.overlap_cells as f64) < args.min_overlap * smaller as f64 {
            continue;
        }
        combination.pairs_used += 1;
        let Ok(matched) = match_grids(&own, &other, &params) else {
            continue;
        };
        let accepted = matched.best().copied();
        if accepted.is_some() {
            combination.matcher_accepted += 1;
        }
        if let Some(best) = accepted.filter(|h| !near(&h.a_from_b, &truth, CORRECT_WITHIN)) {
            let error = truth.between(&best.a_from_b);
            combination.matcher_wrong.push([
                error.translation().norm(),
                wrap_angle_rad(error.theta_rad).to_degrees(),
                best.metrics.overlap_cells as f64 / smaller as f64,
            ]);
        }
        let mut merges: Vec<(bool, Se2, &'static str)> = Vec::new();
        if let Some(best) = accepted.filter(|h| near(&h.a_from_b, &truth, CORRECT_WITHIN)) {
            combination.matcher_correct += 1;
            if correct < args.merges {
                merges.push((false, best.a_from_b, "matcher"));
            }
        }
        if wrong < args.merges {
            if let Some((transform, source)) = wrong_transform(
                &own,
                &other,
                &truth,
                &matched.hypotheses,
                &thresholds,
                &mut rng,
            ) {
                merges.push((true, transform, source));
            }
        }
        for (is_wrong, a_from_b, source) in merges {
            let follow = |mode| {
                follow_merge(
                    posed,
                    &own,
                    &other,
                    &a_from_b,
                    own_start,
                    mode,
                    args,
                    &thresholds,
                )
            };
            let (single_map, single_map_local) = follow(ReversibleMode::SingleMap)?;
            let (multi_map, _) = follow(ReversibleMode::MultiMap)?;
            let pose = |p: &Se2| [p.x_m, p.y_m, p.theta_rad];
            combination.cases.push(Case {
                wrong: is_wrong,
                own_start,
                other_start,
                a_from_b: pose(&a_from_b),
                truth_a_from_b: pose(&truth),
                source,
                single_map,
                multi_map,
                single_map_local,
            });
            if is_wrong {
                wrong += 1;
            } else {
                correct += 1;
            }
        }
    }
    summarise(&mut combination);
    Ok(combination)
}

/// A transform far from the truth that passes SM ≥ 0.9: the matcher's best such runner-up,
/// else the best-scoring random perturbation of the truth.
fn wrong_transform(
    own: &OccupancyGrid,
    other: &OccupancyGrid,
    truth: &Se2,
    hypotheses: &[mapmerge_gridmatch::MatchHypothesis],
    thresholds: &ClassThresholds,
    rng: &mut ChaCha8Rng,
) -> Option<(Se2, &'static str)> {
    // A wrong merge must overlap about as much as the right one, or there is nothing to see.
    let min_overlap =
        map_metrics(own, other, truth, thresholds).map_or(usize::MAX, |m| m.overlap_cells / 2);
    if let Some(h) = hypotheses.iter().find(|h| {
        h.acceptance >= ACCEPT_SM
            && h.metrics.overlap_cells >= min_overlap
            && far_from(&h.a_from_b, truth, WRONG_BEYOND)
    }) {
        return Some((h.a_from_b, "runner_up"));
    }
    let (low, high) = other.geometry().bounds_m();
    let centre = truth.transform_point(&((low + high) / 2.0));
    let mut best: Option<(f64, Se2)> = None;
    for _ in 0..WRONG_TRIALS {
        // Look-alike errors: a shift along the structure, a turn by a multiple of 90°, or both.
        let turn = f64::from(rng.random_range(-2i32..=2)) * std::f64::consts::FRAC_PI_2
            + rng.random_range(-0.05..0.05);
        // Turned about B's centre (in A's frame), so that the maps still overlap.
        let about = Se2::new(centre.x, centre.y, 0.0);
        let shift = Se2::new(
            rng.random_range(-3.0..3.0),
            rng.random_range(-3.0..3.0),
            0.0,
        );
        let candidate = shift
            .compose(&about)
            .compose(&Se2::new(0.0, 0.0, turn))
            .compose(&about.inverse())
            .compose(truth);
        if !far_from(&candidate, truth, WRONG_BEYOND) {
            continue;
        }
        let Ok(m) = map_metrics(own, other, &candidate, thresholds) else {
            continue;
        };
        if m.sm >= ACCEPT_SM && m.overlap_cells >= min_overlap {
            let score = m.agree_occupied_cells as f64;
            if best.is_none_or(|(s, _)| score > s) {
                best = Some((score, candidate));
            }
        }
    }
    best.map(|(_, t)| (t, "perturbed"))
}

/// Merges `other` into `own` by `a_from_b`, maps the next scans in `mode`, and measures SM/DM
/// right after the merge and at the end; in 1M also the local-update measure (second value).
#[allow(clippy::too_many_arguments)]
fn follow_merge(
    posed: &crate::PosedLog,
    own: &OccupancyGrid,
    other: &OccupancyGrid,
    a_from_b: &Se2,
    own_start: usize,
    mode: ReversibleMode,
    args: &GridMergeEvalArgs,
    thresholds: &ClassThresholds,
) -> anyhow::Result<(CaseMetrics, CaseMetrics)> {
    let params = ReversibleParams {
        mode,
        check_every_scans: 0,
        ..ReversibleParams::default()
    };
    let mut mapper = ReversibleMapper::new(own.clone(), params)?;
    mapper.merge(other, a_from_b, "experiment")?;
    let check = MetricsCheck::default();
    let identity = Se2::identity();
    // Ours (2M: own vs B; 1M: the restricted merged map vs B) is the check's own measure; the
    // paper's 1M compares the whole merged map with B. B as fused, in A's frame.
    let measure = |mapper: &ReversibleMapper| -> anyhow::Result<(MapMetrics, MapMetrics)> {
        let input = mapper.check_input().context("the merge is gone")?;
        let ours = check
            .measure(&input)
            .context("the check could not compare the maps")?;
        let paper = match mode {
            ReversibleMode::MultiMap => ours,
            ReversibleMode::SingleMap => {
                map_metrics(input.merged, input.b_in_a, &identity, thresholds)?
            }
        };
        Ok((paper, ours))
    };
    let (initial, initial_local) = measure(&mapper)?;
    let mut update_seconds = 0.0;
    let further = posed
        .poses
        .iter()
        .zip(&posed.log.scans)
        .skip(own_start + args.scans)
        .take(args.further_scans);
    let mut count = 0usize;
    for (pose, record) in further {
        let scan: &LaserScan = &record.scan;
        let update = mapper.insert_scan(pose, scan, &KeepMerge)?;
        update_seconds += update.timing.update_seconds;
        count += 1;
    }
    let (end, end_local) = measure(&mapper)?;
    let undone = !mapper.verify_now(&check)?.is_consistent();
    let update_ms = 1e3 * update_seconds / count.max(1) as f64;
    Ok((
        CaseMetrics {
            initial,
            end,
            update_ms,
            undone,
        },
        CaseMetrics {
            initial: initial_local,
            end: end_local,
            update_ms,
            undone,
        },
    ))
}

fn column<'a>(cases: impl Iterator<Item = &'a CaseMetrics>) -> Column {
    let cases: Vec<&CaseMetrics> = cases.collect();
    let n = cases.len();
    if n == 0 {
        return Column::default();
    }
    let mean = |f: &dyn Fn(&CaseMetrics) -> f64| cases.iter().map(|c| f(c)).sum::<f64>() / n as f64;
    let range = |f: &dyn Fn(&CaseMetrics) -> f64| {
        cases
            .iter()
            .map(|c| f(c))
            .fold([f64::INFINITY, f64::NEG_INFINITY], |[lo, hi], v| {
                [lo.min(v), hi.max(v)]
            })
    };
    Column {
        cases: n,
        initial_sm: mean(&|c| c.initial.sm),
        end_sm: mean(&|c| c.end.sm),
        initial_dm: mean(&|c| c.initial.dm_cells),
        end_dm: mean(&|c| c.end.dm_cells),
        update_ms: mean(&|c| c.update_ms),
        end_sm_range: range(&|c| c.end.sm),
        end_dm_range: range(&|c| c.end.dm_cells),
        undone: cases.iter().filter(|c| c.undone).count(),
    }
}

fn summarise(combination: &mut Combination) {
    let of = |wrong: bool, pick: fn(&Case) -> &CaseMetrics| -> Vec<CaseMetrics> {
        combination
            .cases
            .iter()
            .filter(|c| c.wrong == wrong)
            .map(|c| *pick(c))
            .collect()
    };
    let single: fn(&Case) -> &CaseMetrics = |c| &c.single_map;
    let multi: fn(&Case) -> &CaseMetrics = |c| &c.multi_map;
    let local: fn(&Case) -> &CaseMetrics = |c| &c.single_map_local;
    combination.correct_1m = column(of(false, single).iter());
    combination.correct_2m = column(of(false, multi).iter());
    combination.wrong_1m = column(of(true, single).iter());
    combination.wrong_2m = column(of(true, multi).iter());
    combination.correct_1m_local = column(of(false, local).iter());
    combination.wrong_1m_local = column(of(true, local).iter());
    let mut separation = Vec::new();
    for (name, pick) in [("1M", single), ("2M", multi), ("1M local", local)] {
        let (wrong, correct) = (of(true, pick), of(false, pick));
        let sm = |cases: &[CaseMetrics]| cases.iter().map(|c| -c.end.sm).collect::<Vec<_>>();
        let dm = |cases: &[CaseMetrics]| cases.iter().map(|c| c.end.dm_cells).collect::<Vec<_>>();
        let label_sm: &'static str = match name {
            "1M" => "SM 1M",
            "2M" => "SM 2M",
            _ => "SM 1M local",
        };
        let label_dm: &'static str = match name {
            "1M" => "DM 1M",
            "2M" => "DM 2M",
            _ => "DM 1M local",
        };
        separation.push(Separation {
            measure: label_sm,
            auc: roc_auc(&sm(&wrong), &sm(&correct)),
        });
        separation.push(Separation {
            measure: label_dm,
            auc: roc_auc(&dm(&wrong), &dm(&correct)),
        });
    }
    combination.separation = separation;
}

/// Andersone's Tables 1–3 (averages) for 0.07–0.07, 0.07–0.1, 0.1–0.07 and Table 4 (ranges,
/// 0.07–0.07), columns Correct 1M, Correct 2M, Wrong 1M, Wrong 2M.
const PAPER_AVERAGES: [[[f64; 4]; 5]; 3] = [
    [
        [0.995, 0.979, 0.990, 0.923],
        [0.986, 0.977, 0.974, 0.910],
        [0.419, 1.251, 2.485, 14.950],
        [0.883, 1.462, 5.006, 14.570],
        [6.816, 10.516, 9.512, 12.289],
    ],
    [
        [0.992, 0.970, 0.991, 0.913],
        [0.982, 0.968, 0.970, 0.896],
        [0.329, 1.229, 2.202, 14.604],
        [0.754, 1.702, 4.532, 14.656],
        [7.384, 10.709, 9.221, 12.600],
    ],
    [
        [0.989, 0.966, 0.994, 0.909],
        [0.973, 0.956, 0.976, 0.864],
        [0.518, 1.313, 2.055, 9.979],
        [1.094, 1.678, 3.298, 10.249],
        [3.395, 5.106, 4.757, 6.321],
    ],
];

fn tables(report: &Report) -> String {
    let mut md = String::new();
    // One line per log and combination: how often matching was right, and how well each
    // end metric tells wrong merges from correct ones.
    let measures: Vec<&str> = report
        .logs
        .first()
        .and_then(|l| l.combinations.first())
        .map(|c| c.separation.iter().map(|s| s.measure).collect())
        .unwrap_or_default();
    let _ = write!(
        md,
        "| log | own–other (m) | pairs | matcher right / accepted | correct / wrong merges |"
    );
    for m in &measures {
        let _ = write!(md, " AUC {m} |");
    }
    let _ = writeln!(md, " undone: wrong 2M / 1M local, correct 2M / 1M local |");
    let _ = writeln!(md, "|{}", "---|".repeat(6 + measures.len()));
    for log in &report.logs {
        let name = log.log.file_name().unwrap_or_default().to_string_lossy();
        let name = name.trim_end_matches(".xz").trim_end_matches(".log");
        for c in &log.combinations {
            let _ = write!(
                md,
                "| {name} | {:.2}–{:.2} | {} | {} / {} | {} / {} |",
                c.own_resolution_m,
                c.other_resolution_m,
                c.pairs_used,
                c.matcher_correct,
                c.matcher_accepted,
                c.correct_2m.cases,
                c.wrong_2m.cases
            );
            for sep in &c.separation {
                let _ = write!(
                    md,
                    " {} |",
                    sep.auc.map_or("–".to_owned(), |a| format!("{a:.3}"))
                );
            }
            let _ = writeln!(
                md,
                " {}/{} · {}/{} · {}/{} · {}/{} |",
                c.wrong_2m.undone,
                c.wrong_2m.cases,
                c.wrong_1m_local.undone,
                c.wrong_1m_local.cases,
                c.correct_2m.undone,
                c.correct_2m.cases,
                c.correct_1m_local.undone,
                c.correct_1m_local.cases
            );
        }
    }
    let _ = writeln!(md);
    for log in &report.logs {
        let name = log.log.file_name().unwrap_or_default().to_string_lossy();
        let _ = writeln!(md, "### {name} ({} scans)\n", log.scans);
        for (k, c) in log.combinations.iter().enumerate() {
            let _ = writeln!(
                md,
                "**{:.2}–{:.2}** ({} pairs tried, {} overlapping enough; matcher accepted {}, {} of them right; {} correct and {} wrong merges followed). Ours (paper)\n",
                c.own_resolution_m,
                c.other_resolution_m,
                c.pairs_tried,
                c.pairs_used,
                c.matcher_accepted,
                c.matcher_correct,
                c.correct_1m.cases,
                c.wrong_1m.cases
            );
            let _ = writeln!(
                md,
                "| | Correct (1M) | Correct (2M) | Wrong (1M) | Wrong (2M) | Correct (1M local) | Wrong (1M local) |\n|---|---|---|---|---|---|---|"
            );
            let columns = [&c.correct_1m, &c.correct_2m, &c.wrong_1m, &c.wrong_2m];
            let paper = PAPER_AVERAGES.get(k).filter(|_| is_paper_setup(report, c));
            type Row = (&'static str, fn(&Column) -> f64);
            let rows: [Row; 5] = [
                ("Initial SM", |c| c.initial_sm),
                ("End SM", |c| c.end_sm),
                ("Initial DM", |c| c.initial_dm),
                ("End DM", |c| c.end_dm),
                ("Upd. time (ms)", |c| c.update_ms),
            ];
            for (r, (label, value)) in rows.iter().enumerate() {
                let _ = write!(md, "| {label} |");
                for (i, col) in columns.iter().enumerate() {
                    let theirs = paper
                        .and_then(|p| p.get(r))
                        .and_then(|row| row.get(i))
                        .map(|v| format!(" ({v:.3})"))
                        .unwrap_or_default();
                    let _ = write!(md, " {:.3}{theirs} |", value(col));
                }
                for col in [&c.correct_1m_local, &c.wrong_1m_local] {
                    let _ = write!(md, " {:.3} |", value(col));
                }
                let _ = writeln!(md);
            }
            let _ = write!(md, "| Undone by the check |");
            for col in columns
                .iter()
                .chain([&&c.correct_1m_local, &&c.wrong_1m_local])
            {
                let _ = write!(md, " {}/{} |", col.undone, col.cases);
            }
            let _ = writeln!(md);
            let _ = writeln!(md, "\nEnd ranges (Table 4):\n");
            let _ = writeln!(md, "| | Correct (1M) | Wrong (1M) | Correct (2M) | Wrong (2M) | Correct (1M local) | Wrong (1M local) |\n|---|---|---|---|---|---|---|");
            let ranged = [
                &c.correct_1m,
                &c.wrong_1m,
                &c.correct_2m,
                &c.wrong_2m,
                &c.correct_1m_local,
                &c.wrong_1m_local,
            ];
            for (label, pick) in [
                (
                    "End SM",
                    (|c: &Column| c.end_sm_range) as fn(&Column) -> [f64; 2],
                ),
                ("End DM", |c: &Column| c.end_dm_range),
            ] {
                let _ = write!(md, "| {label} |");
                for col in ranged {
                    let [lo, hi] = pick(col);
                    let _ = write!(md, " {lo:.3}–{hi:.3} |");
                }
                let _ = writeln!(md);
            }
            let _ = writeln!(md, "\nAUC, wrong vs correct after the further scans:\n");
            let _ = writeln!(md, "| measure | AUC |\n|---|---|");
            for s in &c.separation {
                let auc = s.auc.map_or("–".to_owned(), |a| format!("{a:.3}"));
                let _ = writeln!(md, "| {} | {auc} |", s.measure);
            }
            let _ = writeln!(md);
        }
    }
    md
}

/// The paper's numbers go beside ours only for its setup: 30 + 10 scans at 0.07 / 0.10 m.
fn is_paper_setup(report: &Report, c: &Combination) -> bool {
    let paper_resolution = |r: f64| (r - 0.07).abs() < 1e-9 || (r - 0.10).abs() < 1e-9;
    report.scans == 30
        && report.further_scans == 10
        && paper_resolution(c.own_resolution_m)
        && paper_resolution(c.other_resolution_m)
}
