//! Kidnapping: the robot is carried to another place while its odometry goes on as if nothing
//! happened. When to do it, and where to put the robot down (anywhere far enough, or the same
//! spot of a look-alike room, the hardest case for place recognition).

use mapmerge_geometry::{LieGroup, Se2};
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::rng::{uniform, SimRng};
use crate::{Roadmap, SimError, World};

/// Where a kidnapped robot is put down.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum KidnapTarget {
    /// A random free place at least `min_distance_m` away, random heading.
    Random,
    /// When the robot is in a room with look-alike copies: the same pose in a random copy
    /// (the scans before and after the jump look alike); otherwise as `Random`.
    LookAlike,
}

/// When and how often the robot is kidnapped.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct KidnapParams {
    /// Most kidnaps per session (default: 1).
    pub max_per_session: usize,
    /// Probability of each of those kidnaps happening (default: 0.5), so a session has a
    /// binomial number of kidnaps.
    pub probability: f64,
    /// Shortest distance of a `Random` jump (m) (default: 5.0).
    pub min_distance_m: f64,
    /// Shortest time between two kidnaps, and from a kidnap to the start or end of the
    /// session (s) (default: 20.0).
    pub min_gap_secs: f64,
    /// Where the robot is put down (default: `look-alike`, which is `random` in worlds
    /// without look-alike rooms).
    pub target: KidnapTarget,
}

impl Default for KidnapParams {
    fn default() -> Self {
        Self {
            max_per_session: 1,
            probability: 0.5,
            min_distance_m: 5.0,
            min_gap_secs: 20.0,
            target: KidnapTarget::LookAlike,
        }
    }
}

impl KidnapParams {
    /// No kidnaps.
    pub fn none() -> Self {
        Self {
            max_per_session: 0,
            ..Self::default()
        }
    }

    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), SimError> {
        if !(0.0..=1.0).contains(&self.probability) {
            return Err(SimError::InvalidParams {
                field: "kidnap.probability",
                reason: "must lie in [0, 1]".to_owned(),
            });
        }
        if !(self.min_distance_m.is_finite() && self.min_distance_m >= 0.0) {
            return Err(SimError::InvalidParams {
                field: "kidnap.min_distance_m",
                reason: "must be finite and non-negative".to_owned(),
            });
        }
        if !(self.min_gap_secs.is_finite() && self.min_gap_secs >= 0.0) {
            return Err(SimError::InvalidParams {
                field: "kidnap.min_gap_secs",
                reason: "must be finite and non-negative".to_owned(),
            });
        }
        Ok(())
    }
}

/// A kidnap as it happened.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Kidnap {
    /// Index of the first scan taken after the jump (in `SessionData::log.scans`; equal to
    /// the scan count when no scan follows).
    pub scan_index: usize,
    /// When it happened (s, log time).
    pub stamp_secs: f64,
    /// True pose just before the jump (`world_from_robot`).
    pub from: Se2,
    /// True pose just after it.
    pub to: Se2,
}

/// Kidnap times in `(0, duration_secs)` (session time), sorted, `min_gap_secs` apart and from
/// the ends; fewer when they do not fit.
pub(crate) fn schedule_kidnaps(
    rng: &mut SimRng,
    params: &KidnapParams,
    duration_secs: f64,
) -> Vec<f64> {
    let count = (0..params.max_per_session)
        .filter(|_| rng.random::<f64>() < params.probability)
        .count();
    let gap = params.min_gap_secs;
    let mut times: Vec<f64> = Vec::with_capacity(count);
    for _ in 0..count {
        for _ in 0..50 {
            let t = uniform(rng, gap, duration_secs - gap);
            if t > 0.0 && t < duration_secs && times.iter().all(|other| (other - t).abs() >= gap) {
                times.push(t);
                break;
            }
        }
    }
    times.sort_by(f64::total_cmp);
    times
}

/// Where to put the robot down, kidnapped at `from`.
pub(crate) fn kidnap_target(
    rng: &mut SimRng,
    params: &KidnapParams,
    world: &World,
    roadmap: &Roadmap,
    from: &Se2,
) -> Option<Se2> {
    let from_m = from.translation();
    if params.target == KidnapTarget::LookAlike {
        if let Some(room) = world.room_at(&from_m) {
            let copies = world.look_alikes(room.id);
            if !copies.is_empty() {
                let copy = copies[rng.random_range(0..copies.len())];
                let room_from_robot = room.world_from_room.inverse().compose(from);
                let to = copy.world_from_room.compose(&room_from_robot);
                let to_m = to.translation();
                let clear = roadmap.caster().clearance_m(&to_m, 0.2) >= 0.2
                    && !world.is_inside_obstacle(&to_m);
                if clear
                    && roadmap
                        .entry_node(&to_m)
                        .is_some_and(|n| roadmap.is_main(n))
                {
                    return Some(to);
                }
            }
        }
    }
    let nodes = roadmap.main_nodes();
    let far: Vec<usize> = nodes
        .iter()
        .copied()
        .filter(|&n| (roadmap.nodes()[n] - from_m).norm() >= params.min_distance_m)
        .collect();
    let pool = if far.is_empty() { &nodes } else { &far };
    if pool.is_empty() {
        return None;
    }
    let node = pool[rng.random_range(0..pool.len())];
    let p = roadmap.nodes()[node];
    Some(Se2::new(
        p.x,
        p.y,
        uniform(rng, -std::f64::consts::PI, std::f64::consts::PI),
    ))
}
