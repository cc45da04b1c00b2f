//! `mapmerge eval lifelong`: the lifelong engine under real conditions, judged from its
//! outputs. Each corrected log is run once per seed as a kidnapped robot recorded it
//! ([`crate::carried`]: seeded noisy odometry, 1–4 carries by travel, the odometry going on as
//! if the robot had not moved); each simulated world once per seed with its own kidnaps.
//! Every run is `mapmerge atlas`'s job; its `maps/` are judged against the truth
//! ([`crate::map_judge`]). Per run: revisiting segments, those ending merged and placed,
//! misplaced ones, the stage where each lost revisit stopped, the relocalization distance of
//! each merge (iRobot Sec. 6: travel from the first true revisit to the conditional and to
//! the full merge) and the time per scan.

use std::collections::BTreeMap;
use std::path::PathBuf;

use clap::Args;
use mapmerge_engine::{EngineParams, EpochEnd};
use mapmerge_jobs::{AtlasJob, AtlasOptions, AtlasReport, AtlasSession};
use mapmerge_posegraph::NodeId;
use serde::Serialize;

use crate::break_judge::{judge_breaks, BreakJudgement, DETECT_WITHIN_SCANS};
use crate::map_judge::{judge_maps, Frames, MapsJudgement, SegmentJudgement};
use crate::print_json;
use crate::protrusion_eval::seeds;
use crate::start_judge::{judge_starts, StartJudgement, START_LOCALIZED_WITHIN_M};

/// Arguments of `mapmerge eval lifelong`.
#[derive(Args, Debug)]
pub struct LifelongEvalArgs {
    /// Corrected CARMEN logs (`.xz` accepted).
    pub logs: Vec<PathBuf>,
    /// Seeds of the logs' noise and kidnaps (`A-B` or a comma list).
    #[arg(long, default_value = "1-3")]
    pub seeds: String,
    /// Odometry noise profile for the logs: default, harsh or none.
    #[arg(long, default_value = "default")]
    pub noise: String,
    /// Simulated worlds to run as well (comma list of presets).
    #[arg(long, value_delimiter = ',')]
    pub sim: Vec<String>,
    /// Seeds of the simulated worlds (tuning 1-10, held out 101-110).
    #[arg(long, default_value = "101-110")]
    pub sim_seeds: String,
    /// Sessions per simulated run, and robot time per session (s).
    #[arg(long, default_value_t = 3)]
    pub sessions: usize,
    #[arg(long, default_value_t = 120.0)]
    pub duration: f64,
    /// Engine parameters as JSON (any subset).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Withhold the kidnaps from the engine (the honest stream): its tracking-failure
    /// detector must notice them. They are still judged.
    #[arg(long)]
    pub hide_kidnaps: bool,
    /// Carry the logs nowhere (no kidnaps; with `--hide-kidnaps`, every epoch break the
    /// engine makes is a false one).
    #[arg(long)]
    pub no_kidnaps: bool,
    /// Folder for every run's outputs (`<run>/maps/…`).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Trace every merge query (`atlas.recognition.trace`) and count, over the queries at
    /// true revisits, where they were lost: retrieval, the descriptor gate, verification or
    /// acceptance (verification runs twice for them, so the times are not comparable).
    #[arg(long)]
    pub diagnose: bool,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Merge queries at true revisits, stage by stage (`--diagnose`): a query keyframe whose true
/// pose lies within [`REVISIT_QUERY_M`] of a keyframe of an earlier epoch.
#[derive(Clone, Debug, Default, Serialize)]
pub struct QueryStages {
    pub revisit_queries: usize,
    /// A retrieved keyframe truly within [`TRUE_CANDIDATE_M`] …
    pub retrieved_true: usize,
    /// … admitted by the descriptor distance …
    pub admitted_true: usize,
    /// … verified to the true relative pose (within 0.5 m, 10°) at any score …
    pub verified_true: usize,
    /// … and at the acceptance score.
    pub verified_true_above: usize,
    /// Accepted (score and confidence): to the true pose, and wrongly.
    pub accepted_true: usize,
    pub accepted_wrong: usize,
    /// Scores of every verified candidate (every query), to the true pose and not: where the
    /// acceptance score separates them.
    pub scores_true: Vec<f64>,
    pub scores_wrong: Vec<f64>,
}

impl QueryStages {
    fn add(&mut self, other: &Self) {
        self.revisit_queries += other.revisit_queries;
        self.retrieved_true += other.retrieved_true;
        self.admitted_true += other.admitted_true;
        self.verified_true += other.verified_true;
        self.verified_true_above += other.verified_true_above;
        self.accepted_true += other.accepted_true;
        self.accepted_wrong += other.accepted_wrong;
        self.scores_true.extend(&other.scores_true);
        self.scores_wrong.extend(&other.scores_wrong);
    }
}

/// A query is at a true revisit within this of an earlier epoch's keyframe (m) …
const REVISIT_QUERY_M: f64 = 2.0;
/// … and a retrieved keyframe is the true place within this of the query (m).
const TRUE_CANDIDATE_M: f64 = 3.0;

/// Where a revisiting segment that did not end merged and placed was lost, from its last
/// epoch's outcome.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct LostAt {
    /// No verified match: retrieval or verification found nothing.
    pub no_match: usize,
    /// Matches made hypotheses that never became conditional.
    pub hypothesis: usize,
    /// A conditional merge never became full (rejected or the epoch ended).
    pub conditional: usize,
    /// Merged, then undone (the invalid-merge detector).
    pub undone: usize,
    /// Merged and kept, but not placed within 0.5 m, or merged into a map without an
    /// earlier segment.
    pub misplaced: usize,
}

impl LostAt {
    fn add(&mut self, other: &Self) {
        self.no_match += other.no_match;
        self.hypothesis += other.hypothesis;
        self.conditional += other.conditional;
        self.undone += other.undone;
        self.misplaced += other.misplaced;
    }
}

/// One run.
#[derive(Clone, Debug, Serialize)]
pub struct RunRow {
    pub run: String,
    pub scans: usize,
    pub segments: usize,
    pub revisiting: usize,
    pub merged: usize,
    pub misplaced: usize,
    pub lost: LostAt,
    /// Travel (m, true path) from each merged revisiting segment's first true revisit to its
    /// conditional merge and to its full merge.
    pub to_conditional_m: Vec<f64>,
    pub to_full_m: Vec<f64>,
    pub ms_per_scan: f64,
    /// Maps holding several segments: whole-map ATE beside the worst segment's excess (m).
    pub merged_maps: Vec<(String, Option<f64>, Option<f64>)>,
    /// With `--diagnose`.
    pub queries: Option<QueryStages>,
    /// The engine's `tracking_lost` breaks against the true kidnaps.
    pub breaks: BreakJudgement,
    /// How each later session started (simulated runs).
    pub starts: StartJudgement,
}

#[derive(Serialize)]
struct Report {
    runs: Vec<RunRow>,
    /// Over every run: kidnaps detected, false breaks and travel.
    breaks: BreakJudgement,
    false_breaks_per_500_m: Option<f64>,
    /// Over every simulated run: later sessions, those starting covered, and started
    /// localized within 2 m correctly and wrongly.
    starts: StartJudgement,
    revisiting: usize,
    merged: usize,
    misplaced: usize,
    lost: LostAt,
    to_conditional_median_m: Option<f64>,
    to_conditional_p90_m: Option<f64>,
    to_full_median_m: Option<f64>,
    to_full_p90_m: Option<f64>,
    /// Total time over total scans (ms).
    ms_per_scan: f64,
    /// With `--diagnose`, over every run.
    queries: Option<QueryStages>,
}

/// Runs `mapmerge eval lifelong`.
pub fn run(args: &LifelongEvalArgs) -> anyhow::Result<()> {
    let mut params: EngineParams = crate::read_config(args.config.as_deref())?;
    params.atlas.recognition.trace |= args.diagnose;
    let mut runs = Vec::new();
    for path in &args.logs {
        let name = crate::log_short_name(path);
        let log = crate::read_log(path, &crate::BagTopics::default())?;
        for seed in seeds(&args.seeds)? {
            let (sessions, _) = crate::carried::carried_sessions(
                vec![(name.clone(), log.clone())],
                &[],
                !args.no_kidnaps,
                &args.noise,
                seed,
            )?;
            let run = format!("{name}-s{seed}");
            runs.push(run_one(&run, &sessions, Frames::PerSession, &params, args)?);
        }
    }
    for world in &args.sim {
        for seed in seeds(&args.sim_seeds)? {
            let sessions = crate::atlas_judge::simulated_sessions(
                world,
                args.sessions,
                args.duration,
                seed,
                None,
            )?;
            let run = format!("{world}-{seed}");
            runs.push(run_one(&run, &sessions, Frames::Shared, &params, args)?);
        }
    }
    let sum = |f: fn(&RunRow) -> usize| runs.iter().map(f).sum::<usize>();
    let mut lost = LostAt::default();
    for r in &runs {
        lost.add(&r.lost);
    }
    let all = |f: fn(&RunRow) -> &Vec<f64>| -> Vec<f64> {
        runs.iter().flat_map(|r| f(r).iter().copied()).collect()
    };
    let (conditional, full) = (all(|r| &r.to_conditional_m), all(|r| &r.to_full_m));
    let scans = sum(|r| r.scans);
    let mut breaks = BreakJudgement::default();
    let mut starts = StartJudgement::default();
    for r in &runs {
        breaks.add(&r.breaks);
        starts.add(&r.starts);
    }
    let ms: f64 = runs.iter().map(|r| r.ms_per_scan * r.scans as f64).sum();
    let report = Report {
        revisiting: sum(|r| r.revisiting),
        merged: sum(|r| r.merged),
        misplaced: sum(|r| r.misplaced),
        lost,
        to_conditional_median_m: quantile(&conditional, 0.5),
        to_conditional_p90_m: quantile(&conditional, 0.9),
        to_full_median_m: quantile(&full, 0.5),
        to_full_p90_m: quantile(&full, 0.9),
        ms_per_scan: ms / scans.max(1) as f64,
        false_breaks_per_500_m: breaks.false_per_500_m(),
        breaks,
        starts,
        queries: args.diagnose.then(|| {
            let mut all = QueryStages::default();
            for q in runs.iter().filter_map(|r| r.queries.as_ref()) {
                all.add(q);
            }
            all
        }),
        runs,
    };
    if args.json {
        return print_json(&report);
    }
    println!("| run | scans | segments | revisiting | merged and placed | misplaced | lost: no match / hypothesis / conditional / undone / misplaced | to conditional m | to full m | ms/scan |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let list = |v: &[f64]| {
        v.iter()
            .map(|d| format!("{d:.1}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    for r in &report.runs {
        let l = &r.lost;
        println!(
            "| {} | {} | {} | {} | {} | {} | {} / {} / {} / {} / {} | {} | {} | {:.2} |",
            r.run,
            r.scans,
            r.segments,
            r.revisiting,
            r.merged,
            r.misplaced,
            l.no_match,
            l.hypothesis,
            l.conditional,
            l.undone,
            l.misplaced,
            list(&r.to_conditional_m),
            list(&r.to_full_m),
            r.ms_per_scan
        );
    }
    let l = &report.lost;
    let m = |v: Option<f64>| v.map_or_else(|| "-".to_owned(), |d| format!("{d:.1}"));
    println!(
        "\nrevisiting segments merged and placed: {} of {} ({:.0} %); misplaced {}; lost at no match {}, hypothesis {}, conditional {}, undone {}, misplaced {}; relocalization to conditional median {} m (p90 {}), to full median {} m (p90 {}); {:.2} ms per scan",
        report.merged,
        report.revisiting,
        100.0 * report.merged as f64 / report.revisiting.max(1) as f64,
        report.misplaced,
        l.no_match,
        l.hypothesis,
        l.conditional,
        l.undone,
        l.misplaced,
        m(report.to_conditional_median_m),
        m(report.to_conditional_p90_m),
        m(report.to_full_median_m),
        m(report.to_full_p90_m),
        report.ms_per_scan
    );
    let b = &report.breaks;
    println!(
        "kidnaps detected within {DETECT_WITHIN_SCANS} scans: {} of {} ({} later); false breaks {} over {:.0} m ({} per 500 m)",
        b.detected,
        b.kidnaps,
        b.late,
        b.false_breaks,
        b.travel_m,
        report
            .false_breaks_per_500_m
            .map_or_else(|| "-".to_owned(), |r| format!("{r:.2}"))
    );
    let st = &report.starts;
    if st.sessions > 0 {
        println!(
            "later sessions: {}; starting where an earlier session passed: {}; started localized within {START_LOCALIZED_WITHIN_M} m: {} correctly, {} wrongly; travel to the first correct merge, median {} m",
            st.sessions,
            st.covered,
            st.localized,
            st.wrongly,
            quantile(&st.to_localized_m, 0.5).map_or_else(|| "-".to_owned(), |d| format!("{d:.1}"))
        );
    }
    if let Some(q) = &report.queries {
        println!(
            "merge queries at true revisits: {}; a true place retrieved {}, admitted {}, verified to the true pose {} ({} at the acceptance score), accepted {}; wrong matches accepted {}",
            q.revisit_queries,
            q.retrieved_true,
            q.admitted_true,
            q.verified_true,
            q.verified_true_above,
            q.accepted_true,
            q.accepted_wrong
        );
    }
    Ok(())
}

/// One atlas run of `sessions` into `args.output/<run>`, judged from its files.
fn run_one(
    run: &str,
    sessions: &[AtlasSession],
    frames: Frames,
    params: &EngineParams,
    args: &LifelongEvalArgs,
) -> anyhow::Result<RunRow> {
    let output = args.output.join(run);
    let job = AtlasJob::open(AtlasOptions {
        params: params.clone(),
        output: output.clone(),
        pictures: false,
        store: None,
        keep_versions: 1,
        announce_kidnaps: !args.hide_kidnaps,
    })
    .map_err(crate::job_error)?;
    let mut done = job.run(sessions, |_| {}).map_err(crate::job_error)?;
    // Sessions that share one truth frame (the simulator's): how each later one started.
    let started = match frames {
        Frames::Shared => {
            crate::atlas_judge::judge_atlas(&mut done, sessions);
            judge_starts(done.engine.events(), &done.report.merges, sessions)
        }
        Frames::PerSession => StartJudgement::default(),
    };
    let judged = judge_maps(&output, sessions, frames)?;
    let report = &done.report;
    let starts = session_starts(sessions);
    let epochs = epoch_starts(report)?;
    // The epoch the engine was in at a scan: the last one started at or before it.
    let epoch_at = |scan: usize| {
        epochs
            .iter()
            .take_while(|(at, _)| *at <= scan)
            .last()
            .map(|(_, epoch)| *epoch)
    };
    let mut lost = LostAt::default();
    let (mut to_conditional_m, mut to_full_m) = (Vec::new(), Vec::new());
    for segment in judged.segments.iter().filter(|s| s.revisits) {
        let last = starts[segment.session] + last_scan(segment, sessions);
        let epoch = epoch_at(last);
        if segment.merged_correctly {
            let first = segment.first_revisit_scan.unwrap_or(0);
            let truth = sessions[segment.session]
                .reference
                .as_deref()
                .unwrap_or(&[]);
            let merge = report
                .merges
                .iter()
                .filter(|m| Some(m.epoch) == epoch && m.full_at_scan.is_some())
                .min_by_key(|m| m.full_at_scan);
            if let Some(m) = merge {
                let local = |scan: usize| scan.saturating_sub(starts[segment.session]);
                let travel = |to: usize| travel_m(truth, first, local(to));
                if let Some(at) = m.conditional_at_scan {
                    to_conditional_m.push(travel(at));
                }
                if let Some(at) = m.full_at_scan {
                    to_full_m.push(travel(at));
                }
            }
            continue;
        }
        let outcome = epoch.and_then(|e| report.epoch_outcomes.iter().find(|o| o.epoch.0 == e));
        match outcome.map(|o| o.end) {
            None | Some(EpochEnd::NoHypothesis) => lost.no_match += 1,
            Some(EpochEnd::HypothesesNeverConditional) => lost.hypothesis += 1,
            Some(EpochEnd::ConditionalNeverFull) => lost.conditional += 1,
            Some(EpochEnd::MergeUndone) => lost.undone += 1,
            Some(EpochEnd::Merged) => lost.misplaced += 1,
        }
    }
    Ok(RunRow {
        run: run.to_owned(),
        scans: report.scans,
        segments: judged.segments.len(),
        revisiting: judged.segments_revisiting,
        merged: judged.revisiting_merged_correctly,
        misplaced: judged.misplaced,
        lost,
        to_conditional_m,
        to_full_m,
        ms_per_scan: report.ms_per_scan,
        merged_maps: merged_maps(&judged),
        queries: args.diagnose.then(|| query_stages(&done, params)),
        breaks: judge_breaks(done.engine.events(), sessions),
        starts: started,
    })
}

/// The traced merge queries of `run` at true revisits, stage by stage (one truth frame: a
/// single log, or a simulated world).
fn query_stages(run: &mapmerge_jobs::AtlasRun, params: &EngineParams) -> QueryStages {
    use mapmerge_geometry::{LieGroup, Se2};
    let atlas = run.engine.atlas();
    let truth = &run.reference_of_node;
    let epoch = |n: NodeId| atlas.epoch_of(n).map(|e| e.0);
    let near = |a: NodeId, b: NodeId, within_m: f64| {
        truth
            .get(&a)
            .zip(truth.get(&b))
            .is_some_and(|(x, y)| (x.translation() - y.translation()).norm() <= within_m)
    };
    let is_true = |query: NodeId, candidate: NodeId, candidate_from_query: &Se2| {
        let (Some(q), Some(c)) = (truth.get(&query), truth.get(&candidate)) else {
            return false;
        };
        let error = c.between(q).between(candidate_from_query);
        error.translation().norm() <= crate::atlas_judge::TRUE_WITHIN.0
            && error.theta_rad.abs() <= crate::atlas_judge::TRUE_WITHIN.1
    };
    let min_score = params.atlas.recognition.place.min_score;
    // Each query once, over every graph it searched.
    let mut by_query: BTreeMap<NodeId, Vec<&mapmerge_atlas::MergeQueryTrace>> = BTreeMap::new();
    for record in atlas.merge_trace() {
        by_query.entry(record.query).or_default().push(record);
    }
    let mut stages = QueryStages::default();
    for (query, records) in by_query {
        let Some(query_epoch) = epoch(query) else {
            continue;
        };
        let revisit = truth
            .keys()
            .any(|&k| epoch(k).is_some_and(|e| e < query_epoch) && near(query, k, REVISIT_QUERY_M));
        for (node, verified) in records.iter().flat_map(|r| r.verified.iter()) {
            if let Some((from, score)) = verified {
                if is_true(query, *node, from) {
                    stages.scores_true.push(*score);
                } else {
                    stages.scores_wrong.push(*score);
                }
            }
        }
        let accepted = records.iter().filter_map(|r| r.accepted.as_ref());
        for (node, from, _, _) in accepted.clone() {
            if is_true(query, *node, from) {
                stages.accepted_true += usize::from(revisit);
            } else {
                stages.accepted_wrong += 1;
            }
        }
        if !revisit {
            continue;
        }
        stages.revisit_queries += 1;
        let retrieved = records.iter().flat_map(|r| r.retrieved.iter());
        let true_retrieved: Vec<&(NodeId, f64, bool)> = retrieved
            .filter(|(n, _, _)| near(query, *n, TRUE_CANDIDATE_M))
            .collect();
        stages.retrieved_true += usize::from(!true_retrieved.is_empty());
        stages.admitted_true += usize::from(true_retrieved.iter().any(|(_, _, a)| *a));
        let verified = records.iter().flat_map(|r| r.verified.iter());
        let true_verified: Vec<f64> = verified
            .filter_map(|(n, v)| v.filter(|(from, _)| is_true(query, *n, from)).map(|v| v.1))
            .collect();
        stages.verified_true += usize::from(!true_verified.is_empty());
        stages.verified_true_above += usize::from(true_verified.iter().any(|&s| s >= min_score));
    }
    stages
}

fn merged_maps(judged: &MapsJudgement) -> Vec<(String, Option<f64>, Option<f64>)> {
    judged
        .maps
        .iter()
        .filter(|m| m.segments.len() > 1)
        .map(|m| (m.map.clone(), m.whole_ate_m, m.worst_placed_off_m))
        .collect()
}

/// The engine's scan number at each session's start (every scan fed).
fn session_starts(sessions: &[AtlasSession]) -> Vec<usize> {
    let mut start = 0;
    sessions
        .iter()
        .map(|s| {
            let here = start;
            start += s.log.scans.len();
            here
        })
        .collect()
}

/// A segment's last scan in its session.
fn last_scan(segment: &SegmentJudgement, sessions: &[AtlasSession]) -> usize {
    let session = &sessions[segment.session];
    let end = session
        .kidnaps
        .get(segment.segment)
        .copied()
        .unwrap_or(session.log.scans.len());
    end.saturating_sub(1)
}

/// Where each epoch started (scan, epoch), from the run's `events.jsonl`.
fn epoch_starts(report: &AtlasReport) -> anyhow::Result<Vec<(usize, u32)>> {
    let path = &report.events;
    let text = std::fs::read_to_string(path)
        .map_err(|e| anyhow::anyhow!("reading {}: {e}", path.display()))?;
    let mut starts = Vec::new();
    for line in text.lines() {
        let event: serde_json::Value = serde_json::from_str(line)?;
        if event["event"] == "epoch_started" {
            if let (Some(scan), Some(epoch)) = (event["scan"].as_u64(), event["epoch"].as_u64()) {
                starts.push((scan as usize, epoch as u32));
            }
        }
    }
    Ok(starts)
}

/// Travel (m) along `truth` from scan `from` to scan `to` (0 when `to` is not later).
fn travel_m(truth: &[mapmerge_geometry::Se2], from: usize, to: usize) -> f64 {
    truth
        .get(from..=to.min(truth.len().saturating_sub(1)))
        .unwrap_or_default()
        .windows(2)
        .map(|w| (w[1].translation() - w[0].translation()).norm())
        .sum()
}

/// The `q` quantile (nearest rank) of `values`; none when empty.
fn quantile(values: &[f64], q: f64) -> Option<f64> {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let rank = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len().max(1));
    sorted.get(rank - 1).copied()
}
