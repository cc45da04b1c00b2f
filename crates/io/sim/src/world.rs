//! The simulated world: solid obstacles (walls, furniture, shelves, closed doors) plus the
//! named rooms and doors that routes and changes refer to.

use std::fmt;

use mapmerge_geometry::Se2;
use serde::{Deserialize, Serialize};

use crate::shapes::{LineSegment, Rect, Shape};
use crate::{Point2, SimError};

/// Thickness of a closed door's leaf (m).
pub const DOOR_LEAF_THICKNESS_M: f64 = 0.05;
/// How far a closed door's leaf reaches into the jambs on each side (m), so no gap is left.
const DOOR_LEAF_OVERLAP_M: f64 = 0.03;

/// Identifies an obstacle of a [`World`]; stable across the sessions of a dataset (a moved
/// piece of furniture keeps its id, an added one gets a new id).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct ObstacleId(pub u32);

/// Identifies a room (or corridor, hall, aisle) of a [`World`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct RoomId(pub u32);

/// Identifies a door of a [`World`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct DoorId(pub u32);

impl fmt::Display for ObstacleId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "obstacle {}", self.0)
    }
}

impl fmt::Display for RoomId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "room {}", self.0)
    }
}

impl fmt::Display for DoorId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "door {}", self.0)
    }
}

/// What an obstacle is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ObstacleKind {
    /// Part of the building (outer or inner wall, a filled gap).
    Wall,
    /// Movable furniture (desks, tables, cabinets, boxes, pallets).
    Furniture,
    /// Warehouse racking (shelf rows and their uprights).
    Shelf,
    /// The leaf of a closed door, filling a doorway.
    ClosedDoor,
}

/// One solid obstacle.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Obstacle {
    /// Stable id.
    pub id: ObstacleId,
    /// What it is.
    pub kind: ObstacleKind,
    /// Its outline.
    pub shape: Shape,
    /// The room it stands in (furniture), if any.
    pub room: Option<RoomId>,
}

/// What a room is used for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RoomKind {
    /// An office or meeting room (a destination of routes).
    Office,
    /// A small storage room or closet (a destination, rarely furnished).
    Storage,
    /// A corridor (passed through, not a destination).
    Corridor,
    /// An open area of a hall (a destination).
    Hall,
    /// An aisle between shelf rows (a destination).
    Aisle,
}

impl RoomKind {
    /// True for kinds that routes visit (everything but corridors).
    pub fn is_destination(self) -> bool {
        !matches!(self, RoomKind::Corridor)
    }
}

/// A named free area: a room, corridor, hall or aisle.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Room {
    /// Stable id.
    pub id: RoomId,
    /// Unique name (`room-07`, `corridor-1`, `aisle-03`, ...).
    pub name: String,
    /// What it is.
    pub kind: RoomKind,
    /// Its free interior (inside the walls), world frame (m).
    pub rect: Rect,
    /// Pose of the room's own frame in the world. Rooms of one `alias_group` look the same in
    /// their own frames, so `world_from_room_b · world_from_room_a⁻¹` maps one onto the other.
    pub world_from_room: Se2,
    /// Rooms with the same group are copies of each other (same size, doors and furniture up
    /// to a rigid motion): deliberate perceptual aliasing. `None` for unique rooms.
    pub alias_group: Option<u32>,
}

/// How a door connects its rooms.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DoorKind {
    /// From a room to a corridor or hall.
    Entrance,
    /// Between two neighbouring rooms.
    Connecting,
}

/// A doorway: a gap of `width_m` in a wall of `wall_thickness_m`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Door {
    /// Stable id.
    pub id: DoorId,
    /// How it connects.
    pub kind: DoorKind,
    /// Centre of the gap, in the middle of the wall (m).
    pub center_m: Point2,
    /// Clear width of the gap (m).
    pub width_m: f64,
    /// Thickness of the wall the gap is in (m).
    pub wall_thickness_m: f64,
    /// Direction of passage through the door (rad): 0 along +x, π/2 along +y.
    pub passage_yaw_rad: f64,
    /// The two areas it connects (`rooms[1]` lies in the passage direction).
    pub rooms: [RoomId; 2],
    /// The leaf obstacle when the door is closed, `None` when open.
    pub closed_by: Option<ObstacleId>,
}

impl Door {
    /// Unit vector of the passage direction.
    pub fn passage_direction(&self) -> Point2 {
        let (s, c) = self.passage_yaw_rad.sin_cos();
        Point2::new(c, s)
    }

    /// Unit vector along the wall (the passage direction turned by +90°).
    pub fn wall_direction(&self) -> Point2 {
        let d = self.passage_direction();
        Point2::new(-d.y, d.x)
    }

    /// The segment across the doorway, in the middle of the wall, from jamb to jamb.
    pub fn span(&self) -> LineSegment {
        let half = self.wall_direction() * (0.5 * self.width_m);
        LineSegment::new(self.center_m - half, self.center_m + half)
    }

    /// The point `distance_m` from the door's centre on the side of `rooms[side]` (0 or 1).
    pub fn approach_point(&self, side: usize, distance_m: f64) -> Point2 {
        let sign = if side == 0 { -1.0 } else { 1.0 };
        self.center_m + self.passage_direction() * (sign * distance_m)
    }

    /// The leaf that closes this door: a thin rectangle across the gap.
    pub fn leaf_shape(&self) -> Shape {
        Shape::oriented(
            self.center_m,
            Point2::new(
                0.5 * DOOR_LEAF_THICKNESS_M,
                0.5 * self.width_m + DOOR_LEAF_OVERLAP_M,
            ),
            self.passage_yaw_rad,
        )
    }
}

/// A 2D world: everything a laser can hit, plus the named places routes use.
///
/// Everything is kept in vectors in creation order, so iteration (and all that depends on it)
/// is deterministic.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct World {
    /// Name (the preset's, or the hand-made world's).
    pub name: String,
    /// Outline of the building (outer walls included): inside is free or occupied, outside
    /// unknown in [`World::to_grid`].
    pub footprint: Vec<Rect>,
    /// Solid obstacles.
    pub obstacles: Vec<Obstacle>,
    /// Named areas.
    pub rooms: Vec<Room>,
    /// Doorways.
    pub doors: Vec<Door>,
    /// The id the next added obstacle gets (ids are never reused, even after removal).
    next_obstacle_id: u32,
}

impl World {
    /// An empty world.
    pub fn new(name: impl Into<String>) -> Self {
        Self {
            name: name.into(),
            footprint: Vec::new(),
            obstacles: Vec::new(),
            rooms: Vec::new(),
            doors: Vec::new(),
            next_obstacle_id: 0,
        }
    }

    /// Adds an obstacle and returns its new id (ids are never reused).
    pub fn add_obstacle(
        &mut self,
        kind: ObstacleKind,
        shape: Shape,
        room: Option<RoomId>,
    ) -> ObstacleId {
        let id = ObstacleId(self.next_obstacle_id);
        self.next_obstacle_id += 1;
        self.obstacles.push(Obstacle {
            id,
            kind,
            shape,
            room,
        });
        id
    }

    /// Removes an obstacle, returning it.
    pub fn remove_obstacle(&mut self, id: ObstacleId) -> Option<Obstacle> {
        let index = self.obstacles.iter().position(|o| o.id == id)?;
        Some(self.obstacles.remove(index))
    }

    /// Adds a room and returns its id (its index).
    pub fn add_room(&mut self, name: impl Into<String>, kind: RoomKind, rect: Rect) -> RoomId {
        let id = RoomId(self.rooms.len() as u32);
        self.rooms.push(Room {
            id,
            name: name.into(),
            kind,
            rect,
            world_from_room: Se2::new(rect.min_m.x, rect.min_m.y, 0.0),
            alias_group: None,
        });
        id
    }

    /// Adds an open door between `rooms[0]` and `rooms[1]` (`rooms[1]` in the passage
    /// direction) and returns its id (its index). The caller leaves the gap in the wall.
    pub fn add_door(
        &mut self,
        kind: DoorKind,
        center_m: Point2,
        width_m: f64,
        wall_thickness_m: f64,
        passage_yaw_rad: f64,
        rooms: [RoomId; 2],
    ) -> DoorId {
        let id = DoorId(self.doors.len() as u32);
        self.doors.push(Door {
            id,
            kind,
            center_m,
            width_m,
            wall_thickness_m,
            passage_yaw_rad,
            rooms,
            closed_by: None,
        });
        id
    }

    /// Closes a door: adds its leaf as a [`ObstacleKind::ClosedDoor`] obstacle. Closing a
    /// closed door returns the existing leaf.
    pub fn close_door(&mut self, id: DoorId) -> Result<ObstacleId, SimError> {
        let door = self.door(id).ok_or(SimError::UnknownDoor(id))?;
        if let Some(leaf) = door.closed_by {
            return Ok(leaf);
        }
        let shape = door.leaf_shape();
        let leaf = self.add_obstacle(ObstacleKind::ClosedDoor, shape, None);
        if let Some(door) = self.doors.iter_mut().find(|d| d.id == id) {
            door.closed_by = Some(leaf);
        }
        Ok(leaf)
    }

    /// The obstacle with `id`.
    pub fn obstacle(&self, id: ObstacleId) -> Option<&Obstacle> {
        self.obstacles.iter().find(|o| o.id == id)
    }

    /// The room with `id`.
    pub fn room(&self, id: RoomId) -> Option<&Room> {
        self.rooms.iter().find(|r| r.id == id)
    }

    /// The room called `name`.
    pub fn room_by_name(&self, name: &str) -> Option<&Room> {
        self.rooms.iter().find(|r| r.name == name)
    }

    /// The door with `id`.
    pub fn door(&self, id: DoorId) -> Option<&Door> {
        self.doors.iter().find(|d| d.id == id)
    }

    /// The room whose interior contains `p_m` (destinations before corridors), if any.
    pub fn room_at(&self, p_m: &Point2) -> Option<&Room> {
        let mut inside = self.rooms.iter().filter(|r| r.rect.contains(p_m));
        let first = inside.next()?;
        if first.kind.is_destination() {
            return Some(first);
        }
        Some(inside.find(|r| r.kind.is_destination()).unwrap_or(first))
    }

    /// Doors that open into room `id`.
    pub fn doors_of(&self, id: RoomId) -> impl Iterator<Item = &Door> + '_ {
        self.doors.iter().filter(move |d| d.rooms.contains(&id))
    }

    /// Every obstacle's boundary segments, obstacle by obstacle.
    pub fn segments(&self) -> Vec<LineSegment> {
        self.obstacles
            .iter()
            .flat_map(|o| o.shape.edges())
            .collect()
    }

    /// True when `p_m` lies inside a solid obstacle.
    pub fn is_inside_obstacle(&self, p_m: &Point2) -> bool {
        self.obstacles.iter().any(|o| o.shape.contains(p_m))
    }

    /// True when `p_m` lies inside the building's footprint.
    pub fn is_inside_building(&self, p_m: &Point2) -> bool {
        self.footprint.iter().any(|r| r.contains(p_m))
    }

    /// Bounds of the footprint and every obstacle (a unit square at the origin when empty).
    pub fn bounds(&self) -> Rect {
        let mut all = self
            .footprint
            .iter()
            .copied()
            .chain(self.obstacles.iter().map(|o| o.shape.bounds()));
        let Some(first) = all.next() else {
            return Rect::new(0.0, 0.0, 1.0, 1.0);
        };
        all.fold(first, |acc, r| acc.union(&r))
    }

    /// Rooms sharing `room`'s alias group (itself excluded).
    pub fn look_alikes(&self, room: RoomId) -> Vec<&Room> {
        let Some(group) = self.room(room).and_then(|r| r.alias_group) else {
            return Vec::new();
        };
        self.rooms
            .iter()
            .filter(|r| r.id != room && r.alias_group == Some(group))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closing_a_door_adds_a_leaf_across_the_gap() {
        let mut world = World::new("t");
        let a = world.add_room("a", RoomKind::Office, Rect::new(0.0, 0.0, 2.0, 2.0));
        let b = world.add_room("b", RoomKind::Corridor, Rect::new(2.1, 0.0, 4.0, 2.0));
        let door = world.add_door(
            DoorKind::Entrance,
            Point2::new(2.05, 1.0),
            0.9,
            0.1,
            0.0,
            [a, b],
        );
        let leaf = world.close_door(door).unwrap();
        assert_eq!(world.close_door(door).unwrap(), leaf);
        let shape = world.obstacle(leaf).unwrap().shape;
        assert!(
            shape.contains(&Point2::new(2.05, 1.44)) && !shape.contains(&Point2::new(2.05, 1.6))
        );
        assert!(shape.bounds().width_m() < 0.06);
        assert_eq!(world.doors_of(a).count(), 1);
        assert!(world.close_door(DoorId(9)).is_err());
    }

    #[test]
    fn ids_stay_stable_when_obstacles_go() {
        let mut world = World::new("t");
        let shape = Shape::Rect(Rect::new(0.0, 0.0, 1.0, 1.0));
        let first = world.add_obstacle(ObstacleKind::Furniture, shape, None);
        let second = world.add_obstacle(ObstacleKind::Furniture, shape, None);
        assert!(world.remove_obstacle(first).is_some());
        assert!(world.remove_obstacle(second).is_some());
        let third = world.add_obstacle(ObstacleKind::Furniture, shape, None);
        assert_eq!((first.0, second.0, third.0), (0, 1, 2));
        assert!(world.obstacle(first).is_none());
    }
}
