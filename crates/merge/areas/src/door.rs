//! Door passing from laser scans (Ehlers et al., Sec. II-B): of three criteria, (1) a
//! passway in front, (2) a passway behind and (3) a change of the wall distances, at least
//! two must hold.
//!
//! A passway is what an open doorway looks like in the range derivative over the scan angle:
//! a jump away from the robot at one doorpost and a jump back at the other, the posts a door's
//! width apart, with longer ranges between them (Fig. 4a). The wall distances are the extents
//! (min/max x and y, map frame) of the scan after an averaging low-pass over the beams, low-pass
//! filtered again over time; a door changes them quickly (Fig. 4b).
//!
//! Departure from the paper, for robustness: a passing is declared only once the robot's path
//! has crossed the segment between the doorposts (map frame, from the pose the detector is
//! given; when a closer view moves the posts, the steps since the last view are checked
//! again). Criterion (1) must then have been seen before the crossing, (2) after it, and (3)
//! compares the box before the crossing with the box after it
//! ([`crate::EnvironmentParams::change_travel_m`]). A front-only scanner (less than
//! 360°) never sees (2); it then needs (1) and (3).

use std::collections::VecDeque;
use std::f64::consts::PI;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_params::{Checker, Real, Validate};
use mapmerge_scan::{LaserScan, Point2};
use serde::{Deserialize, Serialize};

use crate::environment::{Environment, Extents};
use crate::error::AreasError;

/// Parameters of [`DoorDetector`], one default for every site.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DoorParams {
    /// A range jump between neighbouring beams of at least this marks a doorpost (m)
    /// (default: 0.5).
    pub jump_m: f64,
    /// Narrowest doorway (m) (default: 0.6).
    pub min_width_m: f64,
    /// Widest doorway (m) (default: 1.6).
    pub max_width_m: f64,
    /// Doorposts farther than this are not looked at (m) (default: 4).
    pub max_post_range_m: f64,
    /// Half the angle of the front sector, and of the back sector, around the robot's heading
    /// and its reverse (rad) (default: 60°).
    pub sector_half_angle_rad: f64,
    /// A doorway's posts end walls: on each post's outer side the returns must continue, in
    /// line with the other post, for at least this long (m) (default: 0.3; 0 checks nothing).
    /// Gaps between pillars or pieces of furniture mostly fail it.
    pub min_wall_m: f64,
    /// Largest angle between a post's wall and the line through both posts (rad) (default:
    /// 0.6, about 34°; chosen on the simulator's tuning seeds 1–20: 25° lost 4 % recall).
    pub max_wall_angle_rad: f64,
    /// Two sightings whose doorways' centres lie within this are one door (m) (default: 0.5).
    pub match_m: f64,
    /// The doorposts' segment is widened by this on both ends when checking that the path
    /// crossed it (m) (default: 0.15).
    pub crossing_margin_m: f64,
    /// A crossed door is forgotten when (2) or (3) have not joined (1) within this much
    /// travel (m) (default: 2).
    pub after_crossing_m: f64,
    /// A door not crossed within this much travel of its last sighting is forgotten (m)
    /// (default: 6).
    pub forget_after_m: f64,
    /// A door forgotten without ever being passed, seen in at least this many scans, is
    /// reported as a door not passed ([`UnpassedDoor`], a link-point candidate) (default: 5).
    pub candidate_min_sightings: usize,
    /// Environment: extents and the configuration choice ([`Environment`]).
    pub environment: crate::EnvironmentParams,
}

impl Default for DoorParams {
    fn default() -> Self {
        Self {
            jump_m: 0.5,
            min_width_m: 0.6,
            max_width_m: 1.6,
            max_post_range_m: 4.0,
            sector_half_angle_rad: 60f64.to_radians(),
            min_wall_m: 0.3,
            max_wall_angle_rad: 0.6,
            match_m: 0.5,
            crossing_margin_m: 0.15,
            after_crossing_m: 2.0,
            forget_after_m: 6.0,
            candidate_min_sightings: 5,
            environment: crate::EnvironmentParams::default(),
        }
    }
}

impl Validate for DoorParams {
    fn check(&self, check: &mut Checker) {
        check
            .real("jump_m", self.jump_m, Real::positive())
            .real("min_width_m", self.min_width_m, Real::positive())
            .real("max_width_m", self.max_width_m, Real::positive())
            .rule(
                "max_width_m",
                self.max_width_m,
                self.max_width_m >= self.min_width_m,
                "must be at least min_width_m",
            )
            .real("max_post_range_m", self.max_post_range_m, Real::positive())
            .real(
                "sector_half_angle_rad",
                self.sector_half_angle_rad,
                Real::positive_up_to(PI),
            )
            .real("min_wall_m", self.min_wall_m, Real::non_negative())
            .real(
                "max_wall_angle_rad",
                self.max_wall_angle_rad,
                Real::positive_up_to(PI),
            )
            .real("match_m", self.match_m, Real::positive())
            .real(
                "crossing_margin_m",
                self.crossing_margin_m,
                Real::non_negative(),
            )
            .real("after_crossing_m", self.after_crossing_m, Real::positive())
            .real("forget_after_m", self.forget_after_m, Real::positive())
            .size(
                "candidate_min_sightings",
                self.candidate_min_sightings,
                0,
                100_000,
            )
            .nested("environment", &self.environment);
    }
}

impl DoorParams {
    /// Checks every parameter ([`Validate`]).
    pub fn validate(&self) -> Result<(), AreasError> {
        Ok(Validate::validate(self)?)
    }
}

/// A doorway seen in one scan: its two posts (robot frame, m).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DoorSighting {
    /// The posts, in beam order.
    pub posts_m: [Point2; 2],
}

impl DoorSighting {
    /// The doorway's centre.
    pub fn center_m(&self) -> Point2 {
        0.5 * (self.posts_m[0] + self.posts_m[1])
    }

    /// The doorway's width.
    pub fn width_m(&self) -> f64 {
        (self.posts_m[1] - self.posts_m[0]).norm()
    }
}

/// Which of the three criteria held for a passing.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Criteria {
    /// (1) A passway in front before the crossing.
    pub front: bool,
    /// (2) A passway behind after it.
    pub back: bool,
    /// (3) The wall distances changed around it.
    pub extents: bool,
}

impl Criteria {
    /// How many hold.
    pub fn count(&self) -> usize {
        usize::from(self.front) + usize::from(self.back) + usize::from(self.extents)
    }
}

/// A detected door passing.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DoorPassingDetection {
    /// The scan at which it was declared (the number of scans given before it).
    pub scan: usize,
    /// The scan at which the path crossed the doorway.
    pub crossing_scan: usize,
    /// The doorway's centre in the robot frame of `scan` (m).
    pub center_in_robot_m: Point2,
    /// … and in the frame of the poses given (m).
    pub center_in_map_m: Point2,
    /// The doorway's width (m).
    pub width_m: f64,
    /// The criteria that held.
    pub criteria: Criteria,
    /// The environment behind the door when it was declared.
    pub environment: Environment,
}

/// A door seen but never passed (a link-point candidate, Ehlers et al. Sec. II-A): its posts
/// in the robot frame of the scan that saw it closest.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct UnpassedDoor {
    /// The scan of the closest sighting.
    pub scan: usize,
    /// The posts in that scan's robot frame (m).
    pub posts_in_robot_m: [Point2; 2],
    /// Scans it was seen in.
    pub sightings: usize,
}

impl UnpassedDoor {
    /// The doorway's centre in the robot frame of `scan`.
    pub fn center_in_robot_m(&self) -> Point2 {
        0.5 * (self.posts_in_robot_m[0] + self.posts_in_robot_m[1])
    }
}

/// A doorway being tracked.
#[derive(Clone, Debug)]
struct Candidate {
    /// Posts (map frame) of the closest sighting so far.
    posts_map: [Point2; 2],
    /// The range of that sighting's centre (closer sightings place the posts better).
    sighting_range_m: f64,
    /// That sighting's scan and posts in its robot frame.
    closest: (usize, [Point2; 2]),
    /// Scans it was seen in.
    sightings: usize,
    /// Whether a passing of it was declared.
    passed: bool,
    front: bool,
    back: bool,
    /// Scan and travel (m) of the crossing.
    crossed: Option<(usize, f64)>,
    last_seen_travel_m: f64,
}

impl Candidate {
    fn center(&self) -> Point2 {
        0.5 * (self.posts_map[0] + self.posts_map[1])
    }

    /// As a door not passed, when it is one: never passed nor crossed, seen `min` times.
    fn unpassed(&self, min: usize) -> Option<UnpassedDoor> {
        (!self.passed && self.crossed.is_none() && self.sightings >= min).then_some(UnpassedDoor {
            scan: self.closest.0,
            posts_in_robot_m: self.closest.1,
            sightings: self.sightings,
        })
    }
}

/// Detects door passings from a stream of scans and poses ([`DoorDetector::push`]).
#[derive(Clone, Debug)]
pub struct DoorDetector {
    params: DoorParams,
    scans: usize,
    travel_m: f64,
    /// Recent positions (map frame) with their scan and travel, for crossings found late.
    path: VecDeque<(usize, f64, Point2)>,
    candidates: Vec<Candidate>,
    extents: Extents,
    /// Doors forgotten without being passed, not yet taken.
    unpassed: Vec<UnpassedDoor>,
}

impl DoorDetector {
    /// A detector with `params`.
    pub fn new(params: DoorParams) -> Result<Self, AreasError> {
        params.validate()?;
        let extents = Extents::new(params.environment.clone(), params.forget_after_m);
        Ok(Self {
            params,
            scans: 0,
            travel_m: 0.0,
            path: VecDeque::new(),
            candidates: Vec::new(),
            extents,
            unpassed: Vec::new(),
        })
    }

    /// The doors forgotten since the last call without ever being passed, seen often enough
    /// ([`DoorParams::candidate_min_sightings`]).
    pub fn take_unpassed(&mut self) -> Vec<UnpassedDoor> {
        std::mem::take(&mut self.unpassed)
    }

    /// Ends the log: every door still tracked that was never passed, seen often enough, with
    /// those forgotten and not yet taken.
    pub fn finish(mut self) -> Vec<UnpassedDoor> {
        let min = self.params.candidate_min_sightings;
        let rest: Vec<UnpassedDoor> = self
            .candidates
            .iter()
            .filter_map(|c| c.unpassed(min))
            .collect();
        self.unpassed.extend(rest);
        self.unpassed
    }

    /// Scans given so far.
    pub fn scans(&self) -> usize {
        self.scans
    }

    /// Takes the next scan with the robot's pose (`map_from_robot`: odometry or a tracker's
    /// estimate; only its motion over a few metres matters) and returns the passing it
    /// completes, if any.
    pub fn push(&mut self, map_from_robot: &Se2, scan: &LaserScan) -> Option<DoorPassingDetection> {
        let scan_index = self.scans;
        self.scans += 1;
        let position = map_from_robot.translation();
        let previous = self.path.back().map(|(_, _, p)| *p);
        if let Some(previous) = previous {
            self.travel_m += (position - previous).norm();
        }
        let travel = self.travel_m;
        self.path.push_back((scan_index, travel, position));
        while self
            .path
            .front()
            .is_some_and(|(_, t, _)| travel - t > self.params.forget_after_m)
        {
            self.path.pop_front();
        }
        // Criterion (3)'s boxes.
        self.extents.push(map_from_robot, scan, travel);
        // Criteria (1) and (2): sightings in front and behind.
        let sightings = passways(scan, &self.params);
        let half = self.params.sector_half_angle_rad;
        for sighting in &sightings {
            let center = sighting.center_m();
            let bearing = center.y.atan2(center.x);
            let front = bearing.abs() <= half;
            let back = bearing.abs() >= std::f64::consts::PI - half;
            if front || back {
                self.observe(scan_index, map_from_robot, sighting, front, travel);
            }
        }
        // Crossings by this step.
        if let Some(previous) = previous {
            let margin = self.params.crossing_margin_m;
            for candidate in self.candidates.iter_mut().filter(|c| c.crossed.is_none()) {
                if crosses(previous, position, &candidate.posts_map, margin) {
                    candidate.crossed = Some((scan_index, travel));
                }
            }
        }
        let declared = self.declare(map_from_robot, scan_index);
        let forget = self.params.forget_after_m;
        let window = self.params.after_crossing_m;
        let min = self.params.candidate_min_sightings;
        let unpassed = &mut self.unpassed;
        self.candidates.retain(|c| {
            let keep = match c.crossed {
                Some((_, crossed)) => travel - crossed <= window,
                None => travel - c.last_seen_travel_m <= forget,
            };
            if !keep {
                unpassed.extend(c.unpassed(min));
            }
            keep
        });
        declared
    }

    /// Files a sighting (robot frame) under its candidate, or starts one.
    fn observe(
        &mut self,
        scan: usize,
        map_from_robot: &Se2,
        sighting: &DoorSighting,
        front: bool,
        travel: f64,
    ) {
        let posts = sighting.posts_m.map(|p| map_from_robot.transform_point(&p));
        let center = 0.5 * (posts[0] + posts[1]);
        let range = sighting.center_m().norm();
        let margin = self.params.crossing_margin_m;
        let matched = self
            .candidates
            .iter_mut()
            .filter(|c| (c.center() - center).norm() <= self.params.match_m)
            .min_by(|a, b| {
                (a.center() - center)
                    .norm()
                    .total_cmp(&(b.center() - center).norm())
            });
        let candidate = match matched {
            Some(candidate) => candidate,
            None => {
                self.candidates.push(Candidate {
                    posts_map: posts,
                    sighting_range_m: range,
                    closest: (scan, sighting.posts_m),
                    sightings: 0,
                    passed: false,
                    front: false,
                    back: false,
                    crossed: None,
                    last_seen_travel_m: travel,
                });
                let Some(candidate) = self.candidates.last_mut() else {
                    return;
                };
                // Seen first behind: the crossing may already lie on the path.
                if !front {
                    candidate.crossed = crossing_on_path(&self.path, &posts, margin, None);
                }
                candidate
            }
        };
        candidate.sightings += 1;
        if range < candidate.sighting_range_m && candidate.crossed.is_none() {
            candidate.posts_map = posts;
            candidate.sighting_range_m = range;
            candidate.closest = (scan, sighting.posts_m);
            // A closer view moves the posts (a wall's near or far face): the path since the
            // last view may have crossed them already.
            candidate.crossed = crossing_on_path(
                &self.path,
                &posts,
                margin,
                Some(candidate.last_seen_travel_m),
            );
        }
        candidate.last_seen_travel_m = travel;
        match (front, candidate.crossed.is_some()) {
            (true, false) => candidate.front = true,
            (false, true) => candidate.back = true,
            _ => {}
        }
    }

    /// The first crossed candidate with two criteria, declared; the door is kept, and a later
    /// passing of it starts afresh.
    fn declare(&mut self, map_from_robot: &Se2, scan: usize) -> Option<DoorPassingDetection> {
        let extents = &self.extents;
        let criteria_of = |c: &Candidate| {
            let (_, crossed) = c.crossed?;
            Some(Criteria {
                front: c.front,
                back: c.back,
                extents: extents.changed_around(crossed) == Some(true),
            })
        };
        let (position, criteria) = self
            .candidates
            .iter()
            .enumerate()
            .find_map(|(i, c)| criteria_of(c).filter(|k| k.count() >= 2).map(|k| (i, k)))?;
        let candidate = self.candidates.get_mut(position)?;
        let (crossing_scan, _) = candidate.crossed?;
        let center = candidate.center();
        let detection = DoorPassingDetection {
            scan,
            crossing_scan,
            center_in_robot_m: map_from_robot.inverse().transform_point(&center),
            center_in_map_m: center,
            width_m: (candidate.posts_map[1] - candidate.posts_map[0]).norm(),
            criteria,
            environment: self.extents.environment(map_from_robot),
        };
        // The door stays known (its sightings are not a new door) and starts afresh.
        candidate.passed = true;
        candidate.crossed = None;
        candidate.front = false;
        candidate.back = false;
        Some(detection)
    }
}

/// The first step of `path` (scan, travel, position) that crosses `posts`, of those from
/// `since_travel_m` on (all without it): the scan and travel it ends at.
fn crossing_on_path(
    path: &VecDeque<(usize, f64, Point2)>,
    posts: &[Point2; 2],
    margin_m: f64,
    since_travel_m: Option<f64>,
) -> Option<(usize, f64)> {
    path.iter()
        .zip(path.iter().skip(1))
        .filter(|(_, b)| since_travel_m.is_none_or(|t| b.1 >= t))
        .find(|(a, b)| crosses(a.2, b.2, posts, margin_m))
        .map(|(_, b)| (b.0, b.1))
}

/// Whether the step `a → b` crosses the segment between `posts`, widened by `margin_m` on
/// both ends.
fn crosses(a: Point2, b: Point2, posts: &[Point2; 2], margin_m: f64) -> bool {
    let along = posts[1] - posts[0];
    let length = along.norm();
    if length <= 0.0 {
        return false;
    }
    let unit = along / length;
    let (p, q) = (posts[0] - unit * margin_m, posts[1] + unit * margin_m);
    let cross = |u: Point2, v: Point2| u.x * v.y - u.y * v.x;
    let (d1, d2) = (cross(q - p, a - p), cross(q - p, b - p));
    let (d3, d4) = (cross(b - a, p - a), cross(b - a, q - a));
    (d1 < 0.0) != (d2 < 0.0) && (d3 < 0.0) != (d4 < 0.0)
}

/// Every passway of one scan (robot frame): a jump away at one post, a jump back at the
/// other, longer ranges between, the posts a door's width apart and near enough. A jump back
/// to what still lies beyond the first post (the room behind the doorway in steps) does not
/// end the doorway.
pub fn passways(scan: &LaserScan, params: &DoorParams) -> Vec<DoorSighting> {
    let n = scan.len();
    if n < 3 {
        return Vec::new();
    }
    // No return: far (the beam went through).
    let far = f64::from(scan.range_max_m);
    let ranges: Vec<f64> = scan
        .ranges_m
        .iter()
        .map(|r| {
            if scan.is_return(*r) {
                f64::from(*r)
            } else {
                far
            }
        })
        .collect();
    let point = |i: usize| {
        let angle = scan.beam_angle_rad(i);
        let r = ranges.get(i).copied().unwrap_or(far);
        scan.robot_from_sensor
            .transform_point(&Point2::new(r * angle.cos(), r * angle.sin()))
    };
    let full_circle = (scan.angle_increment_rad.abs() * n as f64) >= std::f64::consts::TAU - 1e-6;
    let next = |i: usize| {
        if i + 1 < n {
            Some(i + 1)
        } else if full_circle {
            Some(0)
        } else {
            None
        }
    };
    let previous = |i: usize| {
        if i > 0 {
            Some(i - 1)
        } else if full_circle {
            Some(n - 1)
        } else {
            None
        }
    };
    // A doorway spans at most this many beams (its width seen from the nearest allowed
    // distance, with a margin).
    let max_span = {
        let step = scan.angle_increment_rad.abs().max(1e-6);
        let angle = 2.0 * (params.max_width_m / (2.0 * 0.3)).atan();
        ((angle / step).ceil() as usize).clamp(1, n / 2)
    };
    let mut sightings = Vec::new();
    for i in 0..n {
        let Some(i1) = next(i) else { break };
        let (near, after) = (ranges[i], ranges[i1]);
        // Post at i: a jump away.
        if after - near < params.jump_m || near > params.max_post_range_m {
            continue;
        }
        let post_a = point(i);
        let mut shortest_between = after;
        let mut k = i1;
        for _ in 0..max_span {
            let Some(k1) = next(k) else { break };
            let (inside, back) = (ranges[k], ranges[k1]);
            // Post at k1: a jump back.
            if inside - back >= params.jump_m {
                if back <= params.max_post_range_m
                    && shortest_between >= near.max(back) + 0.5 * params.jump_m
                {
                    let sighting = DoorSighting {
                        posts_m: [post_a, point(k1)],
                    };
                    let width = sighting.width_m();
                    if (params.min_width_m..=params.max_width_m).contains(&width)
                        && ends_walls(&sighting, i, k1, &point, &previous, &next, params)
                    {
                        sightings.push(sighting);
                        break;
                    }
                }
                // A jump back to what still lies well beyond the first post is the room
                // behind the doorway (furniture, a nearer wall), not the second post: look on.
                if back < near + params.jump_m {
                    break;
                }
            }
            shortest_between = shortest_between.min(back);
            k = k1;
        }
    }
    sightings
}

/// Whether both posts of `sighting` (beams `a` and `b`) end walls in line with the doorway:
/// walking outward from each post (before `a`, after `b`), the returns stay continuous for
/// `min_wall_m` and run away from the other post within `max_wall_angle_rad` of the line
/// through both.
fn ends_walls(
    sighting: &DoorSighting,
    a: usize,
    b: usize,
    point: &impl Fn(usize) -> Point2,
    previous: &impl Fn(usize) -> Option<usize>,
    next: &impl Fn(usize) -> Option<usize>,
    params: &DoorParams,
) -> bool {
    if params.min_wall_m <= 0.0 {
        return true;
    }
    let [post_a, post_b] = sighting.posts_m;
    let door = post_b - post_a;
    let Some(door_unit) = door.try_normalize(1e-9) else {
        return false;
    };
    // A wall's returns are closer together than this (m): the beam spacing there, with room
    // for a grazing view.
    let continuous = |p: &Point2, q: &Point2| (p - q).norm() <= 0.25;
    let wall = |start: usize, post: Point2, step: &dyn Fn(usize) -> Option<usize>, away: Point2| {
        let (mut last, mut index) = (post, start);
        for _ in 0..64 {
            let Some(j) = step(index) else { return false };
            let p = point(j);
            if !continuous(&p, &last) {
                return false;
            }
            let run = p - post;
            if run.norm() >= params.min_wall_m {
                let cos = run.dot(&away) / run.norm();
                return cos >= params.max_wall_angle_rad.cos();
            }
            (last, index) = (p, j);
        }
        false
    };
    wall(a, post_a, previous, -door_unit) && wall(b, post_b, next, door_unit)
}

#[cfg(test)]
pub(crate) mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    /// A 360° scan from −π, one beam per range.
    pub(crate) fn full_circle(ranges_m: Vec<f32>) -> LaserScan {
        LaserScan {
            angle_min_rad: -std::f64::consts::PI,
            angle_increment_rad: std::f64::consts::TAU / ranges_m.len().max(1) as f64,
            range_min_m: 0.05,
            range_max_m: 30.0,
            ranges_m,
            robot_from_sensor: Se2::identity(),
        }
    }

    /// A 360-beam scan from the origin (robot frame) of a wall at x = `wall_x` with a 1 m
    /// doorway centred on y = 0, and a back wall 8 m beyond it; other beams hit a 3 m circle.
    fn doorway_scan(wall_x: f64) -> LaserScan {
        let n = 360;
        let increment = std::f64::consts::TAU / n as f64;
        let ranges: Vec<f32> = (0..n)
            .map(|i| {
                let angle = -std::f64::consts::PI + i as f64 * increment;
                let (s, c) = angle.sin_cos();
                if c > 1e-6 {
                    let y_at_wall = wall_x * s / c;
                    if y_at_wall.abs() <= 0.5 {
                        return ((wall_x + 8.0) / c) as f32;
                    }
                    let r = wall_x / c;
                    if r <= 3.0 {
                        return r as f32;
                    }
                }
                3.0
            })
            .collect();
        full_circle(ranges)
    }

    #[test]
    fn a_doorway_in_front_is_one_passway_a_door_wide() {
        let params = DoorParams::default();
        let sightings = passways(&doorway_scan(1.5), &params);
        assert_eq!(sightings.len(), 1, "{sightings:?}");
        let s = sightings[0];
        assert!((s.width_m() - 1.0).abs() < 0.1, "width {}", s.width_m());
        assert!((s.center_m() - Point2::new(1.5, 0.0)).norm() < 0.1);
    }

    #[test]
    fn a_doorway_with_the_room_behind_it_in_steps_is_one_passway() {
        // Behind half of the doorway a box 2.5 m beyond the wall: a jump back inside the
        // doorway, still well beyond the first post.
        let mut scan = doorway_scan(1.5);
        let n = scan.len();
        for i in 0..n {
            let angle = scan.beam_angle_rad(i);
            let (s, c) = angle.sin_cos();
            if c > 1e-6 && (0.0..=0.5).contains(&(1.5 * s / c)) {
                scan.ranges_m[i] = (4.0 / c) as f32;
            }
        }
        let sightings = passways(&scan, &DoorParams::default());
        assert_eq!(sightings.len(), 1, "{sightings:?}");
        assert!((sightings[0].width_m() - 1.0).abs() < 0.1);
        assert!((sightings[0].center_m() - Point2::new(1.5, 0.0)).norm() < 0.1);
    }

    #[test]
    fn a_door_seen_and_not_passed_is_reported_at_the_end() {
        let scan = doorway_scan(1.5);
        let mut detector = DoorDetector::new(DoorParams::default()).unwrap();
        for k in 0..10 {
            // Standing still, then a step sideways: seen in front, never crossed.
            let pose = Se2::new(0.0, 0.01 * k as f64, 0.0);
            assert!(detector.push(&pose, &scan).is_none());
        }
        assert!(detector.take_unpassed().is_empty(), "still tracked");
        let doors = detector.finish();
        assert_eq!(doors.len(), 1, "{doors:?}");
        assert_eq!(doors[0].sightings, 10);
        assert!((doors[0].center_in_robot_m() - Point2::new(1.5, 0.0)).norm() < 0.1);
        // Seen too few times: no candidate.
        let mut brief = DoorDetector::new(DoorParams::default()).unwrap();
        brief.push(&Se2::identity(), &scan);
        assert!(brief.finish().is_empty());
    }

    #[test]
    fn a_crossing_on_the_path_is_found_from_a_given_travel_on() {
        let posts = [Point2::new(1.0, -0.5), Point2::new(1.0, 0.5)];
        let path: VecDeque<(usize, f64, Point2)> = (0..6)
            .map(|k| (k, 0.3 * k as f64, Point2::new(0.3 * k as f64, 0.0)))
            .collect();
        // The step 3 → 4 (x 0.9 → 1.2) crosses.
        assert_eq!(crossing_on_path(&path, &posts, 0.0, None), Some((4, 1.2)));
        assert_eq!(
            crossing_on_path(&path, &posts, 0.0, Some(0.9)),
            Some((4, 1.2))
        );
        assert_eq!(crossing_on_path(&path, &posts, 0.0, Some(1.3)), None);
    }

    #[test]
    fn a_plain_wall_and_a_far_doorway_are_no_passways() {
        let params = DoorParams::default();
        let plain = full_circle(vec![2.0; 360]);
        assert!(passways(&plain, &params).is_empty());
        let far = DoorParams {
            max_post_range_m: 1.0,
            ..DoorParams::default()
        };
        assert!(passways(&doorway_scan(1.5), &far).is_empty());
    }

    #[test]
    fn crossing_between_the_posts_and_beside_them() {
        let posts = [Point2::new(1.0, -0.5), Point2::new(1.0, 0.5)];
        assert!(crosses(
            Point2::new(0.9, 0.0),
            Point2::new(1.1, 0.1),
            &posts,
            0.0
        ));
        assert!(!crosses(
            Point2::new(0.9, 0.8),
            Point2::new(1.1, 0.8),
            &posts,
            0.15
        ));
        assert!(crosses(
            Point2::new(0.9, 0.6),
            Point2::new(1.1, 0.6),
            &posts,
            0.15
        ));
        assert!(!crosses(
            Point2::new(0.2, 0.0),
            Point2::new(0.8, 0.0),
            &posts,
            0.15
        ));
    }

    #[test]
    fn bad_parameters_are_refused() {
        assert!(DoorParams::default().validate().is_ok());
        let refused = |params: DoorParams| match DoorDetector::new(params) {
            Err(AreasError::Params(e)) => e.field,
            other => panic!("{other:?}"),
        };
        let bad = DoorParams {
            max_width_m: 0.5,
            ..DoorParams::default()
        };
        assert_eq!(refused(bad), "max_width_m");
        let nan = DoorParams {
            jump_m: f64::NAN,
            ..DoorParams::default()
        };
        assert_eq!(refused(nan), "jump_m");
        let negative = DoorParams {
            crossing_margin_m: -0.1,
            ..DoorParams::default()
        };
        assert_eq!(refused(negative), "crossing_margin_m");
        let sightings = DoorParams {
            candidate_min_sightings: usize::MAX,
            ..DoorParams::default()
        };
        assert_eq!(refused(sightings), "candidate_min_sightings");
        let mut environment = DoorParams::default();
        environment.environment.low_pass = 0.0;
        assert_eq!(refused(environment), "environment.low_pass");
    }
}
