//! Helpers shared by the integration tests: brute-force geometry that does not go through the
//! crate's spatial index, so the tests check the index too.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use mapmerge_sim::{LineSegment, Point2, World};

fn cross(a: &Point2, b: &Point2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// True when the closed segments `[p0, p1]` and `[q0, q1]` share a point.
pub fn crosses(p0: &Point2, p1: &Point2, q0: &Point2, q1: &Point2) -> bool {
    let (r, s) = (p1 - p0, q1 - q0);
    if r.norm_squared() < 1e-30 {
        // Not a move: only touching counts.
        return LineSegment::new(*q0, *q1).distance_to_point_m(p0) < 1e-12;
    }
    let denom = cross(&r, &s);
    if denom.abs() < 1e-15 {
        // Parallel: touching counts when collinear and overlapping.
        if cross(&(q0 - p0), &r).abs() > 1e-12 {
            return false;
        }
        let length = r.norm_squared().max(1e-30);
        let (t0, t1) = ((q0 - p0).dot(&r) / length, (q1 - p0).dot(&r) / length);
        return t0.min(t1) <= 1.0 && t0.max(t1) >= 0.0;
    }
    let t = cross(&(q0 - p0), &s) / denom;
    let u = cross(&(q0 - p0), &r) / denom;
    (0.0..=1.0).contains(&t) && (0.0..=1.0).contains(&u)
}

/// Distance from `p` to the segment.
pub fn distance_to(p: &Point2, s: &LineSegment) -> f64 {
    s.distance_to_point_m(p)
}

/// Distance from `p` to the nearest obstacle boundary of `world` (brute force).
pub fn clearance(world: &World, p: &Point2) -> f64 {
    world
        .segments()
        .iter()
        .map(|s| distance_to(p, s))
        .fold(f64::INFINITY, f64::min)
}

/// First hit along a ray (brute force), `None` beyond `max_range_m`.
pub fn brute_force_cast(
    segments: &[LineSegment],
    origin: &Point2,
    angle_rad: f64,
    max_range_m: f64,
) -> Option<f64> {
    let d = Point2::new(angle_rad.cos(), angle_rad.sin());
    let mut best = f64::INFINITY;
    for s in segments {
        let e = s.end_m - s.start_m;
        let denom = cross(&d, &e);
        if denom.abs() < 1e-12 {
            continue;
        }
        let a = s.start_m - origin;
        let t = cross(&a, &e) / denom;
        let u = cross(&a, &d) / denom;
        if t >= 0.0 && (0.0..=1.0).contains(&u) {
            best = best.min(t);
        }
    }
    (best <= max_range_m).then_some(best)
}

/// The odometry pose the log attaches to every scan (the simulator always attaches one).
pub fn scan_odometry(session: &mapmerge_sim::SessionData) -> Vec<mapmerge_geometry::Se2> {
    session
        .log
        .scans
        .iter()
        .map(|r| r.odom_from_robot.unwrap())
        .collect()
}
