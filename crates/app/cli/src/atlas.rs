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

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use mapmerge_atlas::{AtlasEvent, EpochEndReason};
use mapmerge_engine::{Engine, EngineParams};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{GridGeometry, Point2};
use mapmerge_io::{AnyGraph, GraphFormat};
use mapmerge_posegraph::{EdgeKind, NodeId, PoseGraph2};
use mapmerge_render::{session_color, Picture, Rgb};
use mapmerge_scan::LaserLog;
use mapmerge_sim::{simulate, SimParams};
use mapmerge_verify::{
    ChangeDetectionDetector, DetectorScan, InvalidMergeDetector, MergedMap, PointClass,
};
use serde::Serialize;

use crate::{bad_file, bad_input, print_json};

/// Arguments of `mapmerge atlas`.
#[derive(Args, Debug)]
pub struct AtlasArgs {
    /// CARMEN logs, one per session, in order (`.xz` accepted).
    pub logs: Vec<PathBuf>,
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
    /// Engine parameters (JSON, `mapmerge_engine::EngineParams`; absent fields keep their
    /// defaults).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Skip the pictures (faster).
    #[arg(long)]
    pub no_pictures: bool,
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

/// A merge as reported.
#[derive(Clone, Debug, Serialize)]
struct MergeReport {
    merge: u64,
    scan: usize,
    travel_m: f64,
    map: u32,
    epochs: Vec<u32>,
    loop_edges: usize,
    overlap_edges: usize,
    /// Judged by the merge edges against the ground truth (simulation): `true` when most are
    /// within 0.5 m and 10° of the truth.
    correct: Option<bool>,
    /// When it was undone: scan, and robot travel from the merge to the undo (m).
    undone_at_scan: Option<usize>,
    undone_after_m: Option<f64>,
    /// When its epoch ended first (the merge became final): travel after the merge (m).
    final_after_m: Option<f64>,
}

#[derive(Clone, Debug, Serialize)]
struct UnmergeReport {
    scan: usize,
    travel_m: f64,
    merges: Vec<u64>,
    reason: String,
}

#[derive(Serialize)]
struct Report {
    sessions: usize,
    scans: usize,
    epochs: usize,
    merges: Vec<MergeReport>,
    unmerges: Vec<UnmergeReport>,
    /// Simulation: wrong merges, those undone within 10 m of travel, correct ones undone.
    wrong_merges: Option<usize>,
    wrong_undone_within_10m: Option<usize>,
    correct_merges: Option<usize>,
    correct_undone: Option<usize>,
    pictures: Vec<PathBuf>,
    events: PathBuf,
    seconds: f64,
}

/// Merge edges are judged true within this (m, rad).
const TRUE_WITHIN: (f64, f64) = (0.5, 0.1745);
/// A wrong merge must be undone within this much travel (m) (issue target).
const UNDO_WITHIN_M: f64 = 10.0;

fn load_sessions(args: &AtlasArgs) -> anyhow::Result<Vec<Session>> {
    if let Some(preset) = &args.sim {
        let mut params = SimParams::default()
            .with_preset_name(preset)
            .map_err(bad_input)?;
        params.sessions = args.sessions;
        params.duration_secs = args.duration;
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
        let log = mapmerge_io::read_carmen(path).map_err(bad_file)?;
        let n = log.scans.len();
        let kidnaps = args
            .kidnap_at
            .iter()
            .filter(|&&k| k > offset && k < offset + n)
            .map(|&k| k - offset)
            .collect();
        offset += n;
        sessions.push(Session {
            name: path.display().to_string(),
            log,
            kidnaps,
            truth: None,
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
    let params: EngineParams = match &args.config {
        None => EngineParams::default(),
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .map_err(|e| bad_input(format!("{}: {e}", path.display())))?;
            serde_json::from_str(&text)
                .map_err(|e| bad_input(format!("{}: {e}", path.display())))?
        }
    };
    let sessions = load_sessions(args)?;
    let mut engine = Engine::new(params).map_err(bad_input)?;
    let pictures_dir = args.output.join("pictures");
    std::fs::create_dir_all(&pictures_dir)
        .with_context(|| format!("creating {}", pictures_dir.display()))?;
    let total: usize = sessions.iter().map(|s| s.log.scans.len()).sum();
    let visible = !args.json && std::io::IsTerminal::is_terminal(&std::io::stderr());
    let bar = crate::progress_bar(total, "scans", "", visible);
    // Ground truth by vertex stamp (simulation: stamps are unique across sessions).
    let mut truth_at_stamp: BTreeMap<u64, Se2> = BTreeMap::new();
    let mut pictures = Vec::new();
    let mut picture_count = 0usize;
    for (s, session) in sessions.iter().enumerate() {
        bar.set_message(session.name.clone());
        if s > 0 {
            engine.end_epoch(EpochEndReason::Restart)?;
        }
        let mut previous_odometry = None;
        for (k, record) in session.log.scans.iter().enumerate() {
            bar.inc(1);
            if session.kidnaps.contains(&k) {
                engine.end_epoch(EpochEndReason::Kidnap)?;
            }
            let odometry = record
                .odom_from_robot
                .or(previous_odometry)
                .unwrap_or_else(Se2::identity);
            previous_odometry = Some(odometry);
            if let Some(truth) = session.truth.as_ref().and_then(|t| t.get(k)) {
                truth_at_stamp.insert(record.stamp_secs.to_bits(), *truth);
            }
            let fresh: Vec<AtlasEvent> = engine
                .add_scan(&odometry, &record.scan, Some(record.stamp_secs))
                .map_err(|e| anyhow::anyhow!("{}: scan {k}: {e}", session.name))?
                .events
                .iter()
                .map(|e| e.event.clone())
                .collect();
            if args.no_pictures {
                continue;
            }
            for event in fresh {
                let kind = match event {
                    AtlasEvent::Merged(_) => "merge",
                    AtlasEvent::Unmerged(_) => "unmerge",
                    _ => continue,
                };
                let stem = format!("{picture_count:03}-{kind}");
                picture_count += 1;
                if let Some(before) = engine.before_last_change() {
                    let path = pictures_dir.join(format!("{stem}-before.png"));
                    draw_graph(before, &engine, &path)?;
                    pictures.push(path);
                }
                let path = pictures_dir.join(format!("{stem}-after.png"));
                draw_graph(engine.atlas().active(), &engine, &path)?;
                pictures.push(path);
            }
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
    write_atlas(&engine, &args.output.join("atlas"))?;
    let (merges, unmerges) = summarise(&engine, &truth_at_stamp);
    let judged = args.sim.is_some();
    let wrong: Vec<&MergeReport> = merges.iter().filter(|m| m.correct == Some(false)).collect();
    let correct: Vec<&MergeReport> = merges.iter().filter(|m| m.correct == Some(true)).collect();
    let report = Report {
        sessions: sessions.len(),
        scans: engine.scans(),
        epochs: engine
            .events()
            .iter()
            .filter(|e| matches!(e.event, AtlasEvent::EpochStarted { .. }))
            .count(),
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
                .filter(|m| m.undone_at_scan.is_some())
                .count()
        }),
        merges,
        unmerges,
        pictures,
        events: events_path,
        seconds: started.elapsed().as_secs_f64(),
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
        "{} sessions, {} scans, {} epochs; {} merges, {} unmerges in {:.1} s",
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
        let fate = match (m.undone_after_m, m.final_after_m) {
            (Some(d), _) => format!("undone after {d:.1} m"),
            (None, Some(d)) => format!("kept; final when its epoch ended {d:.1} m later"),
            (None, None) => "kept".to_owned(),
        };
        println!(
            "  merge #{} at scan {} ({:.0} m): map {} (epochs {:?}) by {} loops{verdict}; {fate}",
            m.merge, m.scan, m.travel_m, m.map, m.epochs, m.loop_edges
        );
    }
    for u in &report.unmerges {
        println!(
            "  unmerge at scan {} ({:.0} m): merges {:?} undone because {}",
            u.scan, u.travel_m, u.merges, u.reason
        );
    }
    if let (Some(w), Some(u), Some(c), Some(cu)) = (
        report.wrong_merges,
        report.wrong_undone_within_10m,
        report.correct_merges,
        report.correct_undone,
    ) {
        println!(
            "  against the ground truth: {u} of {w} wrong merges undone within {UNDO_WITHIN_M} m; {cu} of {c} correct merges undone"
        );
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

/// Merges and unmerges from the events; merges judged by their merge edges when the truth is
/// known.
fn summarise(
    engine: &Engine,
    truth_at_stamp: &BTreeMap<u64, Se2>,
) -> (Vec<MergeReport>, Vec<UnmergeReport>) {
    let mut merges: Vec<MergeReport> = Vec::new();
    let mut unmerges = Vec::new();
    for e in engine.events() {
        match &e.event {
            AtlasEvent::Merged(m) => merges.push(MergeReport {
                merge: m.merge.0,
                scan: e.scan,
                travel_m: e.travel_m,
                map: m.map.0,
                epochs: m.merged_epochs.iter().map(|x| x.0).collect(),
                loop_edges: m.loop_edges,
                overlap_edges: m.overlap_edges,
                correct: None,
                undone_at_scan: None,
                undone_after_m: None,
                final_after_m: None,
            }),
            AtlasEvent::Unmerged(u) => {
                for id in &u.merges {
                    if let Some(m) = merges.iter_mut().find(|m| m.merge == id.0) {
                        m.undone_at_scan = Some(e.scan);
                        m.undone_after_m = Some(e.travel_m - m.travel_m);
                    }
                }
                unmerges.push(UnmergeReport {
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
                });
            }
            AtlasEvent::EpochEnded { .. } => {
                for m in merges
                    .iter_mut()
                    .filter(|m| m.undone_at_scan.is_none() && m.final_after_m.is_none())
                {
                    m.final_after_m = Some(e.travel_m - m.travel_m);
                }
            }
            _ => {}
        }
    }
    if !truth_at_stamp.is_empty() {
        judge_merges(engine, truth_at_stamp, &mut merges);
    }
    (merges, unmerges)
}

/// A merge is correct when most of its merge edges (recorded by the engine when it merged,
/// since an undo removes them) are within `TRUE_WITHIN` of the ground truth.
fn judge_merges(engine: &Engine, truth_at_stamp: &BTreeMap<u64, Se2>, merges: &mut [MergeReport]) {
    let atlas = engine.atlas();
    let truth_of = |node: NodeId| -> Option<Se2> {
        std::iter::once(atlas.active())
            .chain(atlas.inactive_maps().map(|(_, g)| g))
            .find_map(|g| g.vertex(node))
            .and_then(|v| v.meta.stamp_secs)
            .and_then(|stamp| truth_at_stamp.get(&stamp.to_bits()).copied())
    };
    for (m, recorded) in merges.iter_mut().zip(engine.merge_edges()) {
        let verdicts: Vec<bool> = recorded
            .iter()
            .filter_map(|(from, to, measurement)| {
                let (a, b) = (truth_of(*from)?, truth_of(*to)?);
                let error = a.between(&b).between(measurement);
                Some(
                    error.translation().norm() <= TRUE_WITHIN.0
                        && error.theta_rad.abs() <= TRUE_WITHIN.1,
                )
            })
            .collect();
        if !verdicts.is_empty() {
            let good = verdicts.iter().filter(|&&ok| ok).count();
            m.correct = Some(2 * good > verdicts.len());
        }
    }
}

/// Draws a graph's scans coloured by epoch; the newest current-epoch scans (the detector's
/// window) as larger dots.
fn draw_graph(graph: &PoseGraph2, engine: &Engine, path: &Path) -> anyhow::Result<()> {
    let scans = engine.atlas().keyframes();
    let mut points: Vec<(Point2, Rgb, bool)> = Vec::new();
    let current = engine.atlas().current_epoch().0;
    let recent: Vec<NodeId> = graph
        .vertices()
        .filter(|(_, v)| v.meta.session.0 == current)
        .map(|(id, _)| id)
        .collect();
    let window: Vec<NodeId> = recent.iter().rev().take(10).copied().collect();
    let classes = window_classes(graph, engine);
    for (id, vertex) in graph.vertices() {
        let Some(scan) = scans.get(id) else {
            continue;
        };
        let colour = epoch_colour(vertex.meta.session.0);
        let highlight = window.contains(&id);
        let classes_of_scan = classes.get(&id);
        for (k, p) in scan.iter().enumerate() {
            // Window scans in change-detection colours (Holoch et al., Fig. 1/3): red change,
            // green agree, grey no info.
            let colour = match classes_of_scan.and_then(|c| c.get(k)) {
                Some(PointClass::Change) => Rgb([220, 30, 30]),
                Some(PointClass::Agree) => Rgb([30, 170, 60]),
                Some(PointClass::NoInfo) => Rgb([150, 150, 150]),
                None if k % 2 == 0 => colour,
                None => continue,
            };
            points.push((vertex.pose.transform_point(p), colour, highlight));
        }
    }
    let finite: Vec<&Point2> = points
        .iter()
        .map(|(p, _, _)| p)
        .filter(|p| p.x.is_finite() && p.y.is_finite())
        .collect();
    let Some(first) = finite.first() else {
        return Ok(());
    };
    let (mut min, mut max) = (**first, **first);
    for p in &finite {
        min = min.inf(p);
        max = max.sup(p);
    }
    let margin = Point2::new(1.0, 1.0);
    let resolution_m = ((max.x - min.x).max(max.y - min.y) / 1200.0).max(0.03);
    let geometry = GridGeometry {
        resolution_m,
        origin_m: min - margin,
        width: (((max.x - min.x) + 2.0) / resolution_m).ceil().min(4000.0) as usize,
        height: (((max.y - min.y) + 2.0) / resolution_m).ceil().min(4000.0) as usize,
    };
    let mut picture = Picture::blank(&geometry, 1);
    for (p, colour, highlight) in &points {
        picture.draw_disc(p, if *highlight { 1.5 } else { 0.6 }, *colour);
    }
    for (id, vertex) in graph.vertices() {
        let colour = epoch_colour(vertex.meta.session.0);
        let radius = if window.contains(&id) { 3.0 } else { 1.5 };
        picture.draw_disc(&vertex.pose.translation(), radius, colour);
    }
    for (_, edge) in graph.edges().filter(|(_, e)| e.kind == EdgeKind::Merge) {
        if let (Some(a), Some(b)) = (graph.vertex(edge.from), graph.vertex(edge.to)) {
            picture.draw_line(
                &a.pose.translation(),
                &b.pose.translation(),
                Rgb::MAGENTA,
                2.0,
            );
        }
    }
    picture.save_png(path)?;
    Ok(())
}

/// An epoch's colour: the session palette without its red and green, which mark change
/// detection's classes.
fn epoch_colour(epoch: u32) -> Rgb {
    const PALETTE: [u64; 8] = [0, 1, 4, 5, 6, 7, 8, 9];
    session_color(PALETTE[epoch as usize % PALETTE.len()])
}

/// Change detection's classes of the newest current-epoch scans against the other epochs in
/// `graph` (empty when it holds one epoch only).
fn window_classes(graph: &PoseGraph2, engine: &Engine) -> BTreeMap<NodeId, Vec<PointClass>> {
    let current = engine.atlas().current_epoch().0;
    let (mut now, mut other) = (Vec::new(), Vec::new());
    for (node, vertex) in graph.vertices() {
        let Some(points) = engine.atlas().keyframes().get(node) else {
            continue;
        };
        let scan = DetectorScan {
            node,
            epoch: vertex.meta.session.0,
            map_from_robot: vertex.pose,
            points_in_robot: std::sync::Arc::clone(points),
        };
        if vertex.meta.session.0 == current {
            now.push(scan);
        } else {
            other.push(scan);
        }
    }
    if now.is_empty() || other.is_empty() {
        return BTreeMap::new();
    }
    let map = MergedMap {
        current: &now,
        other: &other,
    };
    let mut detector = ChangeDetectionDetector::default();
    detector.on_merge(&map);
    detector.on_vertex(&map);
    detector.current_classes().into_iter().collect()
}

/// Writes every graph of the atlas as g2o with a picture.
fn write_atlas(engine: &Engine, dir: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let atlas = engine.atlas();
    let mut graphs: Vec<(String, &PoseGraph2)> = vec![("active".to_owned(), atlas.active())];
    graphs.extend(
        atlas
            .inactive_maps()
            .map(|(id, g)| (format!("inactive-{}", id.0), g)),
    );
    for (name, graph) in graphs {
        if graph.num_vertices() == 0 {
            continue;
        }
        mapmerge_io::write_graph(
            &dir.join(format!("{name}.g2o")),
            &AnyGraph::Planar(graph.clone()),
            GraphFormat::G2o,
        )?;
        draw_graph(graph, engine, &dir.join(format!("{name}.png")))?;
    }
    Ok(())
}
