//! Door passings along a session's true trajectory: the ground truth door detection is scored
//! against (Ehlers et al., Sec. II-B).

use serde::{Deserialize, Serialize};

use crate::simulate::SessionData;
use crate::world::{DoorId, World};
use crate::Point2;

/// The robot went through a door.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct DoorPassing {
    /// The first scan taken after crossing the doorway's middle line (index into the
    /// session's scans).
    pub scan: usize,
    /// The door.
    pub door: DoorId,
}

/// Every passing of an open door by the true positions `path_m` (one per scan, in order):
/// a step between consecutive scans that crosses the line through a door's centre across its
/// passage direction, within the door's clear width. Steps across a kidnap (`kidnap_scans`:
/// the first scan after each jump) are not passings.
pub fn door_passings(world: &World, path_m: &[Point2], kidnap_scans: &[usize]) -> Vec<DoorPassing> {
    let mut passings = Vec::new();
    for (i, step) in path_m.windows(2).enumerate() {
        let scan = i + 1;
        if kidnap_scans.contains(&scan) {
            continue;
        }
        let (a, b) = (step[0], step[1]);
        for door in world.doors.iter().filter(|d| d.closed_by.is_none()) {
            let across = door.passage_direction();
            let along = Point2::new(-across.y, across.x);
            let (sa, sb) = (
                (a - door.center_m).dot(&across),
                (b - door.center_m).dot(&across),
            );
            // Crossing from one side to the other (ending on the line counts once).
            if !((sa < 0.0 && sb >= 0.0) || (sa >= 0.0 && sb < 0.0)) {
                continue;
            }
            let t = sa / (sa - sb);
            let crossing = a + (b - a) * t;
            if (crossing - door.center_m).dot(&along).abs() <= 0.5 * door.width_m {
                passings.push(DoorPassing {
                    scan,
                    door: door.id,
                });
            }
        }
    }
    passings
}

impl SessionData {
    /// The session's door passings ([`door_passings`] of its true trajectory).
    pub fn door_passings(&self) -> Vec<DoorPassing> {
        let path: Vec<Point2> = self
            .truth
            .iter()
            .map(|(_, pose)| pose.translation())
            .collect();
        let kidnaps: Vec<usize> = self.kidnaps.iter().map(|k| k.scan_index).collect();
        door_passings(&self.world, &path, &kidnaps)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;
    use crate::world::DoorKind;
    use crate::RoomId;

    fn world_with_a_door() -> World {
        let mut world = World::new("door test");
        // A door at (5, 0) passed along +x, 1 m wide.
        world.add_door(
            DoorKind::Entrance,
            Point2::new(5.0, 0.0),
            1.0,
            0.1,
            0.0,
            [RoomId(0), RoomId(1)],
        );
        world
    }

    fn straight(from: Point2, to: Point2, steps: usize) -> Vec<Point2> {
        (0..=steps)
            .map(|i| from + (to - from) * (i as f64 / steps as f64))
            .collect()
    }

    #[test]
    fn through_and_back_are_two_passings_beside_the_door_none() {
        let world = world_with_a_door();
        let mut path = straight(Point2::new(0.0, 0.2), Point2::new(9.0, 0.2), 90);
        path.extend(straight(Point2::new(9.0, -0.3), Point2::new(1.0, -0.3), 80));
        let passings = door_passings(&world, &path, &[]);
        assert_eq!(passings.len(), 2, "{passings:?}");
        assert_eq!(passings[0].scan, 50, "the first position on or past x = 5");
        assert_eq!(passings[1].door, world.doors[0].id);
        let beside = straight(Point2::new(0.0, 0.8), Point2::new(9.0, 0.8), 90);
        assert!(
            door_passings(&world, &beside, &[]).is_empty(),
            "through the wall"
        );
    }

    #[test]
    fn a_kidnap_across_the_door_and_a_closed_door_are_no_passings() {
        let mut world = world_with_a_door();
        let path = vec![Point2::new(2.0, 0.0), Point2::new(8.0, 0.0)];
        assert_eq!(door_passings(&world, &path, &[]).len(), 1);
        assert!(door_passings(&world, &path, &[1]).is_empty(), "a jump");
        world.doors[0].closed_by = Some(crate::ObstacleId(99));
        assert!(
            door_passings(&world, &path, &[]).is_empty(),
            "a closed door"
        );
    }
}
