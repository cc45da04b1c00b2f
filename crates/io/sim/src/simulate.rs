//! Multi-session datasets: per session, (1) the session's world (session 0's with changes),
//! (2) its roadmap, (3) a start place, (4) slip and kidnap schedules, (5) the robot's true
//! motion, (6) noisy odometry, (7) odometry readings and scans sampled from the motion,
//! (8) lidar scans in parallel.

use std::collections::BTreeMap;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::{LaserLog, OdometryReading, ScanRecord};
use rand::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::changes::{change_world, ChangeParams, WorldChange};
use crate::kidnap::{schedule_kidnaps, Kidnap, KidnapParams};
use crate::motion::{drive, DriveSetup, MotionInfo, RobotParams};
use crate::odometry::{
    integrate_odometry, schedule_slips_by_time, OdometryNoiseParams, SlipEvent, SlipSchedule,
    SlipSpan,
};
use crate::rng::{derive_seed, stream_rng, uniform, Stream};
use crate::world::RoomId;
use crate::{
    generate_world, Lidar, LidarParams, Roadmap, SimError, World, WorldParams, WorldPreset,
};

/// The CARMEN message tag of the scans (a laser with the odometry pose attached).
pub const SCAN_SOURCE_TAG: &str = "ROBOTLASER1";

/// Everything [`simulate`] needs. Build with `SimParams::default()` and the `with_*` methods,
/// or deserialise (every field has a default; unknown fields are refused).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimParams {
    /// The world (default: `office`).
    pub preset: WorldPreset,
    /// Parameters that replace the preset's (default: none).
    pub world: Option<WorldParams>,
    /// Seed of the world alone, so one world can be driven with many seeds (default: none:
    /// derived from the simulation's seed).
    pub world_seed: Option<u64>,
    /// Number of sessions (default: 3). Session 0 sees the generated world, later ones see
    /// it with `changes`.
    pub sessions: usize,
    /// Robot time per session (s) (default: 180).
    pub duration_secs: f64,
    /// Odometry messages per second (default: 20).
    pub odometry_rate_hz: f64,
    /// Scans per second (default: 10).
    pub scan_rate_hz: f64,
    /// Time stamp of session 0's first message (s) (default: 0).
    pub first_stamp_secs: f64,
    /// Time between the starts of consecutive sessions (s) (default: 86400, one day).
    pub session_spacing_secs: f64,
    /// Names of the rooms the sessions start in, by session (default: empty = random rooms,
    /// a different one per session when possible). Missing entries are random.
    pub start_rooms: Vec<String>,
    /// How the robot moves.
    pub robot: RobotParams,
    /// The laser.
    pub lidar: LidarParams,
    /// Wheel odometry noise and slips.
    pub odometry: OdometryNoiseParams,
    /// Kidnaps.
    pub kidnap: KidnapParams,
    /// Changes of later sessions' worlds.
    pub changes: ChangeParams,
}

/// Most sessions one simulation makes.
pub const MAX_SESSIONS: usize = 1000;
/// Longest simulated session (s): a day.
pub const MAX_DURATION_SECS: f64 = 86_400.0;
/// Fastest scan and odometry rate (Hz).
pub const MAX_RATE_HZ: f64 = 1000.0;
/// Most laser ranges a session holds (about 0.4 GB of `f32`).
pub const MAX_SESSION_RANGES: f64 = 1e8;

impl Default for SimParams {
    fn default() -> Self {
        Self {
            preset: WorldPreset::Office,
            world: None,
            world_seed: None,
            sessions: 3,
            duration_secs: 180.0,
            odometry_rate_hz: 20.0,
            scan_rate_hz: 10.0,
            first_stamp_secs: 0.0,
            session_spacing_secs: 86_400.0,
            start_rooms: Vec::new(),
            robot: RobotParams::default(),
            lidar: LidarParams::default(),
            odometry: OdometryNoiseParams::default(),
            kidnap: KidnapParams::default(),
            changes: ChangeParams::default(),
        }
    }
}

impl SimParams {
    /// The same parameters with another preset (and no world override).
    pub fn with_preset(mut self, preset: WorldPreset) -> Self {
        self.preset = preset;
        self.world = None;
        self
    }

    /// The same parameters with the preset called `name`.
    pub fn with_preset_name(self, name: &str) -> Result<Self, SimError> {
        Ok(self.with_preset(WorldPreset::from_name(name)?))
    }

    /// The same parameters with `sessions` sessions.
    pub fn with_sessions(mut self, sessions: usize) -> Self {
        self.sessions = sessions;
        self
    }

    /// The same parameters with sessions of `duration_secs`.
    pub fn with_duration_secs(mut self, duration_secs: f64) -> Self {
        self.duration_secs = duration_secs;
        self
    }

    /// The world parameters in force (the override, else the preset's).
    pub fn world_params(&self) -> WorldParams {
        self.world.clone().unwrap_or_else(|| self.preset.params())
    }

    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |field: &'static str, reason: &str| {
            Err(SimError::InvalidParams {
                field,
                reason: reason.to_owned(),
            })
        };
        if !(1..=MAX_SESSIONS).contains(&self.sessions) {
            return bad("sessions", "must be in [1, 1000]");
        }
        // In (0, max]; NaN and infinities are outside.
        let positive_up_to = |value: f64, max: f64| value > 0.0 && value <= max;
        if !positive_up_to(self.duration_secs, MAX_DURATION_SECS) {
            return bad("duration_secs", "must be in (0, 86400] s");
        }
        if !positive_up_to(self.odometry_rate_hz, MAX_RATE_HZ) {
            return bad("odometry_rate_hz", "must be in (0, 1000] Hz");
        }
        if !positive_up_to(self.scan_rate_hz, MAX_RATE_HZ) {
            return bad("scan_rate_hz", "must be in (0, 1000] Hz");
        }
        if !(self.first_stamp_secs.is_finite()
            && self.session_spacing_secs.is_finite()
            && self.session_spacing_secs >= 0.0)
        {
            return bad(
                "session_spacing_secs",
                "stamps must be finite and the spacing non-negative",
            );
        }
        self.robot.validate()?;
        self.lidar.validate()?;
        let ranges = self.duration_secs * self.scan_rate_hz * self.lidar.beam_count as f64;
        if ranges > MAX_SESSION_RANGES {
            return bad(
                "duration_secs",
                "duration × scan rate × beams must stay within 10⁸ ranges a session",
            );
        }
        self.odometry.validate()?;
        if !matches!(self.odometry.slip_schedule, SlipSchedule::ByTime { .. }) {
            return bad(
                "odometry.slip_schedule",
                "the simulator schedules slips over robot time (slip_rate_per_min, \
                 slip_duration_min_secs, slip_duration_max_secs)",
            );
        }
        self.kidnap.validate()
    }
}

/// A simulated multi-session dataset with its ground truth.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Dataset {
    /// The world's name (the preset's).
    pub world_name: String,
    /// Session 0's world.
    pub world: World,
    /// The sessions, in order.
    pub sessions: Vec<SessionData>,
    /// The seed it was made with.
    pub seed: u64,
    /// The parameters it was made with.
    pub params: SimParams,
}

/// One session: the log a robot would have written, and what really happened.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SessionData {
    /// Index of the session.
    pub index: usize,
    /// Odometry readings and scans. Each scan is a `ROBOTLASER1` record whose
    /// `odom_from_robot` is the (noisy) odometry pose at the scan's time; the odometry frame
    /// is the robot's start pose.
    pub log: LaserLog,
    /// Ground truth `(stamp_secs, world_from_robot)` of every scan, in scan order.
    pub truth: Vec<(f64, Se2)>,
    /// Kidnaps, in time order.
    pub kidnaps: Vec<Kidnap>,
    /// Wheel-slip events, in time order.
    pub slips: Vec<SlipEvent>,
    /// How this session's world differs from session 0's.
    pub world_changes: Vec<WorldChange>,
    /// The world as it was in this session.
    pub world: World,
    /// The room the session started in.
    pub start_room: RoomId,
    /// What the robot did.
    pub motion: MotionInfo,
}

/// Simulates a dataset; the same parameters and seed give the same dataset, bit for bit, on
/// any number of threads.
pub fn simulate(params: &SimParams, seed: u64) -> Result<Dataset, SimError> {
    let world = session_zero_world(params, seed)?;
    // Worlds first (sequentially: cheap), then the sessions in parallel.
    let mut worlds = Vec::with_capacity(params.sessions);
    for index in 0..params.sessions {
        if index == 0 {
            worlds.push((world.clone(), Vec::new()));
        } else {
            let mut rng = stream_rng(seed, Stream::Changes, index as u64);
            worlds.push(change_world(&mut rng, &world, &params.changes)?);
        }
    }
    let starts = pick_start_rooms(params, &worlds, seed)?;
    let sessions = worlds
        .into_par_iter()
        .zip(starts)
        .enumerate()
        .map(|(index, ((session_world, changes), start))| {
            simulate_session(params, seed, index, session_world, changes, start)
        })
        .collect::<Result<Vec<_>, SimError>>()?;
    Ok(Dataset {
        world_name: world.name.clone(),
        world,
        sessions,
        seed,
        params: params.clone(),
    })
}

/// A session's start: its room, and that room's reachable roadmap nodes (with the roadmap).
struct Start {
    room: RoomId,
    roadmap: Roadmap,
    destinations: Vec<(RoomId, Vec<usize>)>,
}

/// Start rooms: the named ones, else random destination rooms reachable in each session,
/// different from the earlier sessions' when possible.
fn pick_start_rooms(
    params: &SimParams,
    worlds: &[(World, Vec<WorldChange>)],
    seed: u64,
) -> Result<Vec<Start>, SimError> {
    let roadmaps: Vec<Roadmap> = worlds
        .par_iter()
        .map(|(world, _)| Roadmap::build(world, params.robot.clearance_m))
        .collect();
    let mut used: Vec<RoomId> = Vec::new();
    let mut starts = Vec::with_capacity(worlds.len());
    for (index, ((world, _), roadmap)) in worlds.iter().zip(roadmaps).enumerate() {
        let start = pick_start_room(params, world, roadmap, seed, index, &used)?;
        used.push(start.room);
        starts.push(start);
    }
    Ok(starts)
}

/// Session `index`'s start: the named room, else a random destination room reachable in
/// `world`, one not in `used` when possible.
fn pick_start_room(
    params: &SimParams,
    world: &World,
    roadmap: Roadmap,
    seed: u64,
    index: usize,
    used: &[RoomId],
) -> Result<Start, SimError> {
    let destinations: Vec<(RoomId, Vec<usize>)> = world
        .rooms
        .iter()
        .filter(|r| r.kind.is_destination())
        .map(|r| (r.id, roadmap.main_nodes_in(&r.rect)))
        .filter(|(_, nodes)| !nodes.is_empty())
        .collect();
    let room = match params.start_rooms.get(index) {
        Some(name) => {
            let id = world.room_by_name(name).map(|r| r.id);
            match id.filter(|id| destinations.iter().any(|(r, _)| r == id)) {
                Some(id) => id,
                None => {
                    return Err(SimError::UnknownStartRoom {
                        session: index,
                        name: name.clone(),
                    })
                }
            }
        }
        None => {
            if destinations.is_empty() {
                return Err(SimError::NoFreeSpace(world.name.clone()));
            }
            let mut rng = stream_rng(seed, Stream::Route, 1_000_000 + index as u64);
            let fresh: Vec<RoomId> = destinations
                .iter()
                .map(|(r, _)| *r)
                .filter(|r| !used.contains(r))
                .collect();
            let pool: Vec<RoomId> = if fresh.is_empty() {
                destinations.iter().map(|(r, _)| *r).collect()
            } else {
                fresh
            };
            pool[rng.random_range(0..pool.len())]
        }
    };
    Ok(Start {
        room,
        roadmap,
        destinations,
    })
}

/// The world of session 0 (validating the parameters first).
fn session_zero_world(params: &SimParams, seed: u64) -> Result<World, SimError> {
    params.validate()?;
    let world_seed = params
        .world_seed
        .unwrap_or_else(|| derive_seed(seed, Stream::World, 0));
    generate_world(&params.world_params(), world_seed)
}

/// Session `index` of the dataset [`simulate`] makes with `params` and `seed`, alone: the
/// same world, changes, route, odometry and kidnaps, so a robot can live one session per run
/// (the lifelong store). One difference: without the earlier sessions, its start room is
/// drawn from every destination room, not from those the earlier sessions did not start in
/// (so it may differ from `simulate`'s session `index`). `params.sessions` is ignored.
pub fn simulate_session_alone(
    params: &SimParams,
    seed: u64,
    index: usize,
) -> Result<SessionData, SimError> {
    let world = session_zero_world(params, seed)?;
    let (session_world, changes) = if index == 0 {
        (world, Vec::new())
    } else {
        let mut rng = stream_rng(seed, Stream::Changes, index as u64);
        change_world(&mut rng, &world, &params.changes)?
    };
    let roadmap = Roadmap::build(&session_world, params.robot.clearance_m);
    let start = pick_start_room(params, &session_world, roadmap, seed, index, &[])?;
    simulate_session(params, seed, index, session_world, changes, start)
}

fn simulate_session(
    params: &SimParams,
    seed: u64,
    index: usize,
    world: World,
    world_changes: Vec<WorldChange>,
    start: Start,
) -> Result<SessionData, SimError> {
    let session = index as u64;
    let dt = params.robot.step_secs;
    let duration = params.duration_secs;
    let step_count = (duration / dt).ceil() as usize;
    let stamp0 = params.first_stamp_secs + index as f64 * params.session_spacing_secs;
    let mut route_rng = stream_rng(seed, Stream::Route, session);
    let mut kidnap_rng = stream_rng(seed, Stream::Kidnap, session);
    let mut odometry_rng = stream_rng(seed, Stream::Odometry, session);
    // 3. Start pose: a random reachable node of the start room, random heading.
    let nodes = start
        .destinations
        .iter()
        .find(|(room, _)| *room == start.room)
        .map(|(_, nodes)| nodes.clone())
        .unwrap_or_default();
    if nodes.is_empty() {
        return Err(SimError::NoFreeSpace(world.name.clone()));
    }
    let p = start.roadmap.nodes()[nodes[route_rng.random_range(0..nodes.len())]];
    let start_pose = Se2::new(
        p.x,
        p.y,
        uniform(&mut route_rng, -std::f64::consts::PI, std::f64::consts::PI),
    );
    // 4. Schedules.
    let kidnap_times = schedule_kidnaps(&mut kidnap_rng, &params.kidnap, duration);
    let slips = schedule_slips_by_time(&mut odometry_rng, &params.odometry, duration);
    // 5. True motion.
    let setup = DriveSetup {
        world: &world,
        roadmap: &start.roadmap,
        robot: &params.robot,
        kidnap: &params.kidnap,
        destinations: &start.destinations,
    };
    let motion = drive(
        &setup,
        start_pose,
        start.room,
        step_count,
        &kidnap_times,
        &mut route_rng,
        &mut kidnap_rng,
    );
    // 6. Odometry.
    let (odometry_poses, odometry_rates) = integrate_odometry(
        &mut odometry_rng,
        &params.odometry,
        &slips,
        &motion.steps,
        dt,
    );
    // 7. Sample odometry readings and scan times.
    let sampler = Sampler {
        dt,
        truth: &motion.truth,
        odometry: &odometry_poses,
        kidnaps: &motion.kidnaps,
    };
    let odometry: Vec<OdometryReading> = sample_times(duration, params.odometry_rate_hz)
        .map(|t| {
            let step = sampler
                .step_of(t)
                .min(odometry_rates.len().saturating_sub(1));
            let (velocity, turn_rate) = odometry_rates.get(step).copied().unwrap_or((0.0, 0.0));
            OdometryReading {
                stamp_secs: stamp0 + t,
                odom_from_robot: sampler.odometry_at(t),
                velocity_m_per_s: velocity,
                turn_rate_rad_per_s: turn_rate,
            }
        })
        .collect();
    let scan_times: Vec<f64> = sample_times(duration, params.scan_rate_hz).collect();
    let truth: Vec<(f64, Se2)> = scan_times
        .iter()
        .map(|&t| (stamp0 + t, sampler.truth_at(t)))
        .collect();
    // 8. Scans.
    let lidar = Lidar::with_caster(start.roadmap.caster().clone(), params.lidar.clone())?;
    let poses: Vec<Se2> = truth.iter().map(|(_, pose)| *pose).collect();
    let lidar_seed = derive_seed(seed, Stream::Lidar, session);
    let scans = lidar.scans(&poses, lidar_seed);
    let records: Vec<ScanRecord> = scans
        .into_iter()
        .zip(&scan_times)
        .map(|(scan, &t)| ScanRecord {
            stamp_secs: stamp0 + t,
            scan,
            odom_from_robot: Some(sampler.odometry_at(t)),
            source_tag: SCAN_SOURCE_TAG.to_owned(),
        })
        .collect();
    let kidnaps = motion
        .kidnaps
        .iter()
        .map(|&(step, from, to)| {
            let t = step as f64 * dt;
            Kidnap {
                scan_index: scan_times.partition_point(|&s| s < t - 1e-9),
                stamp_secs: stamp0 + t,
                from,
                to,
            }
        })
        .collect();
    let slips = slips
        .into_iter()
        .map(|s| SlipEvent {
            span: SlipSpan::Time {
                start_secs: stamp0 + s.start,
                end_secs: stamp0 + s.end,
            },
            kind: s.kind,
            factor: s.factor,
        })
        .collect();
    let mut log_params = BTreeMap::new();
    log_params.insert("mapmerge_sim_world".to_owned(), world.name.clone());
    log_params.insert("mapmerge_sim_seed".to_owned(), seed.to_string());
    log_params.insert("mapmerge_sim_session".to_owned(), index.to_string());
    Ok(SessionData {
        index,
        log: LaserLog {
            odometry,
            scans: records,
            params: log_params,
            skipped_messages: BTreeMap::new(),
        },
        truth,
        kidnaps,
        slips,
        world_changes,
        world,
        start_room: start.room,
        motion: motion.info,
    })
}

/// Sample times `k / rate_hz` in `[0, duration_secs]`.
fn sample_times(duration_secs: f64, rate_hz: f64) -> impl Iterator<Item = f64> {
    let count = (duration_secs * rate_hz + 1e-9).floor() as usize + 1;
    (0..count).map(move |k| k as f64 / rate_hz)
}

/// Poses between simulation steps.
struct Sampler<'a> {
    dt: f64,
    truth: &'a [Se2],
    odometry: &'a [Se2],
    kidnaps: &'a [(usize, Se2, Se2)],
}

impl Sampler<'_> {
    /// The step that starts at or before `t`, and how far into it `t` lies (0..1).
    fn locate(&self, t: f64) -> (usize, f64) {
        let x = t / self.dt;
        let step = (x + 1e-9).floor().max(0.0) as usize;
        let last = self.truth.len().saturating_sub(1);
        if step >= last {
            return (last, 0.0);
        }
        (step, (x - step as f64).clamp(0.0, 1.0))
    }

    fn step_of(&self, t: f64) -> usize {
        self.locate(t).0
    }

    /// True pose at `t`; between a step and a kidnap at the next step, the motion towards
    /// the pose before the jump.
    fn truth_at(&self, t: f64) -> Se2 {
        let (step, fraction) = self.locate(t);
        let a = self.truth[step];
        if fraction < 1e-9 {
            return a;
        }
        let b = self
            .kidnaps
            .iter()
            .find(|(s, _, _)| *s == step + 1)
            .map_or(self.truth[step + 1], |(_, from, _)| *from);
        a.interpolate(&b, fraction)
    }

    /// Odometry pose at `t`.
    fn odometry_at(&self, t: f64) -> Se2 {
        let (step, fraction) = self.locate(t);
        let a = self.odometry[step];
        if fraction < 1e-9 {
            return a;
        }
        a.interpolate(&self.odometry[step + 1], fraction)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_times_cover_the_session_inclusively() {
        let times: Vec<f64> = sample_times(1.0, 10.0).collect();
        assert_eq!(times.len(), 11);
        assert_eq!(times[10], 1.0);
        assert_eq!(sample_times(180.0, 20.0).count(), 3601);
    }

    #[test]
    fn params_validate_and_build() {
        let params = SimParams::default()
            .with_preset_name("warehouse")
            .unwrap()
            .with_sessions(2)
            .with_duration_secs(30.0);
        assert_eq!(params.preset, WorldPreset::Warehouse);
        assert!(params.validate().is_ok());
        assert!(SimParams::default().with_sessions(0).validate().is_err());
        assert!(SimParams::default().with_preset_name("moon").is_err());
        // Sizes are bounded before anything is allocated (issue 67).
        let field = |p: SimParams| match p.validate() {
            Err(SimError::InvalidParams { field, .. }) => field,
            other => panic!("{other:?}"),
        };
        assert_eq!(
            field(SimParams::default().with_sessions(100_000_000)),
            "sessions"
        );
        assert_eq!(
            field(SimParams::default().with_duration_secs(1e12)),
            "duration_secs"
        );
        let mut many_beams = SimParams::default();
        many_beams.lidar.beam_count = u32::MAX as usize;
        assert_eq!(field(many_beams), "lidar.beam_count");
        let mut dense = SimParams::default().with_duration_secs(86_400.0);
        dense.lidar.beam_count = 100_000;
        assert_eq!(field(dense), "duration_secs");
    }
}
