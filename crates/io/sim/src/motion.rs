//! The robot's true motion: a differential-drive robot that visits rooms one after another,
//! following routes planned on the session's [`Roadmap`], with limited speed, turn rate and
//! accelerations, a pause and a look around in every room it visits, and a safety stop that
//! never lets it move into an obstacle. Kidnaps teleport it; the recorded per-step motion (what
//! the wheels did) never includes the jump.

use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use nalgebra::Vector3;
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::kidnap::{kidnap_target, KidnapParams};
use crate::rng::{uniform, SimRng};
use crate::world::RoomId;
use crate::{Point2, Roadmap, SimError, World};

/// Distance at which an intermediate waypoint counts as reached (m).
const WAYPOINT_RADIUS_M: f64 = 0.2;
/// Distance at which the goal counts as reached (m).
const GOAL_RADIUS_M: f64 = 0.08;
/// Heading error above which the robot stops and turns in place (rad).
const TURN_IN_PLACE_RAD: f64 = 0.8;
/// Proportional gain of the heading controller (1/s).
const HEADING_GAIN: f64 = 2.5;
/// Clearance the safety stop keeps (m), unless the robot is already closer.
const SAFETY_CLEARANCE_M: f64 = 0.1;
/// Safety stops in a row after which the route is given up and planned again.
const STUCK_STEPS: usize = 100;
/// Rooms recently visited that the next goal avoids.
const RECENT_ROOMS: usize = 3;

/// How the robot moves.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RobotParams {
    /// Top speed (m/s) (default: 0.8). Each route is driven at a cruise speed between
    /// `cruise_fraction_min` and 1 times this.
    pub max_speed_m_per_s: f64,
    /// Slowest cruise speed as a fraction of the top speed (default: 0.7).
    pub cruise_fraction_min: f64,
    /// Top turn rate (rad/s) (default: 1.2, about 70°/s).
    pub max_turn_rate_rad_per_s: f64,
    /// Linear acceleration and braking limit (m/s²) (default: 0.6).
    pub max_accel_m_per_s2: f64,
    /// Angular acceleration limit (rad/s²) (default: 2.5).
    pub max_turn_accel_rad_per_s2: f64,
    /// Distance kept from obstacles when planning (m) (default: 0.3: a robot of 0.2 m radius
    /// with a 0.1 m margin). Doors must be wider than twice this.
    pub clearance_m: f64,
    /// Longest pause (looking around) in a visited room (s) (default: 3.0); each pause is
    /// uniform in `[0, dwell_max_secs]`.
    pub dwell_max_secs: f64,
    /// Integration step of the simulation (s) (default: 0.01). Odometry and scans are sampled
    /// from these steps, so it should be well below their periods.
    pub step_secs: f64,
}

impl Default for RobotParams {
    fn default() -> Self {
        Self {
            max_speed_m_per_s: 0.8,
            cruise_fraction_min: 0.7,
            max_turn_rate_rad_per_s: 1.2,
            max_accel_m_per_s2: 0.6,
            max_turn_accel_rad_per_s2: 2.5,
            clearance_m: crate::roadmap::DEFAULT_CLEARANCE_M,
            dwell_max_secs: 3.0,
            step_secs: 0.01,
        }
    }
}

impl RobotParams {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), SimError> {
        let positive = [
            ("robot.max_speed_m_per_s", self.max_speed_m_per_s),
            (
                "robot.max_turn_rate_rad_per_s",
                self.max_turn_rate_rad_per_s,
            ),
            ("robot.max_accel_m_per_s2", self.max_accel_m_per_s2),
            (
                "robot.max_turn_accel_rad_per_s2",
                self.max_turn_accel_rad_per_s2,
            ),
            ("robot.step_secs", self.step_secs),
        ];
        for (field, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(SimError::InvalidParams {
                    field,
                    reason: "must be positive and finite".to_owned(),
                });
            }
        }
        if !(self.cruise_fraction_min > 0.0 && self.cruise_fraction_min <= 1.0) {
            return Err(SimError::InvalidParams {
                field: "robot.cruise_fraction_min",
                reason: "must lie in (0, 1]".to_owned(),
            });
        }
        if !(self.clearance_m.is_finite() && self.clearance_m >= SAFETY_CLEARANCE_M) {
            return Err(SimError::InvalidParams {
                field: "robot.clearance_m",
                reason: format!("must be finite and at least {SAFETY_CLEARANCE_M} m"),
            });
        }
        if !(self.dwell_max_secs.is_finite() && self.dwell_max_secs >= 0.0) {
            return Err(SimError::InvalidParams {
                field: "robot.dwell_max_secs",
                reason: "must be finite and non-negative".to_owned(),
            });
        }
        Ok(())
    }
}

/// What the robot did in a session.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MotionInfo {
    /// Rooms reached, in order (the start room first).
    pub visited_rooms: Vec<RoomId>,
    /// Distance driven (m, true).
    pub distance_m: f64,
    /// Angle turned (rad, true, absolute).
    pub turned_rad: f64,
    /// Steps in which the safety stop cancelled a move (0 when the controller tracks its
    /// routes well).
    pub safety_stops: usize,
    /// Routes given up and planned again (after being stuck, or after a kidnap).
    pub replans: usize,
}

/// The simulated motion of one session.
pub(crate) struct Motion {
    /// True pose at every step time `i · step_secs`, `i = 0..=steps` (after a kidnap at step
    /// `i`, the pose put down).
    pub truth: Vec<Se2>,
    /// True `(distance_m, turn_rad)` of every step, as the wheels turned.
    pub steps: Vec<(f64, f64)>,
    /// `(step, from, to)` of every kidnap: the pose at step `step` was `from` before the jump.
    pub kidnaps: Vec<(usize, Se2, Se2)>,
    /// What happened.
    pub info: MotionInfo,
}

enum Mode {
    Idle,
    Drive {
        waypoints: Vec<Point2>,
        next: usize,
        cruise_m_per_s: f64,
        goal_room: RoomId,
    },
    Dwell {
        until_step: usize,
        turn_rate_rad_per_s: f64,
    },
}

/// Inputs of [`drive`] that stay fixed during a session.
pub(crate) struct DriveSetup<'a> {
    pub world: &'a World,
    pub roadmap: &'a Roadmap,
    pub robot: &'a RobotParams,
    pub kidnap: &'a KidnapParams,
    /// Destination rooms with their reachable roadmap nodes.
    pub destinations: &'a [(RoomId, Vec<usize>)],
}

/// Simulates `step_count` steps from `start`, kidnapping at the given session times.
pub(crate) fn drive(
    setup: &DriveSetup<'_>,
    start: Se2,
    start_room: RoomId,
    step_count: usize,
    kidnap_times_secs: &[f64],
    route_rng: &mut SimRng,
    kidnap_rng: &mut SimRng,
) -> Motion {
    let robot = setup.robot;
    let dt = robot.step_secs;
    let caster = setup.roadmap.caster();
    let mut truth = Vec::with_capacity(step_count + 1);
    let mut steps = Vec::with_capacity(step_count);
    let mut kidnaps = Vec::new();
    let mut info = MotionInfo {
        visited_rooms: vec![start_room],
        ..MotionInfo::default()
    };
    let kidnap_steps: Vec<usize> = kidnap_times_secs
        .iter()
        .map(|t| ((t / dt).ceil() as usize).max(1))
        .collect();
    let mut next_kidnap = 0;
    let mut pose = start;
    let (mut v, mut w) = (0.0f64, 0.0f64);
    let mut mode = Mode::Idle;
    let mut stuck = 0usize;
    let mut clearance = caster.clearance_m(&pose.translation(), SAFETY_CLEARANCE_M);
    truth.push(pose);
    for step in 0..step_count {
        // 1. Decide what to do: pick a goal and a route when idle.
        if let Mode::Idle = mode {
            mode = next_leg(setup, &pose, &info.visited_rooms, route_rng, step);
        }
        // 2. Commanded velocities from the mode, within the acceleration limits.
        let (v_want, w_want) = match &mut mode {
            Mode::Idle => (0.0, 0.0),
            Mode::Dwell {
                until_step,
                turn_rate_rad_per_s,
            } => {
                if step >= *until_step {
                    mode = Mode::Idle;
                    (0.0, 0.0)
                } else {
                    (0.0, *turn_rate_rad_per_s)
                }
            }
            Mode::Drive {
                waypoints,
                next,
                cruise_m_per_s,
                goal_room,
            } => match track(robot, &pose, waypoints, next, *cruise_m_per_s) {
                Some(command) => command,
                None => {
                    info.visited_rooms.push(*goal_room);
                    let until_step = step
                        + (uniform(route_rng, 0.0, robot.dwell_max_secs) / dt).round() as usize;
                    let sign = if route_rng.random::<bool>() {
                        1.0
                    } else {
                        -1.0
                    };
                    let turn_rate_rad_per_s =
                        sign * uniform(route_rng, 0.3, 0.8) * robot.max_turn_rate_rad_per_s;
                    mode = Mode::Dwell {
                        until_step,
                        turn_rate_rad_per_s,
                    };
                    (0.0, 0.0)
                }
            },
        };
        v = approach(v, v_want, robot.max_accel_m_per_s2 * dt);
        w = approach(w, w_want, robot.max_turn_accel_rad_per_s2 * dt);
        // 3. Move (exact unicycle arc), unless that would bring the robot into an obstacle.
        let (mut distance_m, turn_rad) = (v * dt, w * dt);
        let mut moved = pose.compose(&Se2::exp(&Vector3::new(distance_m, 0.0, turn_rad)));
        if distance_m != 0.0 {
            let (from_m, to_m) = (pose.translation(), moved.translation());
            let new_clearance = caster.clearance_m(&to_m, SAFETY_CLEARANCE_M);
            let safe = caster.is_path_free(&from_m, &to_m)
                && new_clearance >= clearance.min(SAFETY_CLEARANCE_M);
            if safe {
                clearance = new_clearance;
                stuck = 0;
            } else {
                distance_m = 0.0;
                v = 0.0;
                moved = Se2::new(pose.x_m, pose.y_m, pose.theta_rad + turn_rad);
                info.safety_stops += 1;
                stuck += 1;
                if stuck >= STUCK_STEPS {
                    stuck = 0;
                    info.replans += 1;
                    mode = Mode::Idle;
                }
            }
        }
        steps.push((distance_m, turn_rad));
        info.distance_m += distance_m.abs();
        info.turned_rad += turn_rad.abs();
        pose = moved;
        // 4. Kidnap: the pose jumps, the wheels did not turn for it.
        if next_kidnap < kidnap_steps.len() && kidnap_steps[next_kidnap] <= step + 1 {
            next_kidnap += 1;
            if let Some(to) =
                kidnap_target(kidnap_rng, setup.kidnap, setup.world, setup.roadmap, &pose)
            {
                kidnaps.push((step + 1, pose, to));
                pose = to;
                v = 0.0;
                w = 0.0;
                stuck = 0;
                clearance = caster.clearance_m(&pose.translation(), SAFETY_CLEARANCE_M);
                if let Mode::Drive { .. } = mode {
                    info.replans += 1;
                }
                mode = Mode::Idle;
            }
        }
        truth.push(pose);
    }
    Motion {
        truth,
        steps,
        kidnaps,
        info,
    }
}

/// The next leg: a route to a random node of a room not visited recently; a short look
/// around on the spot when no route is found.
fn next_leg(
    setup: &DriveSetup<'_>,
    pose: &Se2,
    visited: &[RoomId],
    rng: &mut SimRng,
    step: usize,
) -> Mode {
    let robot = setup.robot;
    let here = setup.world.room_at(&pose.translation()).map(|r| r.id);
    let recent: Vec<RoomId> = visited
        .iter()
        .rev()
        .take(RECENT_ROOMS)
        .copied()
        .chain(here)
        .collect();
    let fresh: Vec<&(RoomId, Vec<usize>)> = setup
        .destinations
        .iter()
        .filter(|(room, _)| !recent.contains(room))
        .collect();
    let pool: Vec<&(RoomId, Vec<usize>)> = if fresh.is_empty() {
        setup
            .destinations
            .iter()
            .filter(|(room, _)| Some(*room) != here)
            .collect()
    } else {
        fresh
    };
    for _ in 0..5 {
        if pool.is_empty() {
            break;
        }
        let (room, nodes) = pool[rng.random_range(0..pool.len())];
        if nodes.is_empty() {
            continue;
        }
        let goal = setup.roadmap.nodes()[nodes[rng.random_range(0..nodes.len())]];
        if let Some(waypoints) = setup.roadmap.plan(&pose.translation(), &goal) {
            return Mode::Drive {
                waypoints,
                next: 1,
                cruise_m_per_s: robot.max_speed_m_per_s
                    * uniform(rng, robot.cruise_fraction_min, 1.0),
                goal_room: *room,
            };
        }
    }
    Mode::Dwell {
        until_step: step + (1.0 / robot.step_secs).round() as usize,
        turn_rate_rad_per_s: 0.5 * robot.max_turn_rate_rad_per_s,
    }
}

/// Velocities towards the current waypoint (advancing past reached ones), or `None` when the
/// goal is reached. Speed drops before sharp corners so the robot turns close to its route.
fn track(
    robot: &RobotParams,
    pose: &Se2,
    waypoints: &[Point2],
    next: &mut usize,
    cruise_m_per_s: f64,
) -> Option<(f64, f64)> {
    let position = pose.translation();
    loop {
        let target = *waypoints.get(*next)?;
        let last = *next + 1 == waypoints.len();
        let distance = (target - position).norm();
        let radius = if last {
            GOAL_RADIUS_M
        } else {
            WAYPOINT_RADIUS_M
        };
        if distance < radius {
            *next += 1;
            if last {
                return None;
            }
            continue;
        }
        let corner_speed = if last {
            0.0
        } else {
            let before = target - waypoints[*next - 1];
            let after = waypoints[*next + 1] - target;
            let turn = wrap_angle_rad(after.y.atan2(after.x) - before.y.atan2(before.x)).abs();
            (cruise_m_per_s * (0.5 * (1.0 + turn.cos())).powi(2)).max(0.1)
        };
        let braking = (corner_speed * corner_speed
            + 2.0 * robot.max_accel_m_per_s2 * (distance - radius).max(0.0))
        .sqrt();
        let error =
            wrap_angle_rad((target.y - position.y).atan2(target.x - position.x) - pose.theta_rad);
        let heading_factor = (1.0 - error.abs() / TURN_IN_PLACE_RAD).max(0.0);
        let v = cruise_m_per_s.min(braking) * heading_factor;
        let w = (HEADING_GAIN * error).clamp(
            -robot.max_turn_rate_rad_per_s,
            robot.max_turn_rate_rad_per_s,
        );
        return Some((v, w));
    }
}

/// `value` moved towards `target` by at most `max_change`.
fn approach(value: f64, target: f64, max_change: f64) -> f64 {
    value + (target - value).clamp(-max_change, max_change)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn approach_is_rate_limited() {
        assert_eq!(approach(0.0, 1.0, 0.1), 0.1);
        assert_eq!(approach(0.0, -1.0, 0.1), -0.1);
        assert_eq!(approach(0.95, 1.0, 0.1), 1.0);
    }

    #[test]
    fn tracking_reaches_the_goal_and_stops() {
        let robot = RobotParams::default();
        let waypoints = vec![
            Point2::new(0.0, 0.0),
            Point2::new(2.0, 0.0),
            Point2::new(2.0, 2.0),
        ];
        let mut pose = Se2::new(0.0, 0.0, 0.0);
        let mut next = 1;
        let (mut v, mut w) = (0.0, 0.0);
        let dt = robot.step_secs;
        let mut steps = 0;
        while let Some((v_want, w_want)) = track(&robot, &pose, &waypoints, &mut next, 0.8) {
            v = approach(v, v_want, robot.max_accel_m_per_s2 * dt);
            w = approach(w, w_want, robot.max_turn_accel_rad_per_s2 * dt);
            pose = pose.compose(&Se2::exp(&Vector3::new(v * dt, 0.0, w * dt)));
            // Corners are cut by less than the waypoint radius.
            let p = pose.translation();
            let off = crate::shapes::point_segment_distance(&p, &waypoints[0], &waypoints[1]).min(
                crate::shapes::point_segment_distance(&p, &waypoints[1], &waypoints[2]),
            );
            assert!(off < WAYPOINT_RADIUS_M, "off route by {off} at {pose:?}");
            steps += 1;
            assert!(steps < 5000, "never arrived");
        }
        assert!((pose.translation() - Point2::new(2.0, 2.0)).norm() < GOAL_RADIUS_M + 0.05);
    }
}
