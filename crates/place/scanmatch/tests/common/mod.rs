//! Hand-made geometry shared by the scan-matching tests.

use mapmerge_scan::Point2;

/// Points every 2 cm along a segment.
pub fn segment(points: &mut Vec<Point2>, from: (f64, f64), to: (f64, f64)) {
    let (a, b) = (Point2::new(from.0, from.1), Point2::new(to.0, to.1));
    let count = ((b - a).norm() / 0.02).ceil().max(1.0) as usize;
    for k in 0..=count {
        points.push(a + (b - a) * (k as f64 / count as f64));
    }
}
