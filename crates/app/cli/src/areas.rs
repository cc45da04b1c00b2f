//! `mapmerge areas` and `mapmerge route`: the map manager of Ehlers et al. on one log or one
//! simulated session (`mapmerge_areas`): door passings split it into areas, each area is
//! mapped by the SLAM pipeline with its environment's preset, and the link points at the
//! doors join the maps into a hybrid map; `route` finds the shortest route between two
//! poses in any two maps of it.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use mapmerge_areas::{manage_mapped, map_session, HybridMap, ManagerParams, MappedSession, Route};
use mapmerge_engine::{run_slam, EngineParams};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::InsertParams;
use mapmerge_place::PlaceVerifierParams;
use mapmerge_posegraph::{NodeId, PoseGraph2};
use mapmerge_render::{session_color, Picture, PictureStyle, Rgb};
use mapmerge_scan::{LaserLog, Point2};
use mapmerge_sim::{simulate, simulate_session_alone, SimParams};
use serde::Serialize;

use crate::{bad_file, bad_input, check_resolution, print_json};
use crate::{build_posed_grid as build_grid, PosedLog};

/// Arguments of `mapmerge areas`.
#[derive(Args, Debug)]
pub struct AreasArgs {
    /// CARMEN laser logs (`.xz` accepted) or ROS 2 bags, one session each, in order: their scans' odometry
    /// poses drive door detection and each area's SLAM. A later session is placed in the
    /// first one's frame once it passes a door seen before. With `--store` and no logs, the
    /// stored areas are written out.
    pub logs: Vec<PathBuf>,
    /// Topics of a ROS 2 bag.
    #[command(flatten)]
    pub topics: crate::BagTopics,
    /// Instead of logs, the sessions of a simulated world (a preset of `mapmerge sim`),
    /// without kidnaps.
    #[arg(long, conflicts_with = "logs")]
    pub sim: Option<String>,
    /// Seed of `--sim`.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Sessions of `--sim`.
    #[arg(long, default_value_t = 1)]
    pub sessions: usize,
    /// Simulate only this session of the world (its changes, route and noise as in the
    /// whole simulation): one session per run, as a robot lives with `--store`.
    #[arg(long, requires = "sim", conflicts_with = "sessions")]
    pub session_index: Option<usize>,
    /// Robot time of each `--sim` session (s).
    #[arg(long, default_value_t = 120.0)]
    pub duration: f64,
    /// Cell side of the maps (m).
    #[arg(long, default_value_t = 0.05)]
    pub resolution: f64,
    /// Map-manager parameters as JSON (any subset of `mapmerge_areas::ManagerParams`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Output folder: areas.json, hybrid.json, tracking.json, overview.png and area_K/
    /// (graph.g2o, map.yaml + map.pgm, map.png, trajectory.tum) for each area.
    #[arg(short, long)]
    pub output: PathBuf,
    /// The lifelong store (created when missing): its newest version's sessions come first,
    /// this run's sessions are added after them, and the result is committed as a new
    /// version.
    #[arg(long)]
    pub store: Option<PathBuf>,
    /// Print one JSON summary instead of text.
    #[arg(long)]
    pub json: bool,
}

/// `areas.json` (docs/formats.md): positions in the first area's frame.
#[derive(Serialize)]
struct AreasFile {
    areas: Vec<AreaEntry>,
    link_points: Vec<LinkPointEntry>,
    /// Doors seen in one area and not passed: `{"id", "area", "x", "y"}` in the first
    /// area's frame.
    link_point_candidates: Vec<CandidateEntry>,
    edges: Vec<EdgeEntry>,
    door_passings: Vec<PassingEntry>,
}

#[derive(Serialize)]
struct AreaEntry {
    id: usize,
    config: &'static str,
    /// `[session, first scan, last scan + 1]` of each stretch of scans mapped into it.
    sessions_scans: Vec<[usize; 3]>,
    dir: String,
    /// Whether its frame is placed in the first area's (false: a session never relocalised).
    placed: bool,
}

#[derive(Serialize)]
struct LinkPointEntry {
    id: usize,
    area: usize,
    areas: [usize; 2],
    x: f64,
    y: f64,
}

#[derive(Serialize)]
struct CandidateEntry {
    id: usize,
    area: usize,
    x: f64,
    y: f64,
}

#[derive(Serialize)]
struct EdgeEntry {
    from: usize,
    to: usize,
    area: usize,
    length_m: f64,
}

#[derive(Serialize)]
struct PassingEntry {
    session: usize,
    scan: usize,
    crossing_scan: usize,
    x: f64,
    y: f64,
    /// Whether it starts a new area (a passing too soon after the last one does not).
    boundary: bool,
}

#[derive(Serialize)]
struct AreasReport<'a> {
    sessions: usize,
    sessions_placed: usize,
    scans: usize,
    areas: usize,
    link_points: usize,
    door_passings: usize,
    /// Topological loop closures (a door passed again, recognised).
    closures: usize,
    /// … of them at a link-point candidate (a door seen from another area, then passed).
    candidate_closures: usize,
    /// Link-point candidates left (doors seen, not passed).
    link_point_candidates: usize,
    /// Areas by configuration.
    indoor: usize,
    large: usize,
    seconds: f64,
    output: &'a Path,
    /// With `--store`: the sessions read from it and the version committed (none when the
    /// run added no session).
    stored_sessions: usize,
    committed_version: Option<i64>,
}

/// The sessions `areas` runs on, with their names.
fn input_logs(args: &AreasArgs) -> anyhow::Result<Vec<(String, LaserLog)>> {
    match (&args.logs[..], &args.sim) {
        ([], None) if args.store.is_some() => Ok(Vec::new()),
        (logs, None) if !logs.is_empty() => logs
            .iter()
            .map(|path| {
                let log = crate::read_log(path, &args.topics)?;
                Ok((path.display().to_string(), log))
            })
            .collect(),
        ([], Some(world)) => {
            let mut params = SimParams::default()
                .with_preset_name(world)
                .map_err(bad_input)?
                .with_sessions(args.sessions)
                .with_duration_secs(args.duration);
            // The map manager tracks the robot; a kidnap is another problem (the atlas's).
            params.kidnap.max_per_session = 0;
            if let Some(index) = args.session_index {
                let session =
                    simulate_session_alone(&params, args.seed, index).map_err(bad_input)?;
                let name = format!("sim {world} seed {} session {index}", args.seed);
                return Ok(vec![(name, session.log)]);
            }
            let dataset = simulate(&params, args.seed).map_err(bad_input)?;
            Ok(dataset
                .sessions
                .into_iter()
                .enumerate()
                .map(|(k, s)| (format!("sim {world} seed {} session {k}", args.seed), s.log))
                .collect())
        }
        _ => Err(bad_input("give LOG..., --sim WORLD or --store FILE")),
    }
}

/// Runs `mapmerge areas`.
pub fn run(args: &AreasArgs) -> anyhow::Result<std::process::ExitCode> {
    check_resolution(args.resolution)?;
    let started = std::time::Instant::now();
    let params: ManagerParams = crate::read_config(args.config.as_deref())?;
    // The store first: a refused store stops the run before any work.
    let mut store = match &args.store {
        // Without sessions to add, the run only reads: a missing store is an error.
        Some(path) if args.logs.is_empty() && args.sim.is_none() => {
            Some(crate::store::open_existing(path)?)
        }
        Some(path) => Some(crate::store::open_or_create(path)?),
        None => None,
    };
    let logs = input_logs(args)?;
    let mut sessions: Vec<MappedSession> = match &store {
        Some(store) => store
            .load_areas(None)
            .map_err(bad_file)?
            .map(|stored| stored.sessions)
            .unwrap_or_default(),
        None => Vec::new(),
    };
    let stored_sessions = sessions.len();
    let added: Vec<String> = logs.iter().map(|(name, _)| name.clone()).collect();
    for (name, log) in logs {
        // Scans mapped (spans overlap at doors by a metre: the count ends a little high).
        let bar = crate::progress_bar(log.scans.len(), "scans", "areas", !args.json);
        let mut map_span = |part: &LaserLog, preset: &mapmerge_areas::Preset| {
            let engine = EngineParams {
                tracker: preset.tracker.clone(),
                ..EngineParams::default()
            };
            let run = run_slam(part, engine, |_| {}).map_err(|e| e.to_string())?;
            bar.inc(part.scans.len() as u64);
            Ok((run.trajectory, run.graph))
        };
        sessions.push(map_session(name, log, &params, &mut map_span).map_err(bad_input)?);
        bar.finish_and_clear();
    }
    if sessions.is_empty() {
        return Err(bad_input(match &args.store {
            Some(path) => format!(
                "{}: the store holds no areas; give LOG... or --sim WORLD",
                path.display()
            ),
            None => "no sessions to map".to_string(),
        }));
    }
    let verifier = PlaceVerifierParams::default()
        .verifier()
        .map_err(bad_input)?;
    let managed = manage_mapped(&sessions, &params, &verifier).map_err(bad_input)?;
    let committed_version = match store.as_mut() {
        Some(store) if !added.is_empty() => Some(
            store
                .commit_areas(&mapmerge_store::AreasCommit {
                    session: &added.join(", "),
                    sessions: &sessions,
                    map: &managed,
                })
                .map_err(bad_file)?,
        ),
        _ => None,
    };
    let hybrid = &managed.hybrid;
    // Global span index of each session's spans.
    let spans: Vec<(usize, usize)> = sessions
        .iter()
        .enumerate()
        .flat_map(|(s, m)| (0..m.segmentation.spans.len()).map(move |k| (s, k)))
        .collect();
    // One map per area from its spans, placed in the area's frame; its graph holds each
    // span's graph (vertex ids offset by 1,000,000 a span; no edges between spans).
    for area in &hybrid.areas {
        let mut part = LaserLog::default();
        let mut trajectory = Vec::new();
        let mut graph = PoseGraph2::new();
        for (g, (s, k)) in spans.iter().enumerate() {
            if managed.span_area.get(g) != Some(&area.id) {
                continue;
            }
            let m = &sessions[*s];
            let span = &m.segmentation.spans[*k];
            let Some(area_from_span) = managed.area_from_span(g) else {
                continue;
            };
            part.scans
                .extend_from_slice(m.log.scans.get(span.scans.clone()).unwrap_or(&[]));
            trajectory.extend(m.trajectories[*k].iter().map(|p| area_from_span.compose(p)));
            let offset = 1_000_000 * g as u64;
            for (id, vertex) in m.graphs[*k].vertices() {
                let mut moved = *vertex;
                moved.pose = area_from_span.compose(&vertex.pose);
                graph.add_vertex(NodeId(id.0 + offset), moved)?;
            }
            for (_, edge) in m.graphs[*k].edges() {
                let mut moved = *edge;
                moved.from = NodeId(edge.from.0 + offset);
                moved.to = NodeId(edge.to.0 + offset);
                if moved.is_prior() {
                    moved.measurement = area_from_span.compose(&edge.measurement);
                }
                graph.add_edge(moved)?;
            }
        }
        mapmerge_jobs::write_slam_outputs(
            &args.output.join(format!("area_{}", area.id)),
            &part,
            &trajectory,
            &graph,
            args.resolution,
            || {},
        )
        .map_err(crate::job_error)?;
    }
    // Every scan's pose in the first area's frame (an overlap scan by its earlier span), for
    // placed sessions.
    let mut first_from_robot: Vec<Vec<Option<Se2>>> = sessions
        .iter()
        .map(|m| vec![None; m.log.scans.len()])
        .collect();
    for (g, (s, k)) in spans.iter().enumerate() {
        if !managed.session_placed.get(*s).copied().unwrap_or(false) {
            continue;
        }
        let m = &sessions[*s];
        for (scan, pose) in m.segmentation.spans[*k]
            .scans
            .clone()
            .zip(&m.trajectories[*k])
        {
            if let Some(slot) = first_from_robot[*s].get_mut(scan) {
                slot.get_or_insert(managed.first_from_span[g].compose(pose));
            }
        }
    }
    let mut door_passings = Vec::new();
    for (s, m) in sessions.iter().enumerate() {
        for (i, passing) in m.segmentation.passings.iter().enumerate() {
            let is_boundary = m.segmentation.boundaries.contains(&i);
            let placed = first_from_robot[s].get(passing.scan).copied().flatten();
            if let Some(robot) = placed {
                let center = robot.transform_point(&passing.center_in_robot_m);
                door_passings.push(PassingEntry {
                    session: s,
                    scan: passing.scan,
                    crossing_scan: passing.crossing_scan,
                    x: center.x,
                    y: center.y,
                    boundary: is_boundary,
                });
            }
        }
    }
    let link_points: Vec<LinkPointEntry> = hybrid
        .link_points
        .iter()
        .filter_map(|link| {
            let p = link_in_first_frame(hybrid, link.id)?;
            Some(LinkPointEntry {
                id: link.id,
                area: link.areas[0],
                areas: link.areas,
                x: p.x,
                y: p.y,
            })
        })
        .collect();
    let area_sessions = |area: usize| -> Vec<[usize; 3]> {
        spans
            .iter()
            .enumerate()
            .filter(|(g, _)| managed.span_area.get(*g) == Some(&area))
            .map(|(_, (s, k))| {
                let span = &sessions[*s].segmentation.spans[*k];
                [*s, span.scans.start, span.scans.end]
            })
            .collect()
    };
    let file = AreasFile {
        areas: hybrid
            .areas
            .iter()
            .map(|area| {
                let sessions_scans = area_sessions(area.id);
                let placed = sessions_scans
                    .first()
                    .and_then(|[s, _, _]| managed.session_placed.get(*s).copied())
                    .unwrap_or(false);
                AreaEntry {
                    id: area.id,
                    config: area.environment.name(),
                    sessions_scans,
                    dir: format!("area_{}", area.id),
                    placed,
                }
            })
            .collect(),
        link_points,
        link_point_candidates: hybrid
            .candidates
            .iter()
            .filter_map(|c| {
                let area = hybrid.areas.get(c.area)?;
                let p = area.first_from_area.compose(&c.pose).translation();
                Some(CandidateEntry {
                    id: c.id,
                    area: c.area,
                    x: p.x,
                    y: p.y,
                })
            })
            .collect(),
        edges: hybrid
            .edges
            .iter()
            .map(|e| EdgeEntry {
                from: e.from,
                to: e.to,
                area: e.area,
                length_m: e.length_m,
            })
            .collect(),
        door_passings,
    };
    write_json(&args.output.join("areas.json"), &file)?;
    write_json(&args.output.join("hybrid.json"), hybrid)?;
    write_json(
        &args.output.join("tracking.json"),
        &serde_json::json!({
            "closures": managed.closures,
            "candidate_closures": managed.candidate_closures,
            "tracking": managed.tracking,
            "sessions_placed": managed.session_placed,
        }),
    )?;
    // The overview: every placed session's scans in the first area's frame.
    let mut all = LaserLog::default();
    let mut poses = Vec::new();
    let mut paths: Vec<Vec<Se2>> = vec![Vec::new(); hybrid.areas.len()];
    for (g, (s, k)) in spans.iter().enumerate() {
        let m = &sessions[*s];
        let range = m.segmentation.spans[*k].scans.clone();
        let placed: Vec<(usize, Se2)> = range
            .filter_map(|scan| Some((scan, first_from_robot[*s].get(scan).copied().flatten()?)))
            .collect();
        if let Some(path) = managed.span_area.get(g).and_then(|a| paths.get_mut(*a)) {
            path.extend(placed.iter().map(|(_, p)| *p));
        }
    }
    for (s, m) in sessions.iter().enumerate() {
        for (record, pose) in m.log.scans.iter().zip(&first_from_robot[s]) {
            if let Some(pose) = pose {
                all.scans.push(record.clone());
                poses.push(*pose);
            }
        }
    }
    let scan_count: usize = sessions.iter().map(|m| m.log.scans.len()).sum();
    let posed = PosedLog { log: all, poses };
    overview(
        &posed,
        &paths,
        hybrid,
        args.resolution,
        &args.output.join("overview.png"),
    )?;
    let passings: usize = sessions.iter().map(|m| m.segmentation.passings.len()).sum();
    let report = AreasReport {
        sessions: sessions.len(),
        sessions_placed: managed.session_placed.iter().filter(|p| **p).count(),
        scans: scan_count,
        areas: hybrid.areas.len(),
        link_points: hybrid.link_points.len(),
        door_passings: passings,
        closures: managed.closures.len() + managed.candidate_closures.len(),
        candidate_closures: managed.candidate_closures.len(),
        link_point_candidates: hybrid.candidates.len(),
        indoor: file.areas.iter().filter(|a| a.config == "indoor").count(),
        large: file.areas.iter().filter(|a| a.config == "large").count(),
        seconds: started.elapsed().as_secs_f64(),
        output: &args.output,
        stored_sessions,
        committed_version,
    };
    if args.json {
        print_json(&report)?;
    } else {
        println!(
            "{} sessions ({} placed), {} scans: {} door passings, {} topological loop closures, {} areas ({} indoor, {} large), {} link points; wrote {} in {:.1} s",
            report.sessions,
            report.sessions_placed,
            report.scans,
            report.door_passings,
            report.closures,
            report.areas,
            report.indoor,
            report.large,
            report.link_points,
            args.output.display(),
            report.seconds
        );
        if let Some(path) = &args.store {
            match committed_version {
                Some(version) => println!(
                    "store {}: {stored_sessions} sessions continued, committed version {version}",
                    path.display()
                ),
                None => println!(
                    "store {}: {stored_sessions} sessions written out, nothing committed",
                    path.display()
                ),
            }
        }
    }
    Ok(std::process::ExitCode::SUCCESS)
}

/// A link point's position in the first area's frame.
fn link_in_first_frame(hybrid: &HybridMap, id: usize) -> Option<Point2> {
    let link = hybrid.link_points.get(id)?;
    let area = hybrid.areas.get(link.areas[0])?;
    Some(area.first_from_area.compose(&link.poses[0]).translation())
}

fn write_json(path: &Path, value: &impl Serialize) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(value)?;
    std::fs::write(path, text + "\n").with_context(|| format!("writing {}", path.display()))
}

/// The overview: the whole map in the first area's frame, each area's path in its colour, the
/// link points and the topological graph over it.
fn overview(
    posed: &PosedLog,
    paths: &[Vec<Se2>],
    hybrid: &HybridMap,
    resolution_m: f64,
    path: &Path,
) -> anyhow::Result<()> {
    let (grid, _) = build_grid(posed, resolution_m, &InsertParams::default(), false)?;
    let style = PictureStyle {
        pixels_per_cell: 1,
        classes: Some(mapmerge_grid::ClassThresholds::default()),
    };
    let mut picture = Picture::of_grid(&grid, &style);
    for (k, poses) in paths.iter().enumerate() {
        picture.draw_trajectory(poses, session_color(k as u64), 2.0);
    }
    for edge in &hybrid.edges {
        if let (Some(a), Some(b)) = (
            link_in_first_frame(hybrid, edge.from),
            link_in_first_frame(hybrid, edge.to),
        ) {
            picture.draw_line(&a, &b, Rgb::RED, 2.0);
        }
    }
    for link in &hybrid.link_points {
        if let Some(p) = link_in_first_frame(hybrid, link.id) {
            picture.draw_disc(&p, 5.0, Rgb::RED);
        }
    }
    // Link-point candidates: orange.
    for candidate in &hybrid.candidates {
        if let Some(area) = hybrid.areas.get(candidate.area) {
            let p = area.first_from_area.compose(&candidate.pose).translation();
            picture.draw_disc(&p, 4.0, Rgb([240, 140, 0]));
        }
    }
    picture.save_png(path)?;
    Ok(())
}

/// Arguments of `mapmerge route`.
#[derive(Args, Debug)]
pub struct RouteArgs {
    /// A folder written by `mapmerge areas` (its hybrid.json).
    pub dir: PathBuf,
    /// Start: `AREA:x,y` (a position in that area's frame, m).
    #[arg(long)]
    pub from: String,
    /// Goal: `AREA:x,y`.
    #[arg(long)]
    pub to: String,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// `AREA:x,y`.
fn place(text: &str) -> anyhow::Result<(usize, Point2)> {
    let bad = || bad_input(format!("{text:?}: expected AREA:x,y"));
    let (area, xy) = text.split_once(':').ok_or_else(bad)?;
    let (x, y) = xy.split_once(',').ok_or_else(bad)?;
    let number = |s: &str| s.trim().parse::<f64>().ok().filter(|v| v.is_finite());
    Ok((
        area.trim().parse().map_err(|_| bad())?,
        Point2::new(number(x).ok_or_else(bad)?, number(y).ok_or_else(bad)?),
    ))
}

/// Runs `mapmerge route`.
pub fn route(args: &RouteArgs) -> anyhow::Result<std::process::ExitCode> {
    let file = args.dir.join("hybrid.json");
    let text = std::fs::read_to_string(&file)
        .map_err(|e| bad_input(format!("{}: {e}", file.display())))?;
    let hybrid: HybridMap =
        serde_json::from_str(&text).map_err(|e| bad_input(format!("{}: {e}", file.display())))?;
    let (start_area, start) = place(&args.from)?;
    let (goal_area, goal) = place(&args.to)?;
    for area in [start_area, goal_area] {
        if area >= hybrid.areas.len() {
            return Err(bad_input(format!(
                "no area {area} (the map has {})",
                hybrid.areas.len()
            )));
        }
    }
    let Some(found): Option<Route> = hybrid.route(start_area, start, goal_area, goal) else {
        if args.json {
            print_json(&serde_json::json!({"route": null}))?;
        } else {
            println!(
                "no route: no chain of link points joins area {start_area} to area {goal_area}"
            );
        }
        return Ok(std::process::ExitCode::from(3));
    };
    if args.json {
        print_json(&serde_json::json!({"route": found}))?;
    } else {
        let areas: Vec<String> = found.areas.iter().map(|a| a.to_string()).collect();
        let links: Vec<String> = found.link_points.iter().map(|l| l.to_string()).collect();
        println!(
            "{:.2} m through areas {} via link points [{}]",
            found.length_m,
            areas.join(" → "),
            links.join(", ")
        );
    }
    Ok(std::process::ExitCode::SUCCESS)
}
