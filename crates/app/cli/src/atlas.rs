//! `mapmerge atlas`: the lifelong pipeline over one or more sessions — epochs, merging by place
//! recognition, invalid-merge detection and undo (`mapmerge-engine`).
//!
//! Inputs are CARMEN logs (each a session: the epoch ends with `restart` between logs; scans
//! listed in `--kidnap-at`, counted over all logs from 0, start a new epoch with `kidnap`), or
//! a simulated data set (`--sim PRESET`): its sessions, its kidnaps announced as kidnaps, and
//! its ground truth to judge every merge. With `--hide-kidnaps` the engine is not told: its
//! tracking-failure detector must end the epoch (`tracking_lost`).
//!
//! Writes `DIR/events.jsonl` (every epoch, merge and unmerge with its reason, the scan count
//! and travel when it happened), `DIR/atlas/` (each graph as g2o and a picture of its map) and
//! `DIR/pictures/NNN-{merge,unmerge}-{before,after}.png` (points coloured by epoch; the
//! detector's window — the newest current-epoch scans — drawn thicker in change detection's
//! classes: red change, green agree, grey no information; merge edges magenta).
//!
//! The run is [`mapmerge_jobs::AtlasJob`] (as Python's `run_atlas`); the simulated sessions
//! and the judging against a truth are the lab's ([`mapmerge_lab::atlas_judge`]).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use mapmerge_engine::{EngineParams, EpochEndReason, MergeState};
use mapmerge_jobs::{log_sessions, AtlasJob, AtlasOptions, AtlasProgress, AtlasReport};
use mapmerge_lab::atlas_judge::{
    judge_atlas, simulated_sessions, write_merge_results, AtlasJudgement, REVISIT_MIN_M,
    REVISIT_RADIUS_M, UNDO_WITHIN_M,
};
use mapmerge_lab::break_judge::{judge_breaks, BreakJudgement, DETECT_WITHIN_SCANS};
use mapmerge_lab::carried::{carried_sessions, Carry};
use mapmerge_lab::map_judge::{judge_maps, Frames, MapsJudgement, PLACED_WITHIN_M};
use serde::Serialize;

use crate::{job_error, print_json};

/// Arguments of `mapmerge atlas`.
#[derive(Args, Debug)]
pub struct AtlasArgs {
    /// CARMEN logs (`.xz` accepted) or ROS 2 bags (`.mcap`, `.db3`, bag directories), one
    /// per session, in order.
    pub logs: Vec<PathBuf>,
    /// Topics of a ROS 2 bag.
    #[command(flatten)]
    pub topics: crate::BagTopics,
    /// Scans (counted over all logs from 0) where the robot was kidnapped: each starts a new
    /// epoch.
    #[arg(long, value_delimiter = ',')]
    pub kidnap_at: Vec<usize>,
    /// Withhold the kidnaps (the simulator's, or `--odometry-noise`'s carries) from the
    /// engine: its tracking-failure detector must notice them. They are still judged, and
    /// `sim` still writes them in dataset.json.
    #[arg(long)]
    pub hide_kidnaps: bool,
    /// With `--odometry-noise` and no `--kidnap-at`: draw no kidnaps (the robot is never
    /// carried).
    #[arg(long, requires = "odometry_noise", conflicts_with = "kidnap_at")]
    pub no_kidnaps: bool,
    /// Simulate the sessions instead: a world preset (office, office-aliased, corridor-loop,
    /// warehouse, symmetric-hall). Merges are then judged against the simulator's ground
    /// truth.
    #[arg(long, conflicts_with = "logs")]
    pub sim: Option<String>,
    /// Simulated sessions.
    #[arg(long, default_value_t = 3)]
    pub sessions: usize,
    /// Robot time per simulated session (s).
    #[arg(long, default_value_t = 120.0)]
    pub duration: f64,
    /// Seed of the simulation, or of `--odometry-noise` (noise and drawn kidnaps).
    #[arg(long, default_value_t = 12)]
    pub seed: u64,
    /// Simulate only this session of the world (its changes, route and noise as in the
    /// whole simulation): one session per run, as a robot lives with `--store`.
    #[arg(long, requires = "sim")]
    pub session_index: Option<usize>,
    /// The lifelong store (created when missing): the run continues the atlas of its newest
    /// version and commits one version per session, atomically.
    #[arg(long)]
    pub store: Option<PathBuf>,
    /// How many of the newest versions keep their atlas in the store (older versions keep
    /// their summary only).
    #[arg(long, default_value_t = mapmerge_store::DEFAULT_KEEP_VERSIONS, requires = "store")]
    pub keep_versions: usize,
    /// Keep every view, local map, vertex and edge (the unpruned baseline; sets
    /// `atlas.maintenance.prune` to false).
    #[arg(long)]
    pub no_prune: bool,
    /// Engine parameters (JSON, `mapmerge_engine::EngineParams`; absent fields keep their
    /// defaults).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Judge every merge against the logs' own poses (the public *corrected* logs: their
    /// poses are the reference; merge edges must lie within 0.5 m and 10°).
    #[arg(long, conflicts_with = "sim")]
    pub judge_with_log_poses: bool,
    /// Replace each corrected log's poses by seeded wheel odometry (`default`, `harsh` or
    /// `none`, the model of `slam --odometry-noise`, drawn with `--seed`) and kidnap the robot:
    /// at each kidnap it is carried further along the log (5–15 % of its scans are never seen)
    /// while its odometry goes on as if it had not moved. Kidnaps are `--kidnap-at`'s, else
    /// drawn with the seed (one per 150 m of travel, one to four per log). Every merge is then
    /// judged against the corrected poses.
    #[arg(long, conflicts_with_all = ["sim", "judge_with_log_poses"])]
    pub odometry_noise: Option<String>,
    /// Skip the pictures (faster).
    #[arg(long)]
    pub no_pictures: bool,
    /// Writes every judged merge that the detector read as `mapmerge eval invalid-merge`
    /// results (JSON lines: one per method, the detector's and its components' highest
    /// ratios, labelled by the truth), so that `mapmerge eval calibrate --results` can fit
    /// the decision on the engine's own merges.
    #[arg(long)]
    pub merge_results: Option<PathBuf>,
    /// The group these merges count as in `--merge-results` (`eval calibrate` leaves one
    /// group out at a time; default: `sim-PRESET`, or the first log's name).
    #[arg(long)]
    pub results_group: Option<String>,
    /// Output folder.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Print one JSON summary instead of text.
    #[arg(long)]
    pub json: bool,
}

/// What `--json` prints: the job's report and, with a reference, the lab's verdicts.
#[derive(Serialize)]
struct Report<'a> {
    #[serde(flatten)]
    run: &'a AtlasReport,
    #[serde(flatten)]
    judgement: AtlasJudgement,
    /// With a reference: the per-map trajectories judged against it.
    #[serde(skip_serializing_if = "Option::is_none")]
    from_trajectories: Option<MapsJudgement>,
    /// With `--odometry-noise`: each log's carries (original scan numbers).
    #[serde(skip_serializing_if = "Option::is_none")]
    carries: Option<Vec<Vec<Carry>>>,
    /// The engine's `tracking_lost` breaks against the sessions' kidnaps.
    breaks: BreakJudgement,
}

/// Runs `mapmerge atlas`.
pub fn run(args: &AtlasArgs) -> anyhow::Result<ExitCode> {
    crate::check_output_dir(&args.output)?;
    let mut params: EngineParams = crate::read_config(args.config.as_deref())?;
    if args.no_prune {
        params.atlas.maintenance.prune = false;
    }
    // The store first: a refused store stops the run before any work.
    let job = AtlasJob::open(AtlasOptions {
        params,
        output: args.output.clone(),
        pictures: !args.no_pictures,
        store: args.store.clone(),
        keep_versions: args.keep_versions,
        announce_kidnaps: !args.hide_kidnaps,
    })
    .map_err(job_error)?;
    let mut carries = None;
    let sessions = match &args.sim {
        Some(preset) => simulated_sessions(
            preset,
            args.sessions,
            args.duration,
            args.seed,
            args.session_index,
        )?,
        None => {
            let logs = args
                .logs
                .iter()
                .map(|path| {
                    Ok((
                        path.display().to_string(),
                        crate::read_log(path, &args.topics)?,
                    ))
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            match &args.odometry_noise {
                Some(noise) => {
                    let (sessions, carried) = carried_sessions(
                        logs,
                        &args.kidnap_at,
                        !args.no_kidnaps,
                        noise,
                        args.seed,
                    )?;
                    carries = Some(carried);
                    sessions
                }
                None => log_sessions(logs, &args.kidnap_at, args.judge_with_log_poses)
                    .map_err(job_error)?,
            }
        }
    };
    let total: usize = sessions.iter().map(|s| s.log.scans.len()).sum();
    let visible = !args.json && std::io::IsTerminal::is_terminal(&std::io::stderr());
    let bar = crate::progress_bar(total, "scans", "", visible);
    let mut run = job
        .run(&sessions, |step| match step {
            AtlasProgress::Session(name) => bar.set_message(name.to_owned()),
            AtlasProgress::Scan => bar.inc(1),
        })
        .map_err(job_error)?;
    bar.finish_and_clear();
    let judgement = judge_atlas(&mut run, &sessions);
    // Simulated sessions share the world's frame; each corrected log has its own.
    let frames = match args.sim {
        Some(_) => Frames::Shared,
        None => Frames::PerSession,
    };
    let from_trajectories = sessions
        .iter()
        .all(|s| s.reference.is_some())
        .then(|| judge_maps(&args.output, &sessions, frames))
        .transpose()?;
    if let Some(path) = &args.merge_results {
        let group = args
            .results_group
            .clone()
            .unwrap_or_else(|| match &args.sim {
                Some(preset) => format!("sim-{preset}"),
                None => args
                    .logs
                    .first()
                    .map_or_else(|| "atlas".to_owned(), |l| crate::log_short_name(l)),
            });
        let name = args
            .output
            .file_name()
            .map_or_else(|| "atlas".into(), |n| n.to_string_lossy().into_owned());
        write_merge_results(&run.report.merges, &group, &name, path)?;
    }
    let report = Report {
        run: &run.report,
        judgement,
        from_trajectories,
        carries,
        breaks: judge_breaks(run.engine.events(), &sessions),
    };
    if args.json {
        print_json(&report)?;
    } else {
        print_text(
            report.run,
            &report.judgement,
            report.from_trajectories.as_ref(),
        );
        let b = &report.breaks;
        if args.hide_kidnaps && b.kidnaps > 0 {
            println!(
                "  withheld kidnaps: {} of {} found by the tracker within {DETECT_WITHIN_SCANS} scans, {} later",
                b.detected, b.kidnaps, b.late
            );
        }
        if b.false_breaks > 0 {
            println!(
                "  the tracker lost track {} times away from any kidnap ({:.0} m travelled)",
                b.false_breaks, b.travel_m
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn print_text(run: &AtlasReport, judgement: &AtlasJudgement, maps: Option<&MapsJudgement>) {
    println!(
        "{} sessions, {} scans, {} epochs; {} merge decisions, {} unmerges in {:.1} s",
        run.sessions,
        run.scans,
        run.epochs,
        run.merges.len(),
        run.unmerges.len(),
        run.seconds
    );
    for m in &run.merges {
        let verdict = match m.correct {
            Some(true) => " (correct)",
            Some(false) => " (WRONG)",
            None => "",
        };
        let how = match (m.conditional_at_scan, m.full_at_scan) {
            (Some(_), Some(_)) => format!(
                "conditional, full {:.1} m later",
                m.full_after_m.unwrap_or_default()
            ),
            (Some(_), None) => "conditional".to_owned(),
            _ => "full".to_owned(),
        };
        let fate = match (m.state, m.undone_after_m, m.final_after_m) {
            (MergeState::Rejected, Some(d), _) => format!(
                "rejected after {d:.1} m ({})",
                m.reason.as_deref().unwrap_or("")
            ),
            (MergeState::Undone, Some(d), _) => format!(
                "undone after {d:.1} m ({})",
                m.reason.as_deref().unwrap_or("")
            ),
            (MergeState::Conditional, _, _) => "still conditional when its epoch ended".to_owned(),
            (_, _, Some(d)) => format!("kept; final when its epoch ended {d:.1} m later"),
            _ => "kept".to_owned(),
        };
        println!(
            "  merge at scan {} ({:.0} m): epoch {} into map {} (epochs {:?}), {how}, by {} edges{verdict}; {fate}",
            m.scan, m.travel_m, m.epoch, m.map, m.epochs, m.loop_edges
        );
    }
    for u in &run.unmerges {
        println!(
            "  unmerge at scan {} ({:.0} m): merges {:?} undone because {}",
            u.scan, u.travel_m, u.merges, u.reason
        );
    }
    let h = &run.hypotheses;
    println!(
        "  hypotheses: {} ({} merge, {} recovery), {} conditional, {} full, {} conditional rejected, {} expired; {} ambiguous keyframes ({} of {} views searched fit themselves elsewhere; {} of {} joint sets of them fit nowhere else)",
        h.created, h.merge, h.recovery, h.conditional, h.full, h.rejected_conditional, h.expired,
        run.ambiguous_keyframes, run.self_similarity.self_similar, run.self_similarity.views,
        run.self_similarity.joint_unique, run.self_similarity.joint_searched
    );
    // The first epoch has nothing to merge into unless the run continued a stored atlas.
    let skip = usize::from(run.epochs_with_a_map < run.epochs);
    for o in run.epoch_outcomes.iter().skip(skip) {
        let began = match &o.started_by {
            None => "began the run".to_owned(),
            Some(EpochEndReason::Kidnap) => "began at an announced kidnap".to_owned(),
            Some(EpochEndReason::TrackingLost) => "began when the tracker lost track".to_owned(),
            Some(EpochEndReason::Restart) => "began at a restart".to_owned(),
            Some(EpochEndReason::Other(why)) => format!("began: {why}"),
        };
        println!(
            "  epoch {} ({began}): {:.0} m; merge hypotheses {} (most observations {}, weighted {:.1}), conditional {}, merged {}, undone {}: {}",
            o.epoch.0,
            o.travel_m,
            o.hypotheses,
            o.most_observations,
            o.most_weighted_observations,
            o.conditional_merges,
            o.merges,
            o.unmerges,
            match o.end {
                mapmerge_engine::EpochEnd::Merged => "ends merged",
                mapmerge_engine::EpochEnd::MergeUndone => "its merge was undone",
                mapmerge_engine::EpochEnd::ConditionalNeverFull => "a conditional merge never became full",
                mapmerge_engine::EpochEnd::HypothesesNeverConditional => "no hypothesis became conditional",
                mapmerge_engine::EpochEnd::NoHypothesis => "no merge hypothesis (place recognition verified no match)",
            }
        );
    }
    if let (Some(w), Some(u), Some(c), Some(cu), Some(cr), Some(e)) = (
        judgement.wrong_merges,
        judgement.wrong_undone_within_10m,
        judgement.correct_merges,
        judgement.correct_undone,
        judgement.correct_rejected,
        judgement.epochs_merged_correctly,
    ) {
        println!(
            "  against the ground truth: {u} of {w} wrong merges rejected or undone within {UNDO_WITHIN_M} m; {cu} of {c} correct merges undone, {cr} rejected; {e} of {} later epochs end merged correctly",
            run.epochs_with_a_map
        );
    }
    if let (Some(r), Some(m)) = (
        judgement.epochs_revisiting,
        judgement.epochs_revisiting_merged_correctly,
    ) {
        println!(
            "  {m} of the {r} later epochs that travelled {REVISIT_MIN_M} m or more within {REVISIT_RADIUS_M} m of an earlier epoch's path end merged correctly"
        );
    }
    if let Some(maps) = maps {
        println!(
            "  from the per-map trajectories: {} of {} revisiting segments end merged and placed within {PLACED_WITHIN_M} m; {} segments placed further off beside another; {} scans in no map",
            maps.revisiting_merged_correctly, maps.segments_revisiting, maps.misplaced, maps.scans_in_no_map
        );
        for m in maps.maps.iter().filter(|m| m.segments.len() > 1) {
            println!(
                "    {}: segments {:?}, whole-map ATE {} m, worst segment {} m beyond its own error",
                m.map,
                m.segments,
                m.whole_ate_m.map_or_else(|| "-".to_owned(), |a| format!("{a:.2}")),
                m.worst_placed_off_m.map_or_else(|| "-".to_owned(), |a| format!("{a:.2}")),
            );
        }
    }
    if let Some(store) = &run.store {
        let continued = store
            .resumed_from
            .map_or_else(|| "a new atlas".to_owned(), |v| format!("version {v}"));
        for c in &store.committed {
            println!(
                "  store {}: continued {continued}, committed version {} ({} nodes, {} edges, {} keyframes, {} local maps, {:.0} m², {} bytes; session ATE {} m; pruned {} views, {} local maps, {} vertices, {} edges)",
                store.path.display(),
                c.version.version,
                c.version.nodes,
                c.version.edges,
                c.version.keyframes,
                c.version.local_maps,
                c.version.mapped_area_m2,
                c.version.bytes,
                c.session_ate_m.map_or_else(|| "-".to_owned(), |a| format!("{a:.3}")),
                c.maintenance.views_pruned,
                c.maintenance.local_maps_pruned,
                c.maintenance.vertices_marginalized,
                c.maintenance.edges_pruned,
            );
        }
    }
    for r in &run.rejoins {
        println!(
            "  fragment map {} (epochs {:?}, {} vertices) rejoined map {} by {} matches (score {:.3})",
            r.map, r.epochs, r.vertices, r.into, r.loops, r.score
        );
    }
    if let Some(first) = run.pictures.first() {
        println!(
            "  pictures: {} ({} files); events: {}",
            first.parent().unwrap_or(first).display(),
            run.pictures.len(),
            run.events.display()
        );
    } else {
        println!("  events: {}", run.events.display());
    }
}
