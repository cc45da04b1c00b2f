//! The map manager of Ehlers et al. as a job (`mapmerge areas`, `mapmerge route`): door
//! passings split each session into areas, each area is mapped by the SLAM pipeline with its
//! environment's preset, the link points at the doors join the maps into a hybrid map, and a
//! store (optional) keeps the sessions for the next run. Writes areas.json, hybrid.json,
//! tracking.json, overview.png and `area_K/` (graph.g2o, map.yaml + map.pgm, map.png,
//! trajectory.tum) for each area.

use std::path::{Path, PathBuf};

use mapmerge_areas::{manage_mapped, map_session, HybridMap, ManagerParams, MappedSession, Route};
use mapmerge_engine::{run_slam, EngineParams};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{InsertParams, Point2};
use mapmerge_place::PlaceVerifierParams;
use mapmerge_posegraph::{NodeId, PoseGraph2};
use mapmerge_render::{session_color, Picture, PictureStyle, Rgb};
use mapmerge_scan::LaserLog;
use serde::Serialize;

use crate::JobError;

/// How `manage_areas` runs.
#[derive(Clone, Debug)]
pub struct AreasOptions {
    /// The map manager's parameters.
    pub params: ManagerParams,
    /// Cell side of the maps (m).
    pub resolution_m: f64,
    /// The lifelong store (created when missing, unless there are no new sessions): its
    /// newest version's sessions come first, new ones after, and the result is committed.
    pub store: Option<PathBuf>,
}

/// How far `manage_areas` got.
#[derive(Clone, Copy, Debug)]
pub enum AreasProgress {
    /// A new session of this many scans is being mapped.
    Session {
        /// Its scans.
        scans: usize,
    },
    /// This many more of its scans are mapped.
    Mapped {
        /// Scans.
        scans: usize,
    },
    /// The session is mapped.
    SessionDone,
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
    /// Whether its frame is placed in the first area's (false: a session the search did not
    /// place).
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
    /// The area whose scans hold it, and the door's centre in that area's frame.
    area: Option<usize>,
    area_x: Option<f64>,
    area_y: Option<f64>,
    /// Whether its session is placed; then the centre in the first area's frame.
    placed: bool,
    x: Option<f64>,
    y: Option<f64>,
    /// Whether it starts a new area (a passing too soon after the last one does not).
    boundary: bool,
}

/// What `mapmerge areas` did (the object `--json` prints).
#[derive(Clone, Debug, Serialize)]
pub struct AreasReport {
    /// Sessions mapped (stored and new).
    pub sessions: usize,
    /// Sessions placed in the first area's frame.
    pub sessions_placed: usize,
    /// Their scans.
    pub scans: usize,
    /// Areas.
    pub areas: usize,
    /// Link points.
    pub link_points: usize,
    /// Door passings detected.
    pub door_passings: usize,
    /// Topological loop closures (a door passed again, recognised).
    pub closures: usize,
    /// … of them at a link-point candidate (a door seen from another area, then passed).
    pub candidate_closures: usize,
    /// Link-point candidates left (doors seen, not passed).
    pub link_point_candidates: usize,
    /// Areas by configuration.
    pub indoor: usize,
    /// See `indoor`.
    pub large: usize,
    /// Wall time (s).
    pub seconds: f64,
    /// The output folder.
    pub output: PathBuf,
    /// With `--store`: the sessions read from it and the version committed (none when the
    /// run added no session).
    pub stored_sessions: usize,
    pub committed_version: Option<i64>,
}

/// Runs the map manager over the stored sessions (with `options.store`) and `logs` (new
/// sessions, each with its name), commits the new sessions to the store, writes the areas
/// into `output`, and reports.
pub fn manage_areas(
    logs: Vec<(String, LaserLog)>,
    options: &AreasOptions,
    output: &Path,
    mut progress: impl FnMut(AreasProgress),
) -> Result<AreasReport, JobError> {
    let params = &options.params;
    crate::check_resolution(options.resolution_m)?;
    let started = std::time::Instant::now();
    // The store first: a refused store stops the run before any mapping.
    let mut store = match &options.store {
        // Without sessions to add, the run only reads: a missing store is an error.
        Some(path) if logs.is_empty() => Some(crate::open_store_read_only(path)?),
        Some(path) => Some(crate::open_or_create_store(path)?),
        None => None,
    };
    let mut sessions: Vec<MappedSession> = match &store {
        Some(store) => store
            .load_areas(None)
            .map_err(|e| JobError::bad_file(&e))?
            .map(|stored| stored.sessions)
            .unwrap_or_default(),
        None => Vec::new(),
    };
    let stored_sessions = sessions.len();
    let added: Vec<String> = logs.iter().map(|(name, _)| name.clone()).collect();
    for (name, log) in logs {
        // Scans mapped (spans overlap at doors by a metre: the count ends a little high).
        progress(AreasProgress::Session {
            scans: log.scans.len(),
        });
        let mut map_span = |part: &LaserLog, preset: &mapmerge_areas::Preset| {
            let engine = EngineParams {
                tracker: preset.tracker.clone(),
                ..EngineParams::default()
            };
            let run = run_slam(part, engine, |_| {}).map_err(|e| e.to_string())?;
            progress(AreasProgress::Mapped {
                scans: part.scans.len(),
            });
            Ok((run.trajectory, run.graph))
        };
        let mapped = map_session(name, log, params, &mut map_span);
        progress(AreasProgress::SessionDone);
        sessions.push(mapped.map_err(JobError::bad_input)?);
    }
    if sessions.is_empty() {
        return Err(JobError::bad_input(match &options.store {
            Some(path) => format!(
                "{}: the store holds no areas; give LOG... or --sim WORLD",
                path.display()
            ),
            None => "no sessions to map".to_string(),
        }));
    }
    let verifier = PlaceVerifierParams::default()
        .verifier()
        .map_err(JobError::bad_input)?;
    let managed = manage_mapped(&sessions, params, &verifier).map_err(JobError::bad_input)?;
    let committed_version = match store.as_mut() {
        Some(store) if !added.is_empty() => Some(
            store
                .commit_areas(&mapmerge_store::AreasCommit {
                    session: &added.join(", "),
                    sessions: &sessions,
                    map: &managed,
                })
                .map_err(|e| JobError::bad_file(&e))?,
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
                graph
                    .add_vertex(NodeId(id.0 + offset), moved)
                    .map_err(|e| JobError::failed(&e))?;
            }
            for (_, edge) in m.graphs[*k].edges() {
                let mut moved = *edge;
                moved.from = NodeId(edge.from.0 + offset);
                moved.to = NodeId(edge.to.0 + offset);
                if moved.is_prior() {
                    moved.measurement = area_from_span.compose(&edge.measurement);
                }
                graph.add_edge(moved).map_err(|e| JobError::failed(&e))?;
            }
        }
        crate::write_slam_outputs(
            &output.join(format!("area_{}", area.id)),
            &part,
            &trajectory,
            &graph,
            options.resolution_m,
            || {},
        )?;
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
    // Every passing of every session, placed or not.
    let mut door_passings = Vec::new();
    for (s, m) in sessions.iter().enumerate() {
        for (i, passing) in m.segmentation.passings.iter().enumerate() {
            let center = |robot: Se2| robot.transform_point(&passing.center_in_robot_m);
            let in_area = spans
                .iter()
                .enumerate()
                .filter(|(_, (owner, _))| *owner == s)
                .find_map(|(g, (_, k))| {
                    let span = m.segmentation.spans.get(*k)?;
                    let robot = m
                        .trajectories
                        .get(*k)?
                        .get(passing.scan.checked_sub(span.scans.start)?)?;
                    let area = *managed.span_area.get(g)?;
                    Some((area, center(managed.area_from_span(g)?.compose(robot))))
                });
            let placed = first_from_robot[s].get(passing.scan).copied().flatten();
            door_passings.push(PassingEntry {
                session: s,
                scan: passing.scan,
                crossing_scan: passing.crossing_scan,
                area: in_area.map(|(a, _)| a),
                area_x: in_area.map(|(_, p)| p.x),
                area_y: in_area.map(|(_, p)| p.y),
                placed: placed.is_some(),
                x: placed.map(|robot| center(robot).x),
                y: placed.map(|robot| center(robot).y),
                boundary: m.segmentation.boundaries.contains(&i),
            });
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
    write_json(&output.join("areas.json"), &file)?;
    write_json(&output.join("hybrid.json"), hybrid)?;
    write_json(
        &output.join("tracking.json"),
        &serde_json::json!({
            "closures": managed.closures,
            "candidate_closures": managed.candidate_closures,
            "tracking": managed.tracking,
            "sessions_placed": managed.session_placed,
            "placements": managed.placements,
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
    overview(
        &all,
        &poses,
        &paths,
        hybrid,
        options.resolution_m,
        &output.join("overview.png"),
    )?;
    let passings: usize = sessions.iter().map(|m| m.segmentation.passings.len()).sum();
    Ok(AreasReport {
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
        output: output.to_path_buf(),
        stored_sessions,
        committed_version,
    })
}

/// A link point's position in the first area's frame.
fn link_in_first_frame(hybrid: &HybridMap, id: usize) -> Option<Point2> {
    let link = hybrid.link_points.get(id)?;
    let area = hybrid.areas.get(link.areas[0])?;
    Some(area.first_from_area.compose(&link.poses[0]).translation())
}

fn write_json(path: &Path, value: &impl Serialize) -> Result<(), JobError> {
    let text = serde_json::to_string_pretty(value).map_err(|e| JobError::writing(path, &e))?;
    std::fs::write(path, text + "\n").map_err(|e| JobError::writing(path, &e))
}

/// The overview: the whole map in the first area's frame, each area's path in its colour, the
/// link points and the topological graph over it.
fn overview(
    log: &LaserLog,
    poses: &[Se2],
    paths: &[Vec<Se2>],
    hybrid: &HybridMap,
    resolution_m: f64,
    path: &Path,
) -> Result<(), JobError> {
    let (grid, _) = crate::build_grid(log, poses, resolution_m, &InsertParams::default(), || {})?;
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
    picture
        .save_png(path)
        .map_err(|e| JobError::writing(path, &e))
}

/// Reads the hybrid map of a folder written by `mapmerge areas` (its hybrid.json).
pub fn load_hybrid_map(dir: &Path) -> Result<HybridMap, JobError> {
    let file = dir.join("hybrid.json");
    let text = mapmerge_io::read_document(&file).map_err(|e| JobError::bad_file(&e))?;
    let hybrid: HybridMap = serde_json::from_str(&text)
        .map_err(|e| JobError::bad_input(format!("{}: {e}", file.display())))?;
    hybrid
        .validate()
        .map_err(|e| JobError::bad_input(format!("{}: {e}", file.display())))?;
    Ok(hybrid)
}

/// `AREA:x,y`: a position in that area's frame (m).
pub fn parse_area_position(text: &str) -> Result<(usize, Point2), JobError> {
    let bad = || JobError::bad_input(format!("{text:?}: expected AREA:x,y"));
    let (area, xy) = text.split_once(':').ok_or_else(bad)?;
    let (x, y) = xy.split_once(',').ok_or_else(bad)?;
    let number = |s: &str| s.trim().parse::<f64>().ok().filter(|v| v.is_finite());
    Ok((
        area.trim().parse().map_err(|_| bad())?,
        Point2::new(number(x).ok_or_else(bad)?, number(y).ok_or_else(bad)?),
    ))
}

/// The shortest route (Dijkstra over the link points) between two positions given as
/// `AREA:x,y` in the hybrid map of `dir`; `None` when no chain of link points joins them.
pub fn route_between(dir: &Path, from: &str, to: &str) -> Result<Option<Route>, JobError> {
    let hybrid = load_hybrid_map(dir)?;
    let (start_area, start) = parse_area_position(from)?;
    let (goal_area, goal) = parse_area_position(to)?;
    for area in [start_area, goal_area] {
        if area >= hybrid.areas.len() {
            return Err(JobError::bad_input(format!(
                "no area {area} (the map has {})",
                hybrid.areas.len()
            )));
        }
    }
    Ok(hybrid.route(start_area, start, goal_area, goal))
}
