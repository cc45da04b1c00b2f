//! Furnishing a room: desks and cabinets against the walls, tables in the middle, loose boxes
//! at an angle, placed by rejection sampling so that every piece keeps a passage to its
//! neighbours and no piece stands in front of a door.

use rand::Rng;

use crate::rng::uniform;
use crate::shapes::{Rect, Shape};
use crate::Point2;

/// Free gap kept between two pieces of furniture (m): wider than the robot with its
/// clearance, so furniture never walls off part of a room.
pub(crate) const FURNITURE_GAP_M: f64 = 0.8;
/// Depth of the zone kept free in front of a door, inside the room (m).
pub(crate) const DOOR_ZONE_DEPTH_M: f64 = 1.3;
/// Extra width kept free on each side of a door (m).
pub(crate) const DOOR_ZONE_SIDE_M: f64 = 0.35;

/// Attempts per piece before giving up on it.
const ATTEMPTS: usize = 60;

/// The kinds of furniture, with their size ranges (m).
#[derive(Clone, Copy, Debug)]
enum Piece {
    /// Against a wall, long side along it.
    Desk,
    /// Against a wall, shallow.
    Cabinet,
    /// Free-standing, away from the walls.
    Table,
    /// Small, anywhere, turned by a random angle.
    Box,
}

impl Piece {
    fn pick<R: Rng + ?Sized>(rng: &mut R) -> Piece {
        match rng.random_range(0..10) {
            0..=3 => Piece::Desk,
            4..=5 => Piece::Cabinet,
            6..=7 => Piece::Table,
            _ => Piece::Box,
        }
    }
}

/// Places up to `count` pieces in the room `[0, width_m] × [0, depth_m]` (room frame), away
/// from `keep_out` zones and `existing` obstacles. Returns the shapes placed (fewer than
/// `count` when the room is full).
pub(crate) fn furnish<R: Rng + ?Sized>(
    rng: &mut R,
    width_m: f64,
    depth_m: f64,
    keep_out: &[Rect],
    existing: &[Rect],
    count: usize,
) -> Vec<Shape> {
    let mut placed: Vec<Shape> = Vec::new();
    let mut taken: Vec<Rect> = existing.to_vec();
    for _ in 0..count {
        let piece = Piece::pick(rng);
        for _ in 0..ATTEMPTS {
            let Some(shape) = propose(rng, piece, width_m, depth_m) else {
                break;
            };
            let bounds = shape.bounds();
            let inside = bounds.min_m.x >= -1e-9
                && bounds.min_m.y >= -1e-9
                && bounds.max_m.x <= width_m + 1e-9
                && bounds.max_m.y <= depth_m + 1e-9;
            let grown = bounds.expanded(FURNITURE_GAP_M);
            if inside
                && !keep_out.iter().any(|zone| zone.overlaps(&bounds))
                && !taken.iter().any(|other| other.overlaps(&grown))
            {
                taken.push(bounds);
                placed.push(shape);
                break;
            }
        }
    }
    placed
}

/// A random pose and size for `piece`, or `None` when the room is too small for it.
fn propose<R: Rng + ?Sized>(
    rng: &mut R,
    piece: Piece,
    width_m: f64,
    depth_m: f64,
) -> Option<Shape> {
    match piece {
        Piece::Desk | Piece::Cabinet => {
            let (length, deep) = match piece {
                Piece::Desk => (uniform(rng, 1.2, 1.6), uniform(rng, 0.6, 0.8)),
                _ => (uniform(rng, 0.8, 1.2), uniform(rng, 0.4, 0.5)),
            };
            // Which wall: 0 bottom, 1 right, 2 top, 3 left.
            let wall = rng.random_range(0..4);
            let along = if wall % 2 == 0 { width_m } else { depth_m };
            if along < length + 0.2 {
                return None;
            }
            let offset = uniform(rng, 0.1, along - length - 0.1);
            let rect = match wall {
                0 => Rect::new(offset, 0.0, offset + length, deep),
                1 => Rect::new(width_m - deep, offset, width_m, offset + length),
                2 => Rect::new(offset, depth_m - deep, offset + length, depth_m),
                _ => Rect::new(0.0, offset, deep, offset + length),
            };
            Some(Shape::Rect(rect))
        }
        Piece::Table => {
            let (mut length, mut deep) = (uniform(rng, 1.2, 2.0), uniform(rng, 0.8, 1.0));
            if rng.random::<bool>() {
                std::mem::swap(&mut length, &mut deep);
            }
            let margin = FURNITURE_GAP_M;
            if width_m < length + 2.0 * margin || depth_m < deep + 2.0 * margin {
                return None;
            }
            let x = uniform(rng, margin, width_m - margin - length);
            let y = uniform(rng, margin, depth_m - margin - deep);
            Some(Shape::Rect(Rect::new(x, y, x + length, y + deep)))
        }
        Piece::Box => {
            let half = Point2::new(uniform(rng, 0.2, 0.35), uniform(rng, 0.2, 0.35));
            let reach = half.norm() + 0.1;
            if width_m < 2.0 * reach || depth_m < 2.0 * reach {
                return None;
            }
            let center = Point2::new(
                uniform(rng, reach, width_m - reach),
                uniform(rng, reach, depth_m - reach),
            );
            Some(Shape::oriented(
                center,
                half,
                uniform(rng, 0.0, std::f64::consts::PI),
            ))
        }
    }
}

/// The zone kept free in front of a door whose gap spans `[from_m, to_m]` along one wall of
/// the room `[0, width_m] × [0, depth_m]` (room frame). `wall` is 0 bottom, 1 right, 2 top,
/// 3 left.
pub(crate) fn door_zone(wall: usize, from_m: f64, to_m: f64, width_m: f64, depth_m: f64) -> Rect {
    let (lo, hi) = (
        from_m.min(to_m) - DOOR_ZONE_SIDE_M,
        from_m.max(to_m) + DOOR_ZONE_SIDE_M,
    );
    match wall {
        0 => Rect::new(lo, 0.0, hi, DOOR_ZONE_DEPTH_M),
        1 => Rect::new(width_m - DOOR_ZONE_DEPTH_M, lo, width_m, hi),
        2 => Rect::new(lo, depth_m - DOOR_ZONE_DEPTH_M, hi, depth_m),
        _ => Rect::new(0.0, lo, DOOR_ZONE_DEPTH_M, hi),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::seeded;

    #[test]
    fn pieces_stay_inside_apart_and_out_of_door_zones() {
        let mut rng = seeded(3);
        for _ in 0..200 {
            let (w, d) = (uniform(&mut rng, 3.0, 8.0), uniform(&mut rng, 3.0, 6.0));
            let zone = door_zone(2, 0.5, 1.45, w, d);
            let shapes = furnish(&mut rng, w, d, &[zone], &[], 5);
            let bounds: Vec<Rect> = shapes.iter().map(Shape::bounds).collect();
            for (i, b) in bounds.iter().enumerate() {
                assert!(
                    b.min_m.x >= -1e-9
                        && b.max_m.x <= w + 1e-9
                        && b.min_m.y >= -1e-9
                        && b.max_m.y <= d + 1e-9
                );
                assert!(!b.overlaps(&zone));
                for other in &bounds[i + 1..] {
                    assert!(!b.expanded(FURNITURE_GAP_M - 1e-9).overlaps(other));
                }
            }
        }
    }
}
