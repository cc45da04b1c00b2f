//! Planar shapes the worlds are made of (rectangles, rotated boxes, segments) and the small
//! segment geometry the ray caster, the roadmap and the tests share.

use mapmerge_geometry::{wrap_angle_rad, Se2};
use serde::{Deserialize, Serialize};

use crate::Point2;

/// An axis-aligned rectangle `[min_m, max_m]` (m).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Rect {
    /// Lower-left corner (m).
    pub min_m: Point2,
    /// Upper-right corner (m).
    pub max_m: Point2,
}

impl Rect {
    /// The rectangle spanned by two opposite corners, in any order.
    pub fn new(x0_m: f64, y0_m: f64, x1_m: f64, y1_m: f64) -> Self {
        Self {
            min_m: Point2::new(x0_m.min(x1_m), y0_m.min(y1_m)),
            max_m: Point2::new(x0_m.max(x1_m), y0_m.max(y1_m)),
        }
    }

    /// The rectangle of size `size_m` centred on `center_m`.
    pub fn from_center(center_m: Point2, size_m: Point2) -> Self {
        let half = size_m.abs() * 0.5;
        Self {
            min_m: center_m - half,
            max_m: center_m + half,
        }
    }

    /// Extent along x (m).
    pub fn width_m(&self) -> f64 {
        self.max_m.x - self.min_m.x
    }

    /// Extent along y (m).
    pub fn height_m(&self) -> f64 {
        self.max_m.y - self.min_m.y
    }

    /// Centre (m).
    pub fn center_m(&self) -> Point2 {
        (self.min_m + self.max_m) * 0.5
    }

    /// Area (m²).
    pub fn area_m2(&self) -> f64 {
        self.width_m().max(0.0) * self.height_m().max(0.0)
    }

    /// True when `p_m` lies inside or on the border.
    pub fn contains(&self, p_m: &Point2) -> bool {
        p_m.x >= self.min_m.x
            && p_m.x <= self.max_m.x
            && p_m.y >= self.min_m.y
            && p_m.y <= self.max_m.y
    }

    /// True when the two rectangles overlap with positive area.
    pub fn overlaps(&self, other: &Rect) -> bool {
        self.min_m.x < other.max_m.x
            && other.min_m.x < self.max_m.x
            && self.min_m.y < other.max_m.y
            && other.min_m.y < self.max_m.y
    }

    /// The rectangle grown by `margin_m` on every side (shrunk when negative).
    pub fn expanded(&self, margin_m: f64) -> Rect {
        Rect {
            min_m: self.min_m - Point2::new(margin_m, margin_m),
            max_m: self.max_m + Point2::new(margin_m, margin_m),
        }
    }

    /// The smallest rectangle containing both.
    pub fn union(&self, other: &Rect) -> Rect {
        Rect {
            min_m: self.min_m.inf(&other.min_m),
            max_m: self.max_m.sup(&other.max_m),
        }
    }

    /// The rectangle moved by `offset_m`.
    pub fn translated(&self, offset_m: &Point2) -> Rect {
        Rect {
            min_m: self.min_m + offset_m,
            max_m: self.max_m + offset_m,
        }
    }

    /// Corners counter-clockwise from the lower-left one.
    pub fn corners_m(&self) -> [Point2; 4] {
        [
            self.min_m,
            Point2::new(self.max_m.x, self.min_m.y),
            self.max_m,
            Point2::new(self.min_m.x, self.max_m.y),
        ]
    }
}

/// A line segment from `start_m` to `end_m` (m).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LineSegment {
    /// First end point (m).
    pub start_m: Point2,
    /// Second end point (m).
    pub end_m: Point2,
}

impl LineSegment {
    /// The segment between two points.
    pub fn new(start_m: Point2, end_m: Point2) -> Self {
        Self { start_m, end_m }
    }

    /// Length (m).
    pub fn length_m(&self) -> f64 {
        (self.end_m - self.start_m).norm()
    }

    /// True when the two closed segments share a point (collinear overlaps included).
    pub fn intersects(&self, other: &LineSegment) -> bool {
        segments_intersect(&self.start_m, &self.end_m, &other.start_m, &other.end_m)
    }

    /// Distance from `p_m` to the closest point of the segment (m).
    pub fn distance_to_point_m(&self, p_m: &Point2) -> f64 {
        point_segment_distance(p_m, &self.start_m, &self.end_m)
    }
}

/// The outline of an obstacle.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Shape {
    /// A solid axis-aligned rectangle (walls, desks, shelves).
    Rect(Rect),
    /// A solid rectangle of half extents `half_size_m` turned by `yaw_rad` about its centre
    /// (boxes standing at an angle).
    Box {
        /// Centre (m).
        center_m: Point2,
        /// Half the side lengths along the box's own axes (m).
        half_size_m: Point2,
        /// Rotation of the box's x axis from the world's (rad).
        yaw_rad: f64,
    },
    /// An infinitely thin wall (hand-made worlds; the generators use rectangles).
    Segment(LineSegment),
}

impl Shape {
    /// The boundary as segments (one for a [`Shape::Segment`], four otherwise).
    pub fn edges(&self) -> Vec<LineSegment> {
        match self {
            Shape::Segment(segment) => vec![*segment],
            _ => {
                let c = self.corners_m();
                (0..4)
                    .map(|i| LineSegment::new(c[i], c[(i + 1) % 4]))
                    .collect()
            }
        }
    }

    /// Corners counter-clockwise (a segment repeats its end points).
    pub fn corners_m(&self) -> [Point2; 4] {
        match self {
            Shape::Rect(rect) => rect.corners_m(),
            Shape::Box {
                center_m,
                half_size_m,
                yaw_rad,
            } => {
                let (s, c) = yaw_rad.sin_cos();
                let axis_x = Point2::new(c, s) * half_size_m.x;
                let axis_y = Point2::new(-s, c) * half_size_m.y;
                [
                    center_m - axis_x - axis_y,
                    center_m + axis_x - axis_y,
                    center_m + axis_x + axis_y,
                    center_m - axis_x + axis_y,
                ]
            }
            Shape::Segment(segment) => [
                segment.start_m,
                segment.end_m,
                segment.end_m,
                segment.start_m,
            ],
        }
    }

    /// True when `p_m` lies inside the solid (never for a segment).
    pub fn contains(&self, p_m: &Point2) -> bool {
        match self {
            Shape::Rect(rect) => rect.contains(p_m),
            Shape::Box {
                center_m,
                half_size_m,
                yaw_rad,
            } => {
                let (s, c) = yaw_rad.sin_cos();
                let d = p_m - center_m;
                let local = Point2::new(c * d.x + s * d.y, -s * d.x + c * d.y);
                local.x.abs() <= half_size_m.x && local.y.abs() <= half_size_m.y
            }
            Shape::Segment(_) => false,
        }
    }

    /// Axis-aligned bounds.
    pub fn bounds(&self) -> Rect {
        let corners = self.corners_m();
        let mut bounds = Rect {
            min_m: corners[0],
            max_m: corners[0],
        };
        for corner in &corners[1..] {
            bounds.min_m = bounds.min_m.inf(corner);
            bounds.max_m = bounds.max_m.sup(corner);
        }
        bounds
    }

    /// The shape moved by `b_from_a` (the shape was given in frame `a`). Rectangles turned by
    /// a multiple of 90° stay rectangles; other turns give boxes.
    pub fn transformed(&self, b_from_a: &Se2) -> Shape {
        match self {
            Shape::Segment(segment) => Shape::Segment(LineSegment::new(
                b_from_a.transform_point(&segment.start_m),
                b_from_a.transform_point(&segment.end_m),
            )),
            Shape::Rect(rect) => Shape::oriented(
                b_from_a.transform_point(&rect.center_m()),
                Point2::new(rect.width_m(), rect.height_m()) * 0.5,
                b_from_a.theta_rad,
            ),
            Shape::Box {
                center_m,
                half_size_m,
                yaw_rad,
            } => Shape::oriented(
                b_from_a.transform_point(center_m),
                *half_size_m,
                yaw_rad + b_from_a.theta_rad,
            ),
        }
    }

    /// A box of half extents `half_size_m` turned by `yaw_rad`, as a [`Shape::Rect`] when the
    /// turn is a multiple of 90°.
    pub fn oriented(center_m: Point2, half_size_m: Point2, yaw_rad: f64) -> Shape {
        let yaw_rad = wrap_angle_rad(yaw_rad);
        let quarter_turns = (yaw_rad / std::f64::consts::FRAC_PI_2).round();
        if (yaw_rad - quarter_turns * std::f64::consts::FRAC_PI_2).abs() < 1e-9 {
            let half = if (quarter_turns as i64).rem_euclid(2) == 0 {
                half_size_m
            } else {
                Point2::new(half_size_m.y, half_size_m.x)
            };
            Shape::Rect(Rect {
                min_m: center_m - half,
                max_m: center_m + half,
            })
        } else {
            Shape::Box {
                center_m,
                half_size_m,
                yaw_rad,
            }
        }
    }
}

/// `a × b` for plane vectors.
pub(crate) fn cross(a: &Point2, b: &Point2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Distance from `p` to the segment `[a, b]`.
pub(crate) fn point_segment_distance(p: &Point2, a: &Point2, b: &Point2) -> f64 {
    let ab = b - a;
    let length_sq = ab.norm_squared();
    let t = if length_sq > 0.0 {
        ((p - a).dot(&ab) / length_sq).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a + ab * t - p).norm()
}

/// True when the closed segments `[p0, p1]` and `[q0, q1]` share a point.
pub(crate) fn segments_intersect(p0: &Point2, p1: &Point2, q0: &Point2, q1: &Point2) -> bool {
    let d1 = cross(&(p1 - p0), &(q0 - p0));
    let d2 = cross(&(p1 - p0), &(q1 - p0));
    let d3 = cross(&(q1 - q0), &(p0 - q0));
    let d4 = cross(&(q1 - q0), &(p1 - q0));
    if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0))
        && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
    {
        return true;
    }
    let on = |a: &Point2, b: &Point2, p: &Point2, d: f64| {
        d == 0.0
            && p.x >= a.x.min(b.x)
            && p.x <= a.x.max(b.x)
            && p.y >= a.y.min(b.y)
            && p.y <= a.y.max(b.y)
    };
    on(p0, p1, q0, d1) || on(p0, p1, q1, d2) || on(q0, q1, p0, d3) || on(q0, q1, p1, d4)
}

/// Distance between the closed segments `[p0, p1]` and `[q0, q1]` (0 when they cross).
pub(crate) fn segment_segment_distance(p0: &Point2, p1: &Point2, q0: &Point2, q1: &Point2) -> f64 {
    if segments_intersect(p0, p1, q0, q1) {
        return 0.0;
    }
    point_segment_distance(p0, q0, q1)
        .min(point_segment_distance(p1, q0, q1))
        .min(point_segment_distance(q0, p0, p1))
        .min(point_segment_distance(q1, p0, p1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_2, PI};

    #[test]
    fn rect_turned_a_quarter_stays_a_rect_with_swapped_sides() {
        let shape = Shape::Rect(Rect::new(0.0, 0.0, 2.0, 1.0));
        let turned = shape.transformed(&Se2::new(10.0, 0.0, FRAC_PI_2));
        let Shape::Rect(rect) = turned else {
            panic!("expected a rectangle, got {turned:?}");
        };
        assert!((rect.width_m() - 1.0).abs() < 1e-12 && (rect.height_m() - 2.0).abs() < 1e-12);
        assert!((rect.center_m() - Point2::new(9.5, 1.0)).norm() < 1e-12);
        let half_turn = shape.transformed(&Se2::new(0.0, 0.0, PI));
        assert!(matches!(half_turn, Shape::Rect(_)));
        assert!(matches!(
            shape.transformed(&Se2::new(0.0, 0.0, 0.3)),
            Shape::Box { .. }
        ));
    }

    #[test]
    fn box_contains_and_bounds() {
        let shape = Shape::oriented(Point2::new(1.0, 1.0), Point2::new(1.0, 0.1), PI / 4.0);
        assert!(shape.contains(&Point2::new(1.5, 1.5)));
        assert!(!shape.contains(&Point2::new(1.5, 0.5)));
        let bounds = shape.bounds();
        assert!(bounds.contains(&Point2::new(1.7, 1.7)));
        assert_eq!(shape.edges().len(), 4);
    }

    #[test]
    fn segment_tests() {
        let a = LineSegment::new(Point2::new(0.0, 0.0), Point2::new(2.0, 0.0));
        let b = LineSegment::new(Point2::new(1.0, -1.0), Point2::new(1.0, 1.0));
        let c = LineSegment::new(Point2::new(3.0, -1.0), Point2::new(3.0, 1.0));
        let touching = LineSegment::new(Point2::new(2.0, 0.0), Point2::new(2.0, 1.0));
        assert!(a.intersects(&b) && !a.intersects(&c) && a.intersects(&touching));
        let d = segment_segment_distance(&a.start_m, &a.end_m, &c.start_m, &c.end_m);
        assert!((d - 1.0).abs() < 1e-12);
        assert!((a.distance_to_point_m(&Point2::new(1.0, 0.5)) - 0.5).abs() < 1e-12);
    }
}
