//! The `atlas` job: laser sessions through the lifelong engine (Holoch et al.'s merge
//! decisions over Atlas's epochs), with the events, the atlas's graphs, pictures around every
//! merge and, with a store, one committed version per session. [`AtlasJob::open`] opens the
//! store and the engine (a refused store stops before any work); [`AtlasJob::run`] feeds the
//! sessions and reports.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use mapmerge_atlas::{AtlasEvent, AtlasSnapshot, EpochEndReason};
use mapmerge_engine::{Decision, DetectorReading, Engine, EngineParams, EventKind, MergeState};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::NodeId;
use mapmerge_scan::LaserLog;
use mapmerge_store::{Store, StoreError};
use serde::{Deserialize, Serialize};

use crate::{draw_graph, open_or_create_store, write_atlas, JobError};

/// One session: a log fed scan by scan.
pub struct AtlasSession {
    pub name: String,
    pub log: LaserLog,
    /// Scans of this session where the robot was kidnapped (the truth): each starts a new
    /// epoch when the job announces kidnaps ([`AtlasOptions::announce_kidnaps`]); otherwise
    /// the engine must notice them itself.
    pub kidnaps: Vec<usize>,
    /// A reference pose per scan (a corrected log's poses, a simulator's truth), kept for
    /// every keyframe and committed with the atlas; none without.
    pub reference: Option<Vec<Se2>>,
}

/// One session per log (`(name, log)`, in order); `kidnap_at` counts scans over all logs
/// from 0. With `reference_from_poses`, each log's own poses are its reference (the public
/// corrected logs).
pub fn log_sessions(
    logs: Vec<(String, LaserLog)>,
    kidnap_at: &[usize],
    reference_from_poses: bool,
) -> Result<Vec<AtlasSession>, JobError> {
    if logs.is_empty() {
        return Err(JobError::bad_input(
            "give one or more logs, or --sim PRESET",
        ));
    }
    let lengths: Vec<usize> = logs.iter().map(|(_, log)| log.scans.len()).collect();
    let kidnaps = kidnaps_per_log(kidnap_at, &lengths)?;
    let mut sessions = Vec::with_capacity(logs.len());
    for ((name, log), kidnaps) in logs.into_iter().zip(kidnaps) {
        let reference = reference_from_poses.then(|| {
            let mut previous = Se2::identity();
            log.scans
                .iter()
                .map(|s| {
                    previous = s.odom_from_robot.unwrap_or(previous);
                    previous
                })
                .collect()
        });
        sessions.push(AtlasSession {
            name,
            log,
            // A log's first scan starts an epoch anyway (a restart).
            kidnaps: kidnaps.into_iter().filter(|&k| k > 0).collect(),
            reference,
        });
    }
    Ok(sessions)
}

/// `kidnap_at`, scans counted over all logs from 0, as each log's own scans; logs of
/// `lengths` scans in order. A kidnap beyond the last log is bad input.
pub fn kidnaps_per_log(
    kidnap_at: &[usize],
    lengths: &[usize],
) -> Result<Vec<Vec<usize>>, JobError> {
    let total: usize = lengths.iter().sum();
    if let Some(k) = kidnap_at.iter().find(|&&k| k >= total) {
        return Err(JobError::bad_input(format!(
            "--kidnap-at {k} is beyond the {total} scans of the logs"
        )));
    }
    let mut offset = 0;
    Ok(lengths
        .iter()
        .map(|&n| {
            let here = kidnap_at
                .iter()
                .filter(|&&k| k >= offset && k < offset + n)
                .map(|&k| k - offset)
                .collect();
            offset += n;
            here
        })
        .collect())
}

/// What the atlas job does besides mapping.
pub struct AtlasOptions {
    pub params: EngineParams,
    /// Output folder: `events.jsonl`, `atlas/` and `pictures/`.
    pub output: PathBuf,
    /// Draw the graph before and after every merge, unmerge and conditional merge.
    pub pictures: bool,
    /// The lifelong store (created when missing), and how many newest versions keep their
    /// atlas.
    pub store: Option<PathBuf>,
    pub keep_versions: usize,
    /// Tell the engine where the robot was kidnapped (`end_epoch(Kidnap)` at each of a
    /// session's kidnaps), as `--kidnap-at` does; `false` withholds them (the honest stream:
    /// the engine's tracking-failure detector must find them).
    pub announce_kidnaps: bool,
}

/// Where the job is: a session starts, or one scan was fed.
pub enum AtlasProgress<'a> {
    Session(&'a str),
    Scan,
}

/// A merge as reported: one per merge decision (conditional, full, rejected or undone).
#[derive(Clone, Debug, Serialize)]
pub struct MergeReport {
    /// The atlas's merge id, once merged fully.
    pub merge: Option<u64>,
    /// The hypothesis it came from (none for a forced merge).
    pub hypothesis: Option<u64>,
    /// Scan and travel when it was first decided (conditional, else full).
    pub scan: usize,
    pub travel_m: f64,
    /// The epoch that merged, and the inactive graph with its epochs.
    pub epoch: u32,
    pub map: u32,
    pub epochs: Vec<u32>,
    /// Merge edges (observations and overlap loops) and, when full, the overlap edges the
    /// full merge found.
    pub loop_edges: usize,
    pub overlap_edges: usize,
    /// `conditional`, `full`, `rejected` (a conditional merge dropped) or `undone`.
    pub state: MergeState,
    pub conditional_at_scan: Option<usize>,
    pub full_at_scan: Option<usize>,
    /// Travel from conditional to full (m).
    pub full_after_m: Option<f64>,
    /// Why it was rejected or undone.
    pub reason: Option<String>,
    /// Judged against the reference poses (the lab's judge fills these): `true` when most
    /// merge edges are within 0.5 m and 10° of it, and the median edge's error `[m, deg]`.
    pub correct: Option<bool>,
    pub error_m_deg: Option<[f64; 2]>,
    /// When it was rejected or undone: scan, and robot travel from the first decision (m).
    pub undone_at_scan: Option<usize>,
    pub undone_after_m: Option<f64>,
    /// When its epoch ended (a full merge became final): travel after the merge (m).
    pub final_after_m: Option<f64>,
    /// What the detector (first) and its components read while the merge was judged.
    pub readings: Vec<DetectorReading>,
}

/// An unmerge: the merges it undid and why.
#[derive(Clone, Debug, Serialize)]
pub struct UnmergeReport {
    pub scan: usize,
    pub travel_m: f64,
    pub merges: Vec<u64>,
    pub reason: String,
}

/// A fragment that joined the site map at a session's end
/// ([`mapmerge_atlas::Atlas::rejoin_fragments`]).
#[derive(Clone, Debug, Serialize)]
pub struct RejoinReport {
    /// Scan and travel of the session's end.
    pub scan: usize,
    pub travel_m: f64,
    /// The fragment, with its epochs and vertices, and the site map it joined.
    pub map: u32,
    pub into: u32,
    pub epochs: Vec<u32>,
    pub vertices: usize,
    /// Agreeing matches that joined it, and the best one's score.
    pub loops: usize,
    pub score: f64,
    /// Judged against the reference poses as a merge is (the lab's judge fills these).
    pub correct: Option<bool>,
    pub error_m_deg: Option<[f64; 2]>,
    /// The joining edges `(site view, fragment view, measurement)`.
    #[serde(skip)]
    pub edges: Vec<(NodeId, NodeId, Se2)>,
}

/// Views of inactive graphs searched for another placement of their own local map.
#[derive(Clone, Debug, Serialize)]
pub struct SelfSimilarityReport {
    pub views: usize,
    /// Those that fit themselves elsewhere (from `decisions.self_similar_from_score` on).
    pub self_similar: usize,
    /// Joint local maps of a hypothesis's self-similar views searched
    /// (`decisions.joint_views`) …
    pub joint_searched: usize,
    /// … and those that fit nowhere else (their views then count in full).
    pub joint_unique: usize,
    pub seconds: f64,
}

/// `--store`: the version continued and the versions committed.
#[derive(Clone, Debug, Serialize)]
pub struct StoreRunReport {
    pub path: PathBuf,
    /// The version the run continued (none for a new store).
    pub resumed_from: Option<i64>,
    /// Opening the store, loading its newest atlas and rebuilding the place index (s).
    pub open_secs: f64,
    pub committed: Vec<CommittedSession>,
}

/// One committed session.
#[derive(Clone, Debug, Serialize)]
pub struct CommittedSession {
    #[serde(flatten)]
    pub version: mapmerge_store::VersionInfo,
    /// Ending the session, maintaining, snapshotting and committing the atlas (s).
    pub commit_secs: f64,
    /// ATE (m) of the session's keyframes, and of every keyframe of the graph the robot
    /// ended in, against their reference poses (the lab's judge fills these).
    pub session_ate_m: Option<f64>,
    pub map_ate_m: Option<f64>,
    /// What maintenance did before the commit (included in `commit_secs`).
    pub maintenance: mapmerge_atlas::MaintenanceReport,
    /// The site map (the largest graph) alone: counts and mapped area.
    pub site: Option<SiteMap>,
    /// Graphs in the atlas.
    pub graphs: usize,
    /// The session's first node, and every vertex of the graph the robot ended in as
    /// mapped, before maintenance thinned it.
    #[serde(skip)]
    pub first_node: NodeId,
    #[serde(skip)]
    pub mapped_poses: Vec<(NodeId, Se2)>,
}

/// The site map's size.
#[derive(Clone, Debug, Serialize)]
pub struct SiteMap {
    pub nodes: usize,
    pub edges: usize,
    pub keyframes: usize,
    pub local_maps: usize,
    pub mapped_area_m2: f64,
}

impl SiteMap {
    fn of(atlas: &AtlasSnapshot) -> Option<Self> {
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

/// The atlas job's report (the object `mapmerge atlas --json` prints, with the lab's
/// verdicts beside it when judged).
#[derive(Clone, Debug, Serialize)]
pub struct AtlasReport {
    pub sessions: usize,
    pub scans: usize,
    pub epochs: usize,
    /// Epochs that had a map to merge into: all but the first, or all when the run continued
    /// a stored atlas.
    pub epochs_with_a_map: usize,
    pub merges: Vec<MergeReport>,
    pub unmerges: Vec<UnmergeReport>,
    /// Fragments that joined the site map at a session's end.
    pub rejoins: Vec<RejoinReport>,
    pub hypotheses: mapmerge_engine::HypothesisSummary,
    /// Every epoch: its merge hypotheses and how far they got (why a later epoch did or did
    /// not merge).
    pub epoch_outcomes: Vec<mapmerge_engine::EpochOutcome>,
    pub ambiguous_keyframes: usize,
    /// Views of inactive graphs searched for another placement of their own local map, those
    /// found self-similar (ambiguous), and the time it took.
    pub self_similarity: SelfSimilarityReport,
    /// Where the time went: the tracker's and the constraint builder's counters.
    pub tracker: mapmerge_slam::TrackerInfo,
    pub constraints: mapmerge_atlas::ConstraintInfo,
    pub pictures: Vec<PathBuf>,
    pub events: PathBuf,
    /// Every map with its epochs and their scans (`maps.json`; each map's scans in
    /// `maps/<map>/trajectory.tum`).
    pub maps: Vec<MapReport>,
    /// With a store: what was continued and what was committed.
    pub store: Option<StoreRunReport>,
    pub seconds: f64,
    pub ms_per_scan: f64,
}

/// A graph of the atlas as written to `maps/<map>/`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MapReport {
    /// `active` or `inactive-K`, as in `atlas/`.
    pub map: String,
    /// `maps/<map>/trajectory.tum`: every scan of this run the map holds, in the map's frame,
    /// stamped with the scan's log time (a clock of `TUM_CLOCK_PERIOD_S` per scan for a log
    /// whose stamps do not increase), in the order of `epochs` and their `scan_ranges` (none
    /// when the map holds no scan of this run). Beside it, `reference.tum` holds the same
    /// scans' reference poses when the sessions carry them.
    pub trajectory: Option<PathBuf>,
    pub scans: usize,
    pub epochs: Vec<MapEpoch>,
}

/// One epoch of a map: the session it was taken in and its scans there.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MapEpoch {
    pub epoch: u32,
    /// The session (its name and its place in this run); none for an epoch of the stored
    /// atlas the run continued.
    pub session: Option<String>,
    pub session_index: Option<usize>,
    /// Inclusive runs `[first, last]` of the session's own scan numbers.
    pub scan_ranges: Vec<[usize; 2]>,
}

/// Writes `maps/<map>/trajectory.tum` for every map and `maps.json`; sessions started at
/// the engine's scans `session_starts` (in order, the first at 0).
fn write_maps(
    engine: &Engine,
    sessions: &[AtlasSession],
    session_starts: &[usize],
    output: &Path,
) -> Result<Vec<MapReport>, JobError> {
    // TUM stamps must increase (readers such as evo pair poses by them): each session's own,
    // or a clock where they do not.
    let stamps: Vec<Vec<f64>> = sessions
        .iter()
        .map(|s| s.log.increasing_scan_stamps(crate::TUM_CLOCK_PERIOD_S).0)
        .collect();
    let mut reports = Vec::new();
    for trajectory in engine.map_trajectories() {
        // Each scan's (session, scan in the session).
        let at: Vec<(usize, usize)> = trajectory
            .scans
            .iter()
            .map(|s| {
                let k = session_starts
                    .partition_point(|&start| start <= s.scan)
                    .saturating_sub(1);
                (k, s.scan - session_starts.get(k).copied().unwrap_or(0))
            })
            .collect();
        // Epochs with scans in scan order (an epoch's scans are consecutive), then the
        // stored ones.
        let mut epochs: Vec<MapEpoch> = Vec::new();
        for (scan, &(s, local)) in trajectory.scans.iter().zip(&at) {
            match epochs.last_mut() {
                Some(e) if e.epoch == scan.epoch && e.session_index == Some(s) => {
                    match e.scan_ranges.last_mut() {
                        Some(range) if range[1] + 1 == local => range[1] = local,
                        _ => e.scan_ranges.push([local, local]),
                    }
                }
                _ => epochs.push(MapEpoch {
                    epoch: scan.epoch,
                    session: sessions.get(s).map(|x| x.name.clone()),
                    session_index: Some(s),
                    scan_ranges: vec![[local, local]],
                }),
            }
        }
        for &epoch in &trajectory.epochs {
            if !epochs.iter().any(|e| e.epoch == epoch) {
                epochs.push(MapEpoch {
                    epoch,
                    session: None,
                    session_index: None,
                    scan_ranges: Vec::new(),
                });
            }
        }
        let path = (!trajectory.scans.is_empty()).then(|| {
            output
                .join("maps")
                .join(&trajectory.map)
                .join("trajectory.tum")
        });
        if let Some(path) = &path {
            // Each line's stamp and, when known, its reference pose.
            let stamp = |(k, scan): (usize, usize)| {
                stamps
                    .get(k)
                    .and_then(|x| x.get(scan))
                    .copied()
                    .unwrap_or(scan as f64)
            };
            let poses: Vec<(f64, Se2)> = at
                .iter()
                .zip(&trajectory.scans)
                .map(|(&a, s)| (stamp(a), s.map_from_robot))
                .collect();
            let reference: Option<Vec<(f64, Se2)>> = at
                .iter()
                .map(|&(k, scan)| {
                    let pose = sessions.get(k)?.reference.as_ref()?.get(scan)?;
                    Some((stamp((k, scan)), *pose))
                })
                .collect();
            if let Some(dir) = path.parent() {
                std::fs::create_dir_all(dir).map_err(|e| JobError::writing(dir, &e))?;
            }
            mapmerge_io::write_tum_planar(path, &poses).map_err(|e| JobError::writing(path, &e))?;
            if let Some(reference) = reference {
                let path = path.with_file_name("reference.tum");
                mapmerge_io::write_tum_planar(&path, &reference)
                    .map_err(|e| JobError::writing(&path, &e))?;
            }
        }
        reports.push(MapReport {
            map: trajectory.map,
            trajectory: path,
            scans: trajectory.scans.len(),
            epochs,
        });
    }
    let path = output.join("maps.json");
    let text = serde_json::to_string_pretty(&reports).map_err(|e| JobError::failed(&e))?;
    std::fs::write(&path, text + "\n").map_err(|e| JobError::writing(&path, &e))?;
    Ok(reports)
}

/// A finished run: the engine, the reference pose of every keyframe (this run's and the
/// store's), and the report.
pub struct AtlasRun {
    pub engine: Engine,
    pub reference_of_node: BTreeMap<NodeId, Se2>,
    pub report: AtlasReport,
}

/// Where a session began: the events and nodes after it are the session's.
#[derive(Clone, Copy, Debug)]
pub struct SessionStart {
    events_before: usize,
    first_node: NodeId,
}

/// The atlas job between [`AtlasJob::open`] and [`AtlasJob::run`].
pub struct AtlasJob {
    options: AtlasOptions,
    engine: Engine,
    store: Option<Store>,
    /// Whether `open` created the store's file (removed again when `run` refuses its input).
    created_store: bool,
    reference_of_node: BTreeMap<NodeId, Se2>,
    resumed_from: Option<i64>,
    open_secs: f64,
    started: Instant,
}

impl AtlasJob {
    /// Opens the store (continuing its newest atlas) and the engine. A store that cannot be
    /// opened or loaded, no version to keep and parameters the engine refuses are bad input.
    pub fn open(options: AtlasOptions) -> Result<Self, JobError> {
        let started = Instant::now();
        let keep_versions = std::num::NonZeroUsize::new(options.keep_versions);
        if options.store.is_some() && keep_versions.is_none() {
            return Err(JobError::bad_input(
                "--keep-versions must be at least 1: the newest version keeps its atlas",
            ));
        }
        let created_store = options.store.as_ref().is_some_and(|path| !path.exists());
        let store = match &options.store {
            Some(path) => {
                let mut store = open_or_create_store(path)?;
                if let Some(keep) = keep_versions {
                    store.keep_versions(keep);
                }
                Some(store)
            }
            None => None,
        };
        let stored = match &store {
            Some(store) => match store.load(None) {
                Ok(stored) => stored,
                // Versions written by schema 1 hold no atlas: the lifelong atlas starts now.
                Err(StoreError::NoAtlas { .. }) => None,
                Err(e) => return Err(JobError::bad_file(&e)),
            },
            None => None,
        };
        let resumed_from = stored.as_ref().map(|s| s.version);
        let params = options.params.clone();
        let (engine, reference_of_node) = match stored {
            Some(stored) => (
                Engine::resume(params, stored.atlas).map_err(|e| JobError::bad_file(&e))?,
                stored.reference_poses,
            ),
            None => (
                Engine::new(params).map_err(JobError::bad_input)?,
                BTreeMap::new(),
            ),
        };
        Ok(Self {
            options,
            engine,
            store,
            created_store,
            reference_of_node,
            resumed_from,
            open_secs: started.elapsed().as_secs_f64(),
            started,
        })
    }

    /// The stored version this run continues.
    pub fn resumed_from(&self) -> Option<i64> {
        self.resumed_from
    }

    /// Starts a session: a restart ends the epoch, unless this is the run's first session
    /// on a new atlas or the last session ended it (a store).
    pub fn begin_session(&mut self, first_of_run: bool) -> Result<SessionStart, JobError> {
        let start = SessionStart {
            events_before: self.engine.events().len(),
            first_node: self.engine.atlas().next_node_id(),
        };
        if (!first_of_run || self.resumed_from.is_some())
            && self.engine.atlas().active().num_vertices() > 0
        {
            self.engine
                .end_epoch(EpochEndReason::Restart)
                .map_err(|e| JobError::failed(&e))?;
        }
        Ok(start)
    }

    /// Ends the session begun at `start`: with a store, closes waiting loops, maintains and
    /// commits it as one version; without, closes waiting loops only.
    pub fn commit(
        &mut self,
        session: &str,
        start: SessionStart,
    ) -> Result<Option<CommittedSession>, JobError> {
        let Some(store) = self.store.as_mut() else {
            self.engine.finish().map_err(|e| JobError::failed(&e))?;
            return Ok(None);
        };
        commit_session(
            store,
            &mut self.engine,
            session,
            start.events_before,
            start.first_node,
            &self.reference_of_node,
        )
        .map(Some)
    }

    /// The engine, to feed scans one at a time between [`AtlasJob::begin_session`] and
    /// [`AtlasJob::commit`] (a live robot).
    pub fn engine_mut(&mut self) -> &mut Engine {
        &mut self.engine
    }

    /// The engine.
    pub fn engine(&self) -> &Engine {
        &self.engine
    }

    /// Feeds every session in order (a new session ends the epoch as a restart; a kidnap
    /// ends it too), commits each with a store, and writes the events, the atlas and the
    /// pictures.
    pub fn run(
        mut self,
        sessions: &[AtlasSession],
        mut progress: impl FnMut(AtlasProgress<'_>),
    ) -> Result<AtlasRun, JobError> {
        // A session without scans would commit an empty version: refused before anything is
        // fed or written, and a store this job created is removed again.
        if let Some(empty) = sessions.iter().find(|s| s.log.scans.is_empty()) {
            if let (Some(store), true) = (self.store.take(), self.created_store) {
                let path = store.path().to_path_buf();
                drop(store);
                for file in mapmerge_store::store_files(&path) {
                    let _ = std::fs::remove_file(file);
                }
            }
            return Err(JobError::bad_input(format!(
                "{}: no scans; nothing is mapped or committed",
                empty.name
            )));
        }
        let output = self.options.output.clone();
        let pictures_dir = output.join("pictures");
        std::fs::create_dir_all(&pictures_dir).map_err(|e| JobError::writing(&pictures_dir, &e))?;
        let mut pictures = Pictures {
            dir: pictures_dir,
            drawn: 0,
            paths: Vec::new(),
        };
        let mut committed = Vec::new();
        let mut session_starts = Vec::with_capacity(sessions.len());
        for (s, session) in sessions.iter().enumerate() {
            progress(AtlasProgress::Session(&session.name));
            session_starts.push(self.engine.scans());
            let start = self.begin_session(s == 0)?;
            self.feed(session, &mut pictures, &mut progress)?;
            if let Some(done) = self.commit(&session.name, start)? {
                committed.push(done);
            }
        }
        // Loops still waiting are closed before anything is written (a store's commit did).
        self.engine.finish().map_err(|e| JobError::failed(&e))?;
        let events = write_events(&self.engine, &output.join("events.jsonl"))?;
        write_atlas(&self.engine, &output.join("atlas"))?;
        let maps = write_maps(&self.engine, sessions, &session_starts, &output)?;
        let engine = &self.engine;
        let (merges, unmerges, rejoins) = summarise(engine);
        let epochs = engine
            .events()
            .iter()
            .filter(|e| matches!(e.atlas(), Some(AtlasEvent::EpochStarted { .. })))
            .count();
        let threshold = engine.params().decisions.self_similar_from_score;
        let view_scores = mapmerge_engine::view_self_similarity(engine.events());
        let fitting_elsewhere = |scores: &mut dyn Iterator<Item = &f64>| {
            scores.filter(|&&score| score >= threshold).count()
        };
        let joint = engine.joint_self_similarity();
        let seconds = self.started.elapsed().as_secs_f64();
        let report = AtlasReport {
            sessions: sessions.len(),
            scans: engine.scans(),
            epochs,
            epochs_with_a_map: if self.resumed_from.is_some() {
                epochs
            } else {
                epochs.saturating_sub(1)
            },
            merges,
            unmerges,
            rejoins,
            hypotheses: mapmerge_engine::hypothesis_summary(engine.events()),
            epoch_outcomes: mapmerge_engine::epoch_outcomes(engine.events(), engine.travel_m()),
            ambiguous_keyframes: mapmerge_engine::ambiguous_views(engine.events()).len(),
            self_similarity: SelfSimilarityReport {
                views: view_scores.len(),
                self_similar: fitting_elsewhere(&mut view_scores.values()),
                joint_searched: joint.len(),
                joint_unique: joint.len() - fitting_elsewhere(&mut joint.values()),
                seconds: engine.self_similarity_seconds(),
            },
            tracker: engine.tracker_info(),
            constraints: engine.atlas().constraint_info(),
            pictures: pictures.paths,
            events,
            maps,
            store: self.options.store.as_ref().map(|path| StoreRunReport {
                path: path.clone(),
                resumed_from: self.resumed_from,
                open_secs: self.open_secs,
                committed,
            }),
            seconds,
            ms_per_scan: 1e3 * seconds / engine.scans().max(1) as f64,
        };
        Ok(AtlasRun {
            engine: self.engine,
            reference_of_node: self.reference_of_node,
            report,
        })
    }

    /// One session's scans; its kidnaps end the epoch.
    fn feed(
        &mut self,
        session: &AtlasSession,
        pictures: &mut Pictures,
        progress: &mut impl FnMut(AtlasProgress<'_>),
    ) -> Result<(), JobError> {
        let engine = &mut self.engine;
        let mut previous_odometry = None;
        for (k, record) in session.log.scans.iter().enumerate() {
            progress(AtlasProgress::Scan);
            if self.options.announce_kidnaps && session.kidnaps.contains(&k) {
                engine
                    .end_epoch(EpochEndReason::Kidnap)
                    .map_err(|e| JobError::failed(&e))?;
            }
            let odometry = record
                .odom_from_robot
                .or(previous_odometry)
                .unwrap_or_else(Se2::identity);
            previous_odometry = Some(odometry);
            let report = engine
                .add_scan(&odometry, &record.scan, Some(record.stamp_secs))
                .map_err(|e| JobError::context(format!("{}: scan {k}", session.name), &e))?;
            if let (Some(node), Some(reference)) = (
                report.keyframe,
                session.reference.as_ref().and_then(|r| r.get(k)),
            ) {
                self.reference_of_node.insert(node, *reference);
            }
            if !self.options.pictures {
                continue;
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
            for kind in fresh {
                let stem = format!("{:03}-{kind}", pictures.drawn);
                pictures.drawn += 1;
                if let Some(before) = engine.before_last_change() {
                    let path = pictures.dir.join(format!("{stem}-before.png"));
                    draw_graph(before, engine, &[], &path)?;
                    pictures.paths.push(path);
                }
                let path = pictures.dir.join(format!("{stem}-after.png"));
                draw_graph(
                    engine.map_graph(),
                    engine,
                    &engine.conditional_edges(),
                    &path,
                )?;
                pictures.paths.push(path);
            }
        }
        Ok(())
    }
}

/// The pictures around merges: their folder, how many changes were drawn, the files.
struct Pictures {
    dir: PathBuf,
    drawn: usize,
    paths: Vec<PathBuf>,
}

/// Every event, one JSON object per line.
fn write_events(engine: &Engine, path: &Path) -> Result<PathBuf, JobError> {
    let write = || -> std::io::Result<()> {
        let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
        for event in engine.events() {
            serde_json::to_writer(&mut out, event)?;
            writeln!(out)?;
        }
        out.flush()
    };
    write().map_err(|e| JobError::writing(path, &e))?;
    Ok(path.to_path_buf())
}

/// Merges from the engine's merge log, unmerges and rejoins from the events.
fn summarise(engine: &Engine) -> (Vec<MergeReport>, Vec<UnmergeReport>, Vec<RejoinReport>) {
    let merges = engine
        .merge_log()
        .iter()
        .map(|record| {
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
            MergeReport {
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
                correct: None,
                error_m_deg: None,
                undone_at_scan: record.ended_at_scan,
                undone_after_m: record.ended_after_m(),
                final_after_m,
                readings: record.readings.clone(),
            }
        })
        .collect();
    let unmerges = engine
        .events()
        .iter()
        .filter_map(|e| match e.atlas() {
            Some(AtlasEvent::Unmerged(u)) => Some(UnmergeReport {
                scan: e.scan,
                travel_m: e.travel_m,
                merges: u.merges.iter().map(|m| m.0).collect(),
                reason: u.reason.summary(),
            }),
            _ => None,
        })
        .collect();
    let rejoins = engine
        .events()
        .iter()
        .filter_map(|e| match e.atlas() {
            Some(AtlasEvent::Rejoined(r)) => Some(RejoinReport {
                scan: e.scan,
                travel_m: e.travel_m,
                map: r.map.0,
                into: r.into.0,
                epochs: r.epochs.iter().map(|x| x.0).collect(),
                vertices: r.vertices,
                loops: r.loops.len(),
                score: r.score,
                correct: None,
                error_m_deg: None,
                edges: r
                    .loops
                    .iter()
                    .map(|(site, fragment, [x, y, yaw])| (*site, *fragment, Se2::new(*x, *y, *yaw)))
                    .collect(),
            }),
            _ => None,
        })
        .collect();
    (merges, unmerges, rejoins)
}

/// Ends the session ([`Engine::end_session`]: its epoch ends, the atlas is maintained) and
/// commits it: the atlas, the session's events and the reference poses.
fn commit_session(
    store: &mut Store,
    engine: &mut Engine,
    session: &str,
    events_before: usize,
    first_node: NodeId,
    reference_of_node: &BTreeMap<NodeId, Se2>,
) -> Result<CommittedSession, JobError> {
    let started = Instant::now();
    engine.finish().map_err(|e| JobError::failed(&e))?;
    let mapped_poses = engine
        .atlas()
        .active()
        .vertices()
        .map(|(n, v)| (n, v.pose))
        .collect();
    let maintenance = engine
        .end_session(first_node)
        .map_err(|e| JobError::failed(&e))?;
    let atlas = engine
        .atlas()
        .snapshot()
        .map_err(|e| JobError::failed(&e))?;
    let events = engine
        .events()
        .get(events_before..)
        .unwrap_or_default()
        .iter()
        .map(serde_json::to_string)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| JobError::failed(&e))?;
    let version = store
        .commit_session(&mapmerge_store::SessionCommit {
            session,
            atlas: &atlas,
            events: &events,
            reference_poses: reference_of_node,
        })
        .map_err(|e| JobError::bad_file(&e))?;
    let commit_secs = started.elapsed().as_secs_f64();
    let version = store
        .versions()
        .map_err(|e| JobError::bad_file(&e))?
        .into_iter()
        .find(|v| v.version == version)
        .ok_or_else(|| {
            JobError::Failed(format!("version {version} was committed but is not listed"))
        })?;
    Ok(CommittedSession {
        version,
        commit_secs,
        session_ate_m: None,
        map_ate_m: None,
        maintenance,
        site: SiteMap::of(&atlas),
        graphs: atlas.graphs().filter(|g| g.num_vertices() > 0).count(),
        first_node,
        mapped_poses,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kidnaps_are_cut_into_each_logs_own_scans() {
        assert_eq!(
            kidnaps_per_log(&[0, 5, 10, 12, 29], &[10, 5, 15]).unwrap(),
            vec![vec![0, 5], vec![0, 2], vec![14]]
        );
        let err = kidnaps_per_log(&[30], &[10, 5, 15]).unwrap_err();
        assert_eq!(err.exit_code(), 2);
        assert_eq!(
            err.message(),
            "--kidnap-at 30 is beyond the 30 scans of the logs"
        );
    }
}
