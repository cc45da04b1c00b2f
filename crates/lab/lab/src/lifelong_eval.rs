//! `mapmerge eval lifelong`: the lifelong engine under real conditions, judged from its
//! outputs. Each corrected log is run once per seed as a kidnapped robot recorded it
//! ([`crate::carried`]: seeded noisy odometry, 1–4 carries by travel, the odometry going on as
//! if the robot had not moved); each simulated world once per seed with its own kidnaps.
//! Every run is `mapmerge atlas`'s job; its `maps/` are judged against the truth
//! ([`crate::map_judge`]). Per run: revisiting segments, those ending merged and placed,
//! misplaced ones, the stage where each lost revisit stopped, the relocalization distance of
//! each merge (iRobot Sec. 6: travel from the first true revisit to the conditional and to
//! the full merge) and the time per scan.

use std::path::PathBuf;

use clap::Args;
use mapmerge_engine::{EngineParams, EpochEnd};
use mapmerge_jobs::{AtlasJob, AtlasOptions, AtlasReport, AtlasSession};
use serde::Serialize;

use crate::map_judge::{judge_maps, Frames, MapsJudgement, SegmentJudgement};
use crate::print_json;
use crate::protrusion_eval::seeds;

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
    /// Folder for every run's outputs (`<run>/maps/…`).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

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
}

#[derive(Serialize)]
struct Report {
    runs: Vec<RunRow>,
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
}

/// Runs `mapmerge eval lifelong`.
pub fn run(args: &LifelongEvalArgs) -> anyhow::Result<()> {
    let params: EngineParams = crate::read_config(args.config.as_deref())?;
    let mut runs = Vec::new();
    for path in &args.logs {
        let name = crate::log_short_name(path);
        let log = crate::read_log(path, &crate::BagTopics::default())?;
        for seed in seeds(&args.seeds)? {
            let (sessions, _) = crate::carried::carried_sessions(
                vec![(name.clone(), log.clone())],
                &[],
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
        lost.no_match += r.lost.no_match;
        lost.hypothesis += r.lost.hypothesis;
        lost.conditional += r.lost.conditional;
        lost.undone += r.lost.undone;
        lost.misplaced += r.lost.misplaced;
    }
    let all = |f: fn(&RunRow) -> &Vec<f64>| -> Vec<f64> {
        runs.iter().flat_map(|r| f(r).iter().copied()).collect()
    };
    let (conditional, full) = (all(|r| &r.to_conditional_m), all(|r| &r.to_full_m));
    let scans = sum(|r| r.scans);
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
    })
    .map_err(crate::job_error)?;
    let done = job.run(sessions, |_| {}).map_err(crate::job_error)?;
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
    })
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
