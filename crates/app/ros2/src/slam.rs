//! `mapmerge ros2 slam`: the lifelong engine on a live robot. Scans, odometry and tf come in
//! ([`ScanAssembler`], the bag reader's rules); each scan goes through the engine and its pose
//! goes out at once as `/tf` map → odom, stamped with the scan; the engine's events go to
//! `/mapmerge/events`; the map is rebuilt from every scan at its current pose on a thread of
//! idle priority and published on `/map` (latched, as map_server). With a store the session is
//! committed when the node stops.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::Arc;
use std::time::{Duration, Instant};

use mapmerge_atlas::AtlasEvent;
use mapmerge_engine::EngineParams;
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{ClassThresholds, InsertParams, OccupancyGrid};
use mapmerge_jobs::{AtlasJob, AtlasOptions, CommittedSession, JobError};
use mapmerge_rosbag::{
    occupancy_grid_message, Header, LaserScanMessage, LiveDrops, LiveMount, OdometryMessage,
    Quaternion, ScanAssembler, TfMessage, Transform, TransformStamped, Vector3, LASER_SCAN_TYPE,
    ODOMETRY_TYPE, TF_TYPE,
};
use mapmerge_scan::LaserScan;
use serde::Serialize;

use crate::merge::EVENTS_TOPIC;
use crate::ros::{
    advertise, latched, now_s, open_node, reliable, stamp_of, subscribe, take_all, Delivery,
    MapWriter, STRING_TYPE,
};

/// How long the loop sleeps when no message is waiting.
const IDLE: Duration = Duration::from_millis(1);

/// How long the node waits at the end for its last map to be acknowledged.
const FLUSH_WAIT: Duration = Duration::from_secs(5);

/// What `mapmerge ros2 slam` does.
#[derive(Clone, Debug)]
pub struct SlamNodeOptions {
    /// The DDS domain (`ROS_DOMAIN_ID`).
    pub domain: u16,
    /// sensor_msgs/LaserScan.
    pub scan_topic: String,
    /// nav_msgs/Odometry.
    pub odom_topic: String,
    /// How the scans and odometry are heard.
    pub delivery: Delivery,
    /// The engine's parameters (`--config`, as `atlas`).
    pub params: EngineParams,
    /// The published map's cell side (m).
    pub resolution_m: f64,
    /// Seconds between map publications.
    pub map_period_s: f64,
    /// The map frame (`/map`'s and `/tf`'s parent frame).
    pub map_frame: String,
    /// The lifelong store (created when missing); the session is committed at the end.
    pub store: Option<PathBuf>,
    /// Newest versions that keep their atlas.
    pub keep_versions: usize,
    /// The session's name in the store.
    pub session: String,
    /// Stop after this long (s).
    pub duration_s: Option<f64>,
    /// Stop once no scan has come for this long (s), after the first.
    pub quiet_s: Option<f64>,
}

impl Default for SlamNodeOptions {
    fn default() -> Self {
        Self {
            domain: 0,
            scan_topic: "/scan".into(),
            odom_topic: "/odom".into(),
            delivery: Delivery::BestEffort,
            params: EngineParams::default(),
            resolution_m: mapmerge_jobs::DEFAULT_RESOLUTION_M,
            map_period_s: 5.0,
            map_frame: "map".into(),
            store: None,
            keep_versions: mapmerge_jobs::DEFAULT_KEEP_VERSIONS,
            session: "live".into(),
            duration_s: None,
            quiet_s: None,
        }
    }
}

/// Percentiles of a latency (ms).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct LatencySummary {
    pub count: usize,
    pub median_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
}

impl LatencySummary {
    /// The summary of `samples_ms` (zeros when empty).
    pub fn of(samples_ms: &[f64]) -> Self {
        let mut sorted = samples_ms.to_vec();
        sorted.sort_by(f64::total_cmp);
        let at = |q: f64| {
            let k = ((sorted.len() as f64 * q).ceil() as usize).clamp(1, sorted.len().max(1)) - 1;
            sorted.get(k).copied().unwrap_or(0.0)
        };
        Self {
            count: sorted.len(),
            median_ms: at(0.5),
            p99_ms: at(0.99),
            max_ms: sorted.last().copied().unwrap_or(0.0),
        }
    }
}

/// What the node did: the `--json` object of `mapmerge ros2 slam`.
#[derive(Clone, Debug, Serialize)]
pub struct SlamNodeReport {
    /// Scans heard, and fed to the engine.
    pub scans_heard: usize,
    pub scans_mapped: usize,
    /// Scans the assembler left out, by reason.
    pub left_out: LiveDrops,
    /// Messages that did not decode.
    pub bad_messages: usize,
    /// The laser's mount as tf gave it.
    pub mount: Option<LiveMount>,
    /// Epochs started while the node ran (tracking lost; the first is not counted), merges
    /// made and undos (engine events).
    pub epochs_started: usize,
    pub merges: usize,
    pub unmerges: usize,
    /// From taking a scan off its topic to publishing its pose (map → odom).
    pub pose_latency: LatencySummary,
    /// Maps published, the time from grid to published message, and the largest map's cells.
    pub maps_published: usize,
    pub map_publish: LatencySummary,
    pub largest_map_cells: usize,
    /// The store's committed version, with a store.
    pub committed: Option<CommittedSession>,
    /// The version the session continued.
    pub resumed_from: Option<i64>,
    /// Wall time (s).
    pub seconds: f64,
}

/// A map to draw: each scan at its pose, stamped.
struct MapJob {
    posed: Vec<(Se2, Arc<LaserScan>)>,
    stamp_s: f64,
}

/// Builds and publishes maps off the engine's thread; its figures come back at the end.
struct MapThread {
    jobs: mpsc::SyncSender<MapJob>,
    handle: std::thread::JoinHandle<(usize, Vec<f64>, usize, Option<OccupancyGrid>)>,
}

impl MapThread {
    fn start(publisher: MapWriter, resolution_m: f64, map_frame: String) -> Self {
        // One map waits at most: a map due while one is drawn replaces nothing, it is skipped.
        let (jobs, inbox) = mpsc::sync_channel::<MapJob>(1);
        let handle = std::thread::spawn(move || {
            lower_priority();
            let thresholds = ClassThresholds::default();
            let (mut published, mut publish_ms, mut largest) = (0, Vec::new(), 0);
            let mut last = None;
            while let Ok(job) = inbox.recv() {
                let posed: Vec<(Se2, &LaserScan)> =
                    job.posed.iter().map(|(p, s)| (*p, s.as_ref())).collect();
                let Ok((grid, _)) = OccupancyGrid::from_posed_scans(
                    resolution_m,
                    &posed,
                    &InsertParams::default(),
                    || {},
                ) else {
                    continue;
                };
                let started = Instant::now();
                let header = Header {
                    stamp: stamp_of(job.stamp_s),
                    frame_id: map_frame.clone(),
                };
                let message = occupancy_grid_message(&grid, &thresholds, header);
                largest = largest.max(grid.geometry().len());
                if publisher.publish(message) {
                    published += 1;
                    publish_ms.push(1e3 * started.elapsed().as_secs_f64());
                }
                last = Some(grid);
            }
            // The last map reaches every subscriber before the node leaves.
            publisher.flush(FLUSH_WAIT);
            (published, publish_ms, largest, last)
        });
        Self { jobs, handle }
    }
}

/// The map thread yields the core to the engine (Linux `SCHED_IDLE`): a map is drawn only when
/// no scan waits.
fn lower_priority() {
    #[cfg(target_os = "linux")]
    // SAFETY: sets the calling thread's own policy with a valid parameter block.
    unsafe {
        let param = libc::sched_param { sched_priority: 0 };
        libc::sched_setscheduler(0, libc::SCHED_IDLE, &param);
    }
}

/// `/tf` map → odom for one scan.
fn map_to_odom(map_frame: &str, odom_frame: &str, stamp_s: f64, map_from_odom: &Se2) -> TfMessage {
    TfMessage {
        transforms: vec![TransformStamped {
            header: Header {
                stamp: stamp_of(stamp_s),
                frame_id: map_frame.to_owned(),
            },
            child_frame_id: odom_frame.to_owned(),
            transform: Transform {
                translation: Vector3 {
                    x: map_from_odom.x_m,
                    y: map_from_odom.y_m,
                    z: 0.0,
                },
                rotation: Quaternion::from_yaw(map_from_odom.theta_rad),
            },
        }],
    }
}

/// Runs the node until `stop` is set, the duration is over or the scans have gone quiet;
/// `say` gets each line worth a user's attention. The map built last (every scan of the
/// robot's map at its final pose) is returned beside the report.
pub fn run_slam_node(
    options: &SlamNodeOptions,
    stop: &AtomicBool,
    mut say: impl FnMut(&str),
) -> Result<(SlamNodeReport, Option<OccupancyGrid>), JobError> {
    mapmerge_jobs::check_resolution(options.resolution_m)?;
    if !(options.map_period_s.is_finite() && options.map_period_s > 0.0) {
        return Err(JobError::bad_input(
            "--map-period must be a positive number of seconds",
        ));
    }
    let started = Instant::now();
    let mut job = AtlasJob::open(AtlasOptions {
        params: options.params.clone(),
        output: PathBuf::new(),
        pictures: false,
        store: options.store.clone(),
        keep_versions: options.keep_versions,
        announce_kidnaps: false,
    })?;
    let resumed_from = job.resumed_from();
    let (context, mut node) = open_node(options.domain, "mapmerge_slam")?;
    let sensor = options.delivery.qos();
    let scans = subscribe::<LaserScanMessage>(
        &mut node,
        &options.scan_topic,
        LASER_SCAN_TYPE,
        sensor.clone(),
    )?;
    let odometry =
        subscribe::<OdometryMessage>(&mut node, &options.odom_topic, ODOMETRY_TYPE, sensor)?;
    let tf = subscribe::<TfMessage>(&mut node, "/tf", TF_TYPE, reliable(100))?;
    let tf_static = subscribe::<TfMessage>(&mut node, "/tf_static", TF_TYPE, latched(100))?;
    let tf_out = advertise::<TfMessage>(&mut node, "/tf", TF_TYPE, reliable(100))?;
    let events = advertise::<String>(&mut node, EVENTS_TOPIC, STRING_TYPE, latched(100))?;
    let map_out = MapWriter::new(&context, &mut node, "/map")?;
    let map_thread = MapThread::start(map_out, options.resolution_m, options.map_frame.clone());
    say(&format!(
        "listening on {} and {} (ROS domain {}){}",
        options.scan_topic,
        options.odom_topic,
        options.domain,
        resumed_from
            .map(|v| format!(", continuing store version {v}"))
            .unwrap_or_default()
    ));

    let session = job.begin_session(true)?;
    let scans_before = job.engine().scans();
    let mut assembler = ScanAssembler::new();
    let mut kept_scans: Vec<Arc<LaserScan>> = Vec::new();
    let mut latencies_ms = Vec::new();
    let mut bad_messages = 0usize;
    let (mut scans_heard, mut epochs_started, mut merges, mut unmerges) =
        (0usize, 0usize, 0usize, 0usize);
    let mut odom_frame: Option<String> = None;
    let mut last_scan: Option<Instant> = None;
    let mut last_map = Instant::now();
    let mut last_problem: Option<String> = None;
    let mut announced_mount = false;
    let mut last_drops = assembler.drops();
    loop {
        let quiet = options
            .quiet_s
            .zip(last_scan)
            .is_some_and(|(q, t)| t.elapsed().as_secs_f64() > q);
        let over = options
            .duration_s
            .is_some_and(|d| started.elapsed().as_secs_f64() >= d);
        if stop.load(Ordering::Relaxed) || quiet || over {
            break;
        }
        for message in take_all(&tf_static, &mut bad_messages) {
            if let Err(reason) = assembler.tf(&message, true) {
                say(&format!("/tf_static: {reason}"));
            }
        }
        for message in take_all(&tf, &mut bad_messages) {
            // Our own map → odom comes back here; the assembler keeps each edge's first.
            if let Err(reason) = assembler.tf(&message, false) {
                say(&format!("/tf: {reason}"));
            }
        }
        for message in take_all(&odometry, &mut bad_messages) {
            if odom_frame.is_none() && !message.header.frame_id.is_empty() {
                odom_frame = Some(message.header.frame_id.trim_start_matches('/').to_owned());
            }
            if let Err(reason) = assembler.odometry(&message) {
                say(&format!("{}: {reason}", options.odom_topic));
            }
        }
        let heard = take_all(&scans, &mut bad_messages);
        let any = !heard.is_empty();
        for message in heard {
            scans_heard += 1;
            let now = Instant::now();
            last_scan = Some(now);
            assembler.scan(message, now);
        }
        // Waits are timed to this read of the topics, not to when a scan is processed: a
        // scan behind a slow one must not time out on odometry still unread.
        let read_at = Instant::now();
        while let Some((record, heard_when)) = assembler.next_record(read_at) {
            if !announced_mount {
                if let Some(mount) = assembler.mount() {
                    announced_mount = true;
                    say(&format!(
                        "laser '{}' on '{}' at x {:.3} m, y {:.3} m, yaw {:.1}° {}",
                        mount.laser_frame,
                        mount.base_frame,
                        mount.robot_from_sensor.x_m,
                        mount.robot_from_sensor.y_m,
                        mount.robot_from_sensor.theta_rad.to_degrees(),
                        mount.source.describe()
                    ));
                }
            }
            let Some(odom_from_robot) = record.odom_from_robot else {
                continue;
            };
            let engine = job.engine_mut();
            let fed = engine.add_scan(&odom_from_robot, &record.scan, Some(record.stamp_secs));
            let report = match fed {
                Ok(report) => report,
                Err(e) => {
                    say(&format!("scan at {} s: {e}", record.stamp_secs));
                    continue;
                }
            };
            let (node, node_from_robot) = report.anchor;
            for event in report.events {
                match event.atlas() {
                    Some(AtlasEvent::EpochEnded { epoch, reason, .. }) => say(&format!(
                        "epoch {} ended ({reason:?}): a new map starts",
                        epoch.0
                    )),
                    Some(AtlasEvent::EpochStarted { .. }) => epochs_started += 1,
                    Some(AtlasEvent::Merged(merge)) => {
                        merges += 1;
                        let [x, y, yaw] = merge.active_from_inactive;
                        say(&format!(
                            "merged map {} ({} vertices) at x {x:.2} m, y {y:.2} m, yaw {:.1}° ({:?})",
                            merge.map.0,
                            merge.merged_vertices,
                            yaw.to_degrees(),
                            merge.reason
                        ));
                    }
                    Some(AtlasEvent::Unmerged(unmerge)) => {
                        unmerges += 1;
                        say(&format!(
                            "undid {} merge(s) ({:?})",
                            unmerge.merges.len(),
                            unmerge.reason
                        ));
                    }
                    _ => {}
                }
                if let Ok(text) = serde_json::to_string(event) {
                    let _ = events.publish(text);
                }
            }
            let map_from_robot = engine
                .map_graph()
                .vertex(node)
                .map(|v| v.pose.compose(&node_from_robot));
            if let Some(map_from_robot) = map_from_robot {
                let map_from_odom = map_from_robot.compose(&odom_from_robot.inverse());
                let frame = odom_frame.as_deref().unwrap_or("odom");
                let _ = tf_out.publish(map_to_odom(
                    &options.map_frame,
                    frame,
                    record.stamp_secs,
                    &map_from_odom,
                ));
                latencies_ms.push(1e3 * heard_when.elapsed().as_secs_f64());
            }
            kept_scans.push(Arc::new(record.scan));
        }
        if assembler.drops() != last_drops {
            last_drops = assembler.drops();
            say(&format!("scans left out so far: {last_drops:?}"));
        }
        if let Some(problem) = assembler.mount_problem() {
            if last_problem.as_deref() != Some(problem) {
                say(&format!("scans wait for tf: {problem}"));
                last_problem = Some(problem.to_owned());
            }
        }
        if last_map.elapsed().as_secs_f64() >= options.map_period_s && !kept_scans.is_empty() {
            last_map = Instant::now();
            // A map still being drawn: this one is skipped (`try_send`).
            let _ = map_thread.jobs.try_send(MapJob {
                posed: active_scans(job.engine(), &kept_scans),
                stamp_s: now_s(),
            });
        }
        if !any {
            std::thread::sleep(IDLE);
        }
    }
    // The end: waiting loops closed, the session's last map drawn from the poses as mapped,
    // then (with a store) maintenance and the commit, which thin the stored atlas but do not
    // change what was mapped.
    let scans_mapped = job.engine().scans() - scans_before;
    job.engine_mut()
        .finish()
        .map_err(|e| JobError::failed(&e))?;
    let final_job = MapJob {
        posed: active_scans(job.engine(), &kept_scans),
        stamp_s: now_s(),
    };
    let map_thread_jobs = map_thread.jobs;
    if !final_job.posed.is_empty() {
        let _ = map_thread_jobs.send(final_job);
    }
    drop(map_thread_jobs);
    let committed = if scans_mapped == 0 {
        say("no scan was mapped: nothing to commit");
        None
    } else {
        job.commit(&options.session, session)?
    };
    let (maps_published, publish_ms, largest_map_cells, last_grid) = map_thread
        .handle
        .join()
        .map_err(|_| JobError::Failed("the map thread panicked".into()))?;
    let report = SlamNodeReport {
        scans_heard,
        scans_mapped,
        left_out: assembler.drops(),
        bad_messages,
        mount: assembler.mount().cloned(),
        epochs_started,
        merges,
        unmerges,
        pose_latency: LatencySummary::of(&latencies_ms),
        maps_published,
        map_publish: LatencySummary::of(&publish_ms),
        largest_map_cells,
        committed,
        resumed_from,
        seconds: started.elapsed().as_secs_f64(),
    };
    Ok((report, last_grid))
}

/// Every scan of the robot's map (the active one, with what it merged) at its current pose.
fn active_scans(
    engine: &mapmerge_engine::Engine,
    scans: &[Arc<LaserScan>],
) -> Vec<(Se2, Arc<LaserScan>)> {
    engine
        .map_trajectories()
        .into_iter()
        .find(|t| t.map == mapmerge_atlas::map_name(None))
        .map(|t| {
            t.scans
                .iter()
                .filter_map(|s| {
                    scans
                        .get(s.scan)
                        .map(|scan| (s.map_from_robot, Arc::clone(scan)))
                })
                .collect()
        })
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latency_percentiles() {
        let samples: Vec<f64> = (1..=200).map(f64::from).collect();
        let summary = LatencySummary::of(&samples);
        assert_eq!(summary.count, 200);
        assert_eq!(summary.median_ms, 100.0);
        assert_eq!(summary.p99_ms, 198.0);
        assert_eq!(summary.max_ms, 200.0);
        assert_eq!(LatencySummary::of(&[]), LatencySummary::default());
    }

    #[test]
    fn map_to_odom_is_stamped_with_the_scan() {
        let tf = map_to_odom("map", "odom", 12.5, &Se2::new(1.0, 2.0, 0.5));
        let t = &tf.transforms[0];
        assert_eq!(
            (t.header.frame_id.as_str(), t.child_frame_id.as_str()),
            ("map", "odom")
        );
        assert_eq!(t.header.stamp.seconds(), 12.5);
        assert!((t.transform.rotation.yaw() - 0.5).abs() < 1e-12);
    }
}
