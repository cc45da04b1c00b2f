//! `mapmerge atlas`: the lifelong pipeline over one or more sessions — epochs, merging by place
//! recognition, invalid-merge detection and undo (`mapmerge-engine`).
//!
//! Inputs are CARMEN logs (each a session: the epoch ends with `restart` between logs; scans
//! listed in `--kidnap-at`, counted over all logs from 0, start a new epoch with `kidnap`), or
//! a simulated data set (`--sim PRESET`): its sessions, with the simulator's kidnaps standing
//! in for a tracking-failure detector, and its ground truth to judge every merge.
//!
//! Writes `DIR/events.jsonl` (every epoch, merge and unmerge with its reason, the scan count
//! and travel when it happened), `DIR/atlas/` (each graph as g2o and a picture of its map) and
//! `DIR/pictures/NNN-{merge,unmerge}-{before,after}.png` (points coloured by epoch; the
//! detector's window — the newest current-epoch scans — drawn thicker in change detection's
//! classes: red change, green agree, grey no information; merge edges magenta).

use std::collections::{BTreeMap, BTreeSet};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use mapmerge_atlas::{AtlasEvent, EpochEndReason};
use mapmerge_engine::{Decision, DetectorReading, Engine, EngineParams, EventKind, MergeState};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::{NodeId, PoseGraph2};
use mapmerge_scan::LaserLog;
use mapmerge_sim::{simulate, simulate_session_alone, SimParams};
use nalgebra::Vector2;
use serde::Serialize;

use mapmerge_jobs::{draw_graph, write_atlas};
use mapmerge_lab::invalid_merge_eval::{Label, MergeResult};

use crate::{bad_file, bad_input, job_error, print_json};

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
    /// Seed of the simulation.
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

/// One session's input.
struct Session {
    name: String,
    log: LaserLog,
    /// Scans (of this session) that start a new epoch by a kidnap.
    kidnaps: Vec<usize>,
    /// Ground truth per scan (simulation only).
    truth: Option<Vec<Se2>>,
}

/// A merge as reported: one per merge decision (conditional, full, rejected or undone).
#[derive(Clone, Debug, Serialize)]
struct MergeReport {
    /// The atlas's merge id, once merged fully.
    merge: Option<u64>,
    /// The hypothesis it came from (none for a forced merge).
    hypothesis: Option<u64>,
    /// Scan and travel when it was first decided (conditional, else full).
    scan: usize,
    travel_m: f64,
    /// The epoch that merged, and the inactive graph with its epochs.
    epoch: u32,
    map: u32,
    epochs: Vec<u32>,
    /// Merge edges (observations and overlap loops) and, when full, the overlap edges the
    /// full merge found.
    loop_edges: usize,
    overlap_edges: usize,
    /// `conditional`, `full`, `rejected` (a conditional merge dropped) or `undone`.
    state: mapmerge_engine::MergeState,
    conditional_at_scan: Option<usize>,
    full_at_scan: Option<usize>,
    /// Travel from conditional to full (m).
    full_after_m: Option<f64>,
    /// Why it was rejected or undone.
    reason: Option<String>,
    /// Judged by the merge edges against the ground truth (simulation, or the logs' poses
    /// with `--judge-with-log-poses`): `true` when most are within 0.5 m and 10° of it.
    correct: Option<bool>,
    /// The median merge edge's error against that truth `[m, deg]` (the edge of median
    /// translation error).
    error_m_deg: Option<[f64; 2]>,
    /// When it was rejected or undone: scan, and robot travel from the first decision (m).
    undone_at_scan: Option<usize>,
    undone_after_m: Option<f64>,
    /// When its epoch ended (a full merge became final): travel after the merge (m).
    final_after_m: Option<f64>,
    /// What the detector (first) and its components read while the merge was judged.
    readings: Vec<DetectorReading>,
}

#[derive(Clone, Debug, Serialize)]
struct UnmergeReport {
    scan: usize,
    travel_m: f64,
    merges: Vec<u64>,
    reason: String,
}

/// How many of the searched local maps' scores fit themselves elsewhere: from
/// `decisions.self_similar_from_score` (`threshold`) on.
fn fitting_elsewhere<'a>(scores: impl IntoIterator<Item = &'a f64>, threshold: f64) -> usize {
    scores
        .into_iter()
        .filter(|&&score| score >= threshold)
        .count()
}

#[derive(Serialize)]
struct SelfSimilarityReport {
    views: usize,
    self_similar: usize,
    /// Joint local maps of a hypothesis's self-similar views searched (`decisions.joint_views`) …
    joint_searched: usize,
    /// … and those that fit nowhere else (their views then count in full).
    joint_unique: usize,
    seconds: f64,
}

#[derive(Serialize)]
struct Report {
    sessions: usize,
    scans: usize,
    epochs: usize,
    /// Epochs that had a map to merge into: all but the first, or all when the run continued
    /// a stored atlas.
    epochs_with_a_map: usize,
    merges: Vec<MergeReport>,
    unmerges: Vec<UnmergeReport>,
    hypotheses: mapmerge_engine::HypothesisSummary,
    /// Every epoch: its merge hypotheses and how far they got (why a later epoch did or did
    /// not merge).
    epoch_outcomes: Vec<mapmerge_engine::EpochOutcome>,
    ambiguous_keyframes: usize,
    /// Views of inactive graphs searched for another placement of their own local map, those
    /// found self-similar (ambiguous), and the time it took.
    self_similarity: SelfSimilarityReport,
    /// Where the time went: the tracker's and the constraint builder's counters.
    tracker: mapmerge_slam::TrackerInfo,
    constraints: mapmerge_atlas::ConstraintInfo,
    /// Simulation: wrong merges (any state), those rejected or undone within 10 m of travel,
    /// correct ones, those undone (full) and those rejected (conditional), epochs after the
    /// first that end with a kept correct merge.
    wrong_merges: Option<usize>,
    wrong_undone_within_10m: Option<usize>,
    correct_merges: Option<usize>,
    correct_undone: Option<usize>,
    correct_rejected: Option<usize>,
    epochs_merged_correctly: Option<usize>,
    /// Simulation, fresh runs: epochs after the first whose true path ran at least
    /// `REVISIT_MIN_M` within `REVISIT_RADIUS_M` of an earlier epoch's (the others had
    /// little or no chance to merge), those of them that end with a kept correct merge, and
    /// every epoch's figures.
    epochs_revisiting: Option<usize>,
    epochs_revisiting_merged_correctly: Option<usize>,
    epoch_revisits: Option<Vec<EpochRevisit>>,
    pictures: Vec<PathBuf>,
    events: PathBuf,
    /// With `--store`: what was continued and what was committed.
    store: Option<StoreRunReport>,
    seconds: f64,
    ms_per_scan: f64,
}

/// One epoch after the first, against the ground truth.
#[derive(Serialize)]
struct EpochRevisit {
    epoch: usize,
    /// Its true path's length (m) …
    travel_m: f64,
    /// … and the part of it within `REVISIT_RADIUS_M` of an earlier epoch's true path (m).
    revisit_travel_m: f64,
    /// Whether it ends with a kept correct merge.
    merged_correctly: bool,
}

/// `atlas --store`: the version continued and the versions committed.
#[derive(Serialize)]
struct StoreRunReport {
    path: PathBuf,
    /// The version the run continued (none for a new store).
    resumed_from: Option<i64>,
    /// Opening the store, loading its newest atlas and rebuilding the place index (s).
    open_secs: f64,
    committed: Vec<CommittedSession>,
}

/// One committed session.
#[derive(Serialize)]
struct CommittedSession {
    #[serde(flatten)]
    version: mapmerge_store::VersionInfo,
    /// Ending the session, maintaining, snapshotting and committing the atlas (s).
    commit_secs: f64,
    /// ATE (m, RMS after rigid alignment) of the session's keyframes against their reference
    /// poses, and of every keyframe of the graph the robot ended in.
    session_ate_m: Option<f64>,
    map_ate_m: Option<f64>,
    /// What maintenance did before the commit (included in `commit_secs`).
    maintenance: mapmerge_atlas::MaintenanceReport,
    /// The site map (the largest graph) alone: counts and mapped area.
    site: Option<SiteMap>,
    /// Graphs in the atlas.
    graphs: usize,
}

/// The site map's size.
#[derive(Serialize)]
struct SiteMap {
    nodes: usize,
    edges: usize,
    keyframes: usize,
    local_maps: usize,
    mapped_area_m2: f64,
}

impl SiteMap {
    fn of(atlas: &mapmerge_atlas::AtlasSnapshot) -> Option<Self> {
        let graph = atlas.site_graph()?;
        let holds = |node: &NodeId| graph.contains_vertex(*node);
        Some(Self {
            nodes: graph.num_vertices(),
            edges: graph.num_edges(),
            keyframes: atlas.keyframes.keys().filter(|n| holds(n)).count(),
            local_maps: atlas.local_maps.keys().filter(|n| holds(n)).count(),
            mapped_area_m2: atlas.graph_area_m2(graph, 0.05),
        })
    }
}

/// Merge edges are judged true within this (m, rad).
const TRUE_WITHIN: (f64, f64) = (0.5, 0.1745);
/// A wrong merge must be undone within this much travel (m) (issue target).
const UNDO_WITHIN_M: f64 = 10.0;
/// An epoch revisits where its true path passes within this of an earlier epoch's (m): a
/// 360° scan there sees the same place …
const REVISIT_RADIUS_M: f64 = 1.5;
/// … and counts as revisiting with at least this much such travel (m): the full merge
/// criteria need 5 observations over views 2 m apart, about 5 m of travel.
const REVISIT_MIN_M: f64 = 5.0;

fn load_sessions(args: &AtlasArgs) -> anyhow::Result<Vec<Session>> {
    if let Some(preset) = &args.sim {
        let mut params = SimParams::default()
            .with_preset_name(preset)
            .map_err(bad_input)?;
        params.sessions = args.sessions;
        params.duration_secs = args.duration;
        if let Some(index) = args.session_index {
            let s = simulate_session_alone(&params, args.seed, index).map_err(bad_input)?;
            return Ok(vec![Session {
                name: format!("{preset} session {index}"),
                kidnaps: s.kidnaps.iter().map(|k| k.scan_index).collect(),
                truth: Some(s.truth.iter().map(|(_, pose)| *pose).collect()),
                log: s.log,
            }]);
        }
        let dataset = simulate(&params, args.seed).map_err(bad_input)?;
        return Ok(dataset
            .sessions
            .into_iter()
            .map(|s| Session {
                name: format!("{preset} session {}", s.index),
                kidnaps: s.kidnaps.iter().map(|k| k.scan_index).collect(),
                truth: Some(s.truth.iter().map(|(_, pose)| *pose).collect()),
                log: s.log,
            })
            .collect());
    }
    if args.logs.is_empty() {
        return Err(bad_input("give one or more logs, or --sim PRESET"));
    }
    let mut sessions = Vec::new();
    let mut offset = 0;
    for path in &args.logs {
        let log = crate::read_log(path, &args.topics)?;
        let n = log.scans.len();
        let kidnaps = args
            .kidnap_at
            .iter()
            .filter(|&&k| k > offset && k < offset + n)
            .map(|&k| k - offset)
            .collect();
        offset += n;
        let truth = args.judge_with_log_poses.then(|| {
            let mut previous = Se2::identity();
            log.scans
                .iter()
                .map(|s| {
                    previous = s.odom_from_robot.unwrap_or(previous);
                    previous
                })
                .collect()
        });
        sessions.push(Session {
            name: path.display().to_string(),
            log,
            kidnaps,
            truth,
        });
    }
    if let Some(k) = args.kidnap_at.iter().find(|&&k| k >= offset) {
        return Err(bad_input(format!(
            "--kidnap-at {k} is beyond the {offset} scans of the logs"
        )));
    }
    Ok(sessions)
}

/// Runs `mapmerge atlas`.
pub fn run(args: &AtlasArgs) -> anyhow::Result<ExitCode> {
    let started = Instant::now();
    let mut params: EngineParams = crate::read_config(args.config.as_deref())?;
    if args.no_prune {
        params.atlas.maintenance.prune = false;
    }
    // The store first: a refused store stops the run before any work.
    let opened = Instant::now();
    let mut store = match &args.store {
        Some(path) => {
            let mut store = mapmerge_jobs::open_or_create_store(path).map_err(job_error)?;
            store.keep_versions(args.keep_versions);
            Some(store)
        }
        None => None,
    };
    let stored = match &store {
        Some(store) => match store.load(None) {
            Ok(stored) => stored,
            // Versions written by schema 1 hold no atlas: the lifelong atlas starts now.
            Err(mapmerge_store::StoreError::NoAtlas { .. }) => None,
            Err(e) => return Err(bad_file(e)),
        },
        None => None,
    };
    let resumed_from = stored.as_ref().map(|s| s.version);
    // The reference pose of every keyframe (simulation: ground truth; logs: their poses).
    let (mut engine, mut truth_of_node) = match stored {
        Some(stored) => (
            Engine::resume(params, stored.atlas).map_err(bad_file)?,
            stored.reference_poses,
        ),
        None => (Engine::new(params).map_err(bad_input)?, BTreeMap::new()),
    };
    let open_secs = opened.elapsed().as_secs_f64();
    let sessions = load_sessions(args)?;
    let mut committed = Vec::new();
    let pictures_dir = args.output.join("pictures");
    std::fs::create_dir_all(&pictures_dir)
        .with_context(|| format!("creating {}", pictures_dir.display()))?;
    let total: usize = sessions.iter().map(|s| s.log.scans.len()).sum();
    let visible = !args.json && std::io::IsTerminal::is_terminal(&std::io::stderr());
    let bar = crate::progress_bar(total, "scans", "", visible);
    let mut pictures = Vec::new();
    let mut picture_count = 0usize;
    // Every scan's true position (a fresh run with the truth of every session only), cut
    // into epochs afterwards where the engine's events say they started.
    let mut true_positions: Option<Vec<Vector2<f64>>> =
        (resumed_from.is_none() && sessions.iter().all(|s| s.truth.is_some())).then(Vec::new);
    for (s, session) in sessions.iter().enumerate() {
        bar.set_message(session.name.clone());
        let events_before = engine.events().len();
        let first_node = engine.atlas().next_node_id();
        // A restart ends the epoch, unless the last session ended it (`--store`).
        if (s > 0 || resumed_from.is_some()) && engine.atlas().active().num_vertices() > 0 {
            engine.end_epoch(EpochEndReason::Restart)?;
        }
        let mut previous_odometry = None;
        for (k, record) in session.log.scans.iter().enumerate() {
            bar.inc(1);
            if session.kidnaps.contains(&k) {
                engine.end_epoch(EpochEndReason::Kidnap)?;
            }
            if let (Some(positions), Some(truth)) = (
                true_positions.as_mut(),
                session.truth.as_ref().and_then(|t| t.get(k)),
            ) {
                positions.push(truth.translation());
            }
            let odometry = record
                .odom_from_robot
                .or(previous_odometry)
                .unwrap_or_else(Se2::identity);
            previous_odometry = Some(odometry);
            let report = engine
                .add_scan(&odometry, &record.scan, Some(record.stamp_secs))
                .map_err(|e| anyhow::anyhow!("{}: scan {k}: {e}", session.name))?;
            if let (Some(node), Some(truth)) = (
                report.keyframe,
                session.truth.as_ref().and_then(|t| t.get(k)),
            ) {
                truth_of_node.insert(node, *truth);
            }
            let fresh: Vec<&'static str> = report
                .events
                .iter()
                .filter_map(|e| match &e.event {
                    EventKind::Atlas(AtlasEvent::Merged(_)) => Some("merge"),
                    EventKind::Atlas(AtlasEvent::Unmerged(_)) => Some("unmerge"),
                    EventKind::Decision(Decision::ConditionalMerge { .. }) => Some("conditional"),
                    _ => None,
                })
                .collect();
            if args.no_pictures {
                continue;
            }
            for kind in fresh {
                let stem = format!("{picture_count:03}-{kind}");
                picture_count += 1;
                if let Some(before) = engine.before_last_change() {
                    let path = pictures_dir.join(format!("{stem}-before.png"));
                    draw_graph(before, &engine, &[], &path).map_err(job_error)?;
                    pictures.push(path);
                }
                let path = pictures_dir.join(format!("{stem}-after.png"));
                draw_graph(
                    engine.map_graph(),
                    &engine,
                    &engine.conditional_edges(),
                    &path,
                )
                .map_err(job_error)?;
                pictures.push(path);
            }
        }
        if let Some(store) = store.as_mut() {
            committed.push(commit_session(
                store,
                &mut engine,
                &session.name,
                events_before,
                first_node,
                &truth_of_node,
            )?);
        }
    }
    bar.finish_and_clear();
    // Events.
    let events_path = args.output.join("events.jsonl");
    let mut out = std::io::BufWriter::new(
        std::fs::File::create(&events_path)
            .with_context(|| format!("creating {}", events_path.display()))?,
    );
    for event in engine.events() {
        serde_json::to_writer(&mut out, event)?;
        writeln!(out)?;
    }
    out.flush()?;
    write_atlas(&engine, &args.output.join("atlas")).map_err(job_error)?;
    let (merges, unmerges) = summarise(&engine, &truth_of_node);
    if let Some(path) = &args.merge_results {
        write_merge_results(args, &merges, path)?;
    }
    let judged = !truth_of_node.is_empty();
    let wrong: Vec<&MergeReport> = merges.iter().filter(|m| m.correct == Some(false)).collect();
    let correct: Vec<&MergeReport> = merges.iter().filter(|m| m.correct == Some(true)).collect();
    let epochs = engine
        .events()
        .iter()
        .filter(|e| matches!(e.atlas(), Some(AtlasEvent::EpochStarted { .. })))
        .count();
    let kept_correct: BTreeSet<u32> = correct
        .iter()
        .filter(|m| m.state == MergeState::Full)
        .map(|m| m.epoch)
        .collect();
    // Epochs after the first: how far each travelled where an earlier epoch had been.
    let epoch_revisits: Option<Vec<EpochRevisit>> = true_positions
        .filter(|positions| judged && positions.len() == engine.scans())
        .map(|positions| {
            // An epoch's scans: from the scan count at its start to the next one's.
            let mut starts: Vec<usize> = engine
                .events()
                .iter()
                .filter(|e| matches!(e.atlas(), Some(AtlasEvent::EpochStarted { .. })))
                .map(|e| e.scan.min(positions.len()))
                .collect();
            starts.push(positions.len());
            starts
                .windows(2)
                .map(|w| positions.get(w[0]..w[1]).unwrap_or_default().to_vec())
                .collect::<Vec<_>>()
        })
        .filter(|paths| paths.len() == epochs)
        .map(|paths| {
            let revisit_m = mapmerge_eval::revisit_travel_m(&paths, REVISIT_RADIUS_M);
            (1..paths.len())
                .map(|e| EpochRevisit {
                    epoch: e,
                    travel_m: paths[e].windows(2).map(|w| (w[1] - w[0]).norm()).sum(),
                    revisit_travel_m: revisit_m[e],
                    merged_correctly: u32::try_from(e).is_ok_and(|e| kept_correct.contains(&e)),
                })
                .collect()
        });
    let revisiting = |e: &&EpochRevisit| e.revisit_travel_m >= REVISIT_MIN_M;
    let seconds = started.elapsed().as_secs_f64();
    let threshold = engine.params().decisions.self_similar_from_score;
    let view_scores = mapmerge_engine::view_self_similarity(engine.events());
    let report = Report {
        epochs_revisiting: epoch_revisits
            .as_ref()
            .map(|r| r.iter().filter(revisiting).count()),
        epochs_revisiting_merged_correctly: epoch_revisits.as_ref().map(|r| {
            r.iter()
                .filter(revisiting)
                .filter(|e| e.merged_correctly)
                .count()
        }),
        epoch_revisits,
        sessions: sessions.len(),
        scans: engine.scans(),
        epochs,
        wrong_merges: judged.then_some(wrong.len()),
        wrong_undone_within_10m: judged.then(|| {
            wrong
                .iter()
                .filter(|m| m.undone_after_m.is_some_and(|d| d <= UNDO_WITHIN_M))
                .count()
        }),
        correct_merges: judged.then_some(correct.len()),
        correct_undone: judged.then(|| {
            correct
                .iter()
                .filter(|m| m.state == MergeState::Undone)
                .count()
        }),
        correct_rejected: judged.then(|| {
            correct
                .iter()
                .filter(|m| m.state == MergeState::Rejected)
                .count()
        }),
        epochs_merged_correctly: judged.then_some(kept_correct.len()),
        epochs_with_a_map: if resumed_from.is_some() {
            epochs
        } else {
            epochs.saturating_sub(1)
        },
        hypotheses: mapmerge_engine::hypothesis_summary(engine.events()),
        epoch_outcomes: mapmerge_engine::epoch_outcomes(engine.events(), engine.travel_m()),
        ambiguous_keyframes: mapmerge_engine::ambiguous_views(engine.events()).len(),
        self_similarity: SelfSimilarityReport {
            views: view_scores.len(),
            self_similar: fitting_elsewhere(view_scores.values(), threshold),
            joint_searched: engine.joint_self_similarity().len(),
            joint_unique: engine.joint_self_similarity().len()
                - fitting_elsewhere(engine.joint_self_similarity().values(), threshold),
            seconds: engine.self_similarity_seconds(),
        },
        tracker: engine.tracker_info(),
        constraints: engine.atlas().constraint_info(),
        merges,
        unmerges,
        pictures,
        events: events_path,
        store: args.store.as_ref().map(|path| StoreRunReport {
            path: path.clone(),
            resumed_from,
            open_secs,
            committed,
        }),
        seconds,
        ms_per_scan: 1e3 * seconds / engine.scans().max(1) as f64,
    };
    if args.json {
        print_json(&report)?;
    } else {
        print_text(&report);
    }
    Ok(ExitCode::SUCCESS)
}

fn print_text(report: &Report) {
    println!(
        "{} sessions, {} scans, {} epochs; {} merge decisions, {} unmerges in {:.1} s",
        report.sessions,
        report.scans,
        report.epochs,
        report.merges.len(),
        report.unmerges.len(),
        report.seconds
    );
    for m in &report.merges {
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
    for u in &report.unmerges {
        println!(
            "  unmerge at scan {} ({:.0} m): merges {:?} undone because {}",
            u.scan, u.travel_m, u.merges, u.reason
        );
    }
    let h = &report.hypotheses;
    println!(
        "  hypotheses: {} ({} merge, {} recovery), {} conditional, {} full, {} conditional rejected, {} expired; {} ambiguous keyframes ({} of {} views searched fit themselves elsewhere; {} of {} joint sets of them fit nowhere else)",
        h.created, h.merge, h.recovery, h.conditional, h.full, h.rejected_conditional, h.expired,
        report.ambiguous_keyframes, report.self_similarity.self_similar, report.self_similarity.views,
        report.self_similarity.joint_unique, report.self_similarity.joint_searched
    );
    // The first epoch has nothing to merge into unless the run continued a stored atlas.
    let skip = usize::from(report.epochs_with_a_map < report.epochs);
    for o in report.epoch_outcomes.iter().skip(skip) {
        println!(
            "  epoch {}: {:.0} m; merge hypotheses {} (most observations {}, weighted {:.1}), conditional {}, merged {}, undone {}: {}",
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
        report.wrong_merges,
        report.wrong_undone_within_10m,
        report.correct_merges,
        report.correct_undone,
        report.correct_rejected,
        report.epochs_merged_correctly,
    ) {
        println!(
            "  against the ground truth: {u} of {w} wrong merges rejected or undone within {UNDO_WITHIN_M} m; {cu} of {c} correct merges undone, {cr} rejected; {e} of {} later epochs end merged correctly",
            report.epochs_with_a_map
        );
    }
    if let (Some(r), Some(m)) = (
        report.epochs_revisiting,
        report.epochs_revisiting_merged_correctly,
    ) {
        println!(
            "  {m} of the {r} later epochs that travelled {REVISIT_MIN_M} m or more within {REVISIT_RADIUS_M} m of an earlier epoch's path end merged correctly"
        );
    }
    if let Some(store) = &report.store {
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
    if let Some(first) = report.pictures.first() {
        println!(
            "  pictures: {} ({} files); events: {}",
            first.parent().unwrap_or(first).display(),
            report.pictures.len(),
            report.events.display()
        );
    } else {
        println!("  events: {}", report.events.display());
    }
}

/// Merges from the engine's merge log, unmerges from the events; merges judged by their
/// edges when the truth is known.
fn summarise(
    engine: &Engine,
    truth_of_node: &BTreeMap<NodeId, Se2>,
) -> (Vec<MergeReport>, Vec<UnmergeReport>) {
    let mut merges: Vec<MergeReport> = Vec::new();
    for record in engine.merge_log() {
        let merged = engine.events().iter().find_map(|e| match e.atlas() {
            Some(AtlasEvent::Merged(m)) if Some(m.merge.0) == record.merge => Some(m),
            _ => None,
        });
        let scan = record
            .conditional_at_scan
            .or(record.full_at_scan)
            .unwrap_or_default();
        let travel_m = record
            .conditional_travel_m
            .or(record.full_travel_m)
            .unwrap_or_default();
        // A full merge kept becomes final when its epoch ends.
        let final_after_m = (record.state == MergeState::Full)
            .then(|| {
                engine.events().iter().find_map(|e| match e.atlas() {
                    Some(AtlasEvent::EpochEnded { epoch, .. }) if epoch.0 == record.epoch => {
                        Some(e.travel_m - record.full_travel_m.unwrap_or(travel_m))
                    }
                    _ => None,
                })
            })
            .flatten();
        let judged = judge(truth_of_node, &record.edges);
        merges.push(MergeReport {
            merge: record.merge,
            hypothesis: record.hypothesis,
            scan,
            travel_m,
            epoch: record.epoch,
            map: record.map,
            epochs: merged
                .map(|m| m.merged_epochs.iter().map(|x| x.0).collect())
                .unwrap_or_default(),
            loop_edges: merged.map_or(record.edges.len(), |m| m.loop_edges),
            overlap_edges: merged.map_or(0, |m| m.overlap_edges),
            state: record.state,
            conditional_at_scan: record.conditional_at_scan,
            full_at_scan: record.full_at_scan,
            full_after_m: record.full_after_m(),
            reason: record.reason.clone(),
            correct: judged.map(|(correct, _)| correct),
            error_m_deg: judged.map(|(_, error)| error),
            undone_at_scan: record.ended_at_scan,
            undone_after_m: record.ended_after_m(),
            final_after_m,
            readings: record.readings.clone(),
        });
    }
    let unmerges = engine
        .events()
        .iter()
        .filter_map(|e| match e.atlas() {
            Some(AtlasEvent::Unmerged(u)) => Some(UnmergeReport {
                scan: e.scan,
                travel_m: e.travel_m,
                merges: u.merges.iter().map(|m| m.0).collect(),
                reason: match &u.reason {
                    mapmerge_atlas::UnmergeReason::InvalidMerge {
                        detector,
                        invalidity,
                    } => format!("{detector} invalidity {invalidity:.2}"),
                    mapmerge_atlas::UnmergeReason::Requested { note } => note.clone(),
                },
            }),
            _ => None,
        })
        .collect();
    (merges, unmerges)
}

/// `--merge-results`: one `eval invalid-merge` result per judged merge and method.
fn write_merge_results(
    args: &AtlasArgs,
    merges: &[MergeReport],
    path: &Path,
) -> anyhow::Result<()> {
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
    let run = args
        .output
        .file_name()
        .map_or_else(|| "atlas".into(), |n| n.to_string_lossy().into_owned());
    let mut out = std::io::BufWriter::new(
        std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?,
    );
    for (k, merge) in merges.iter().enumerate() {
        let Some(correct) = merge.correct else {
            continue;
        };
        for reading in &merge.readings {
            let result = MergeResult {
                id: format!("{group}/{run}/merge{k}"),
                method: reading.method.clone(),
                max_invalidity: reading.peak_ratio,
                ms_per_vertex: None,
                vertices: reading.vertices,
                label: Some(if correct {
                    Label::Valid
                } else {
                    Label::Invalid
                }),
                kind: "engine".into(),
                log: group.clone(),
                supported_vertices: Some(reading.supported_vertices),
            };
            serde_json::to_writer(&mut out, &result)?;
            writeln!(out)?;
        }
    }
    out.flush()
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// Ends the session ([`Engine::end_session`]: its epoch ends, the atlas is maintained) and
/// commits it: the atlas, the session's events and the reference poses.
fn commit_session(
    store: &mut mapmerge_store::Store,
    engine: &mut Engine,
    session: &str,
    events_before: usize,
    first_node: NodeId,
    truth_of_node: &BTreeMap<NodeId, Se2>,
) -> anyhow::Result<CommittedSession> {
    let started = Instant::now();
    engine.finish()?;
    // Accuracy as mapped, before maintenance thins the graph.
    let active = engine.atlas().active();
    let session_nodes: Vec<NodeId> = active
        .vertices()
        .map(|(n, _)| n)
        .filter(|n| *n >= first_node)
        .collect();
    let all_nodes: Vec<NodeId> = active.vertices().map(|(n, _)| n).collect();
    let session_ate_m = ate_of(active, &session_nodes, truth_of_node);
    let map_ate_m = ate_of(active, &all_nodes, truth_of_node);
    let maintenance = engine.end_session(first_node)?;
    let atlas = engine.atlas().snapshot()?;
    let events = engine
        .events()
        .get(events_before..)
        .unwrap_or_default()
        .iter()
        .map(serde_json::to_string)
        .collect::<Result<Vec<_>, _>>()?;
    let version = store
        .commit_session(&mapmerge_store::SessionCommit {
            session,
            atlas: &atlas,
            events: &events,
            reference_poses: truth_of_node,
        })
        .map_err(bad_file)?;
    let commit_secs = started.elapsed().as_secs_f64();
    let version = store
        .versions()
        .map_err(bad_file)?
        .into_iter()
        .find(|v| v.version == version)
        .ok_or_else(|| anyhow::anyhow!("version {version} was committed but is not listed"))?;
    Ok(CommittedSession {
        version,
        commit_secs,
        session_ate_m,
        map_ate_m,
        maintenance,
        site: SiteMap::of(&atlas),
        graphs: atlas.graphs().filter(|g| g.num_vertices() > 0).count(),
    })
}

/// ATE (m, RMS after rigid alignment) of `nodes` of `graph` that have a reference pose; none
/// with fewer than three.
fn ate_of(
    graph: &PoseGraph2,
    nodes: &[NodeId],
    truth_of_node: &BTreeMap<NodeId, Se2>,
) -> Option<f64> {
    let (reference, estimate): (Vec<Se2>, Vec<Se2>) = nodes
        .iter()
        .filter_map(|n| Some((*truth_of_node.get(n)?, graph.vertex(*n)?.pose)))
        .unzip();
    if reference.len() < 3 {
        return None;
    }
    mapmerge_eval::absolute_trajectory_error(&reference, &estimate, true)
        .ok()
        .map(|e| e.rms_m)
}

/// A merge is correct when most of its merge edges (recorded by the engine when it decided,
/// since an undo removes them) are within `TRUE_WITHIN` of the ground truth; `None` without
/// a truth. Also returns the median edge's error against the truth `[m, deg]` (the edge with
/// the median translation error).
fn judge(
    truth_of_node: &BTreeMap<NodeId, Se2>,
    edges: &[(NodeId, NodeId, Se2)],
) -> Option<(bool, [f64; 2])> {
    let truth_of = |node: NodeId| truth_of_node.get(&node).copied();
    let mut errors: Vec<(f64, f64)> = edges
        .iter()
        .filter_map(|(from, to, measurement)| {
            let (a, b) = (truth_of(*from)?, truth_of(*to)?);
            let error = a.between(&b).between(measurement);
            Some((error.translation().norm(), error.theta_rad.abs()))
        })
        .collect();
    if errors.is_empty() {
        return None;
    }
    let good = errors
        .iter()
        .filter(|(m, rad)| *m <= TRUE_WITHIN.0 && *rad <= TRUE_WITHIN.1)
        .count();
    errors.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (median_m, median_rad) = errors[errors.len() / 2];
    Some((2 * good > errors.len(), [median_m, median_rad.to_degrees()]))
}
