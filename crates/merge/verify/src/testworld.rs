//! Hand-made worlds for the detectors' tests: wall segments, a 2D lidar ray-cast against them,
//! and merged maps built from scans taken at true poses but placed by (possibly wrong) merges.

use std::sync::Arc;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::NodeId;
use mapmerge_scan::Point2;

use crate::{DetectorScan, MergedMap};

/// Wall segments (m).
#[derive(Clone, Debug, Default)]
pub(crate) struct World {
    pub walls: Vec<(Point2, Point2)>,
}

fn p(x: f64, y: f64) -> Point2 {
    Point2::new(x, y)
}

impl World {
    /// Two rooms (each 5 × 6 m) side by side, joined by a 1 m door at x = 5, y ∈ [2.5, 3.5],
    /// with some furniture so that no two places look alike; `door_closed` closes the door.
    pub fn office(door_closed: bool) -> Self {
        let mut w = World::default();
        w.rect(0.0, 0.0, 10.0, 6.0);
        w.wall(5.0, 0.0, 5.0, 2.5);
        w.wall(5.0, 3.5, 5.0, 6.0);
        if door_closed {
            w.wall(5.0, 2.5, 5.0, 3.5);
        }
        // Furniture: a table in the left room, a shelf and a pillar in the right one.
        w.rect(1.0, 4.0, 2.2, 4.8);
        w.wall(8.5, 0.5, 8.5, 2.0);
        w.rect(7.0, 4.2, 7.3, 4.5);
        w.wall(0.0, 2.0, 1.2, 2.0);
        w
    }

    pub fn wall(&mut self, x0: f64, y0: f64, x1: f64, y1: f64) {
        self.walls.push((p(x0, y0), p(x1, y1)));
    }

    pub fn rect(&mut self, x0: f64, y0: f64, x1: f64, y1: f64) {
        self.wall(x0, y0, x1, y0);
        self.wall(x1, y0, x1, y1);
        self.wall(x1, y1, x0, y1);
        self.wall(x0, y1, x0, y0);
    }

    /// A 360° scan of `beams` beams from `world_from_robot` (points in the robot frame; beams
    /// without a return within `max_range_m` are left out).
    pub fn scan(&self, world_from_robot: &Se2, beams: usize, max_range_m: f64) -> Vec<Point2> {
        let origin = world_from_robot.translation();
        let mut out = Vec::with_capacity(beams);
        for i in 0..beams {
            let a = -std::f64::consts::PI + (i as f64) * std::f64::consts::TAU / beams as f64;
            let angle = world_from_robot.theta_rad + a;
            let d = p(angle.cos(), angle.sin());
            let mut best = f64::INFINITY;
            for (a0, a1) in &self.walls {
                let e = a1 - a0;
                let denom = d.x * (-e.y) - d.y * (-e.x);
                if denom.abs() < 1e-12 {
                    continue;
                }
                let rhs = a0 - origin;
                let t = (rhs.x * (-e.y) - rhs.y * (-e.x)) / denom;
                let u = (d.x * rhs.y - d.y * rhs.x) / denom;
                if t > 1e-6 && (0.0..=1.0).contains(&u) && t < best {
                    best = t;
                }
            }
            if best <= max_range_m {
                out.push(p(a.cos() * best, a.sin() * best));
            }
        }
        out
    }
}

/// Scans along a path of true poses, placed in the map by `map_from_world` (the identity for
/// a correct merge, something else for a wrong one).
pub(crate) fn scans_along(
    world: &World,
    path: &[Se2],
    map_from_world: &Se2,
    epoch: u32,
    first_node: u64,
) -> Vec<DetectorScan> {
    path.iter()
        .enumerate()
        .map(|(i, world_from_robot)| DetectorScan {
            node: NodeId(first_node + i as u64),
            epoch,
            map_from_robot: map_from_world.compose(world_from_robot),
            points_in_robot: Arc::from(world.scan(world_from_robot, 360, 20.0)),
        })
        .collect()
}

/// A straight path of `count` poses from `(x0, y0)` to `(x1, y1)` with heading `theta`.
pub(crate) fn line(x0: f64, y0: f64, x1: f64, y1: f64, theta: f64, count: usize) -> Vec<Se2> {
    (0..count)
        .map(|i| {
            let t = if count > 1 {
                i as f64 / (count - 1) as f64
            } else {
                0.0
            };
            Se2::new(x0 + (x1 - x0) * t, y0 + (y1 - y0) * t, theta)
        })
        .collect()
}

/// A merge case: the other epoch's scans and the current epoch's.
pub(crate) struct Case {
    pub other: Vec<DetectorScan>,
    pub current: Vec<DetectorScan>,
}

impl Case {
    /// Other epoch: a tour of both rooms in `world_other`; current: a walk through the left
    /// room and the door in `world_current`, placed by `map_from_world` (identity = correct).
    pub fn office(world_other: &World, world_current: &World, map_from_world: &Se2) -> Self {
        let mut path = line(1.0, 1.0, 4.0, 1.2, 0.3, 8);
        path.extend(line(4.0, 3.0, 8.0, 3.0, 0.0, 8));
        path.extend(line(8.0, 5.0, 6.0, 5.2, 2.0, 6));
        let other = scans_along(world_other, &path, &Se2::identity(), 1, 0);
        let mut walk = line(0.8, 3.0, 3.8, 1.5, -0.5, 10);
        walk.extend(line(3.6, 2.8, 2.0, 3.2, 2.5, 6));
        let current = scans_along(world_current, &walk, map_from_world, 2, 1000);
        Self { other, current }
    }

    /// The office's right merges (the door open in both epochs, or closed in one of them) and
    /// its wrong ones: turned, shifted by a room with the door closed, placed 20 m off (no
    /// overlap, appearance is blind: the place at two locations) and shifted by 0.8 m.
    pub fn office_valid_and_invalid() -> ([Self; 3], [Self; 4]) {
        let (open, closed) = (World::office(false), World::office(true));
        let valid = [
            Self::office(&open, &open, &Se2::identity()),
            Self::office(&open, &closed, &Se2::identity()),
            Self::office(&closed, &open, &Se2::identity()),
        ];
        let invalid = [
            Self::office(&open, &open, &wrong_turned()),
            Self::office(&open, &closed, &wrong_shifted()),
            Self::office(&open, &open, &Se2::new(20.0, 0.0, 0.0)),
            Self::office(&open, &open, &Se2::new(0.0, 0.8, 0.0)),
        ];
        (valid, invalid)
    }

    /// Runs a detector as the atlas would: merge after the first current scan, then one call
    /// per new vertex; returns the largest ratio.
    pub fn max_ratio(&self, detector: &mut dyn crate::InvalidMergeDetector) -> f64 {
        let first = MergedMap {
            current: self.current.get(..1).unwrap_or(&[]),
            other: &self.other,
        };
        detector.on_merge(&first);
        let mut max = 0.0f64;
        for k in 1..=self.current.len() {
            let map = MergedMap {
                current: &self.current[..k],
                other: &self.other,
            };
            let r = detector.on_vertex(&map);
            assert!((0.0..=1.0).contains(&r), "{} gave {r}", detector.name());
            max = max.max(r);
        }
        max
    }

    /// Runs `restarted` through the first half of the current walk, then merges the same
    /// epochs again there (a conditional merge made full): from then on it must read what
    /// `fresh`, merged there first, reads.
    pub fn merge_again_halfway(
        &self,
        restarted: &mut dyn crate::InvalidMergeDetector,
        fresh: &mut dyn crate::InvalidMergeDetector,
    ) {
        let map = |k: usize| MergedMap {
            current: &self.current[..k],
            other: &self.other,
        };
        let half = self.current.len() / 2;
        restarted.on_merge(&map(1));
        for k in 1..=half {
            restarted.on_vertex(&map(k));
        }
        restarted.on_merge(&map(half));
        fresh.on_merge(&map(half));
        for k in half..=self.current.len() {
            let (a, b) = (restarted.on_vertex(&map(k)), fresh.on_vertex(&map(k)));
            assert_eq!(a, b, "{} at vertex {k}", restarted.name());
        }
    }

    /// Merges the walk with all but the first of the other epoch's scans.
    pub fn merge_other_epochs(&self, detector: &mut dyn crate::InvalidMergeDetector) {
        detector.on_merge(&MergedMap {
            current: &self.current,
            other: self.other.get(1..).unwrap_or(&[]),
        });
    }

    /// A default detector merged again halfway ([`Case::merge_again_halfway`], beside a
    /// fresh one) built the other epochs' data once (`builds` reads its count), `check`
    /// then sees both; merged with other epochs ([`Case::merge_other_epochs`]) it builds
    /// again.
    pub fn builds_once_per_merged_epochs<D: crate::InvalidMergeDetector + Default>(
        &self,
        builds: impl Fn(&D) -> usize,
        check: impl FnOnce(&D, &D),
    ) {
        let (mut restarted, mut fresh) = (D::default(), D::default());
        self.merge_again_halfway(&mut restarted, &mut fresh);
        assert_eq!(builds(&restarted), 1, "{}", restarted.name());
        check(&restarted, &fresh);
        self.merge_other_epochs(&mut restarted);
        assert_eq!(builds(&restarted), 2, "{}", restarted.name());
    }
}

/// The wrong merges of the tests: turned by 90° about the left room's centre, and shifted
/// by a room.
pub(crate) fn wrong_turned() -> Se2 {
    let c = Se2::new(2.5, 3.0, 0.0);
    c.compose(&Se2::new(0.0, 0.0, std::f64::consts::FRAC_PI_2))
        .compose(&c.inverse())
}

pub(crate) fn wrong_shifted() -> Se2 {
    Se2::new(5.0, 0.0, 0.0)
}
