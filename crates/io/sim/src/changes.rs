//! Changes between sessions: doors closed, furniture moved, added and removed. Every later
//! session's world is session 0's world with its own independent set of changes, so each
//! session's list describes exactly how it differs from session 0.

use mapmerge_geometry::Se2;
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::furniture::{door_zone, furnish};
use crate::rng::SimRng;
use crate::world::{DoorId, ObstacleId, ObstacleKind, RoomId, RoomKind, World};
use crate::{Rect, Shape, SimError};

/// How much a later session's world differs from session 0's. Counts are upper bounds:
/// fewer happen when the world has too few doors or pieces, or no room has space.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ChangeParams {
    /// Doors closed in each later session (default: 1). A room whose only door is closed
    /// cannot be visited in that session.
    pub doors_closed: usize,
    /// Pieces of furniture moved within their room (default: 2).
    pub furniture_moved: usize,
    /// Pieces of furniture added to random rooms (default: 1).
    pub furniture_added: usize,
    /// Pieces of furniture removed (default: 1).
    pub furniture_removed: usize,
}

impl Default for ChangeParams {
    fn default() -> Self {
        Self {
            doors_closed: 1,
            furniture_moved: 2,
            furniture_added: 1,
            furniture_removed: 1,
        }
    }
}

impl ChangeParams {
    /// No changes: every session sees session 0's world.
    pub fn none() -> Self {
        Self {
            doors_closed: 0,
            furniture_moved: 0,
            furniture_added: 0,
            furniture_removed: 0,
        }
    }
}

/// One difference from session 0's world.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum WorldChange {
    /// A door was closed; its leaf is a new obstacle.
    DoorClosed {
        /// The door.
        door: DoorId,
        /// The leaf filling the doorway.
        leaf: ObstacleId,
    },
    /// A piece of furniture stands somewhere else in its room (same id).
    FurnitureMoved {
        /// The piece.
        obstacle: ObstacleId,
        /// Its room.
        room: Option<RoomId>,
        /// Where it stood in session 0.
        from: Shape,
        /// Where it stands now.
        to: Shape,
    },
    /// A new piece of furniture.
    FurnitureAdded {
        /// Its new id.
        obstacle: ObstacleId,
        /// Its room.
        room: Option<RoomId>,
        /// Where it stands.
        shape: Shape,
    },
    /// A piece of furniture is gone.
    FurnitureRemoved {
        /// Its id in session 0.
        obstacle: ObstacleId,
        /// Its room.
        room: Option<RoomId>,
        /// Where it stood.
        shape: Shape,
    },
}

/// A copy of `world` with random changes drawn from `rng`, and the list of them.
pub(crate) fn change_world(
    rng: &mut SimRng,
    world: &World,
    params: &ChangeParams,
) -> Result<(World, Vec<WorldChange>), SimError> {
    let mut changed = world.clone();
    let mut changes = Vec::new();
    // 1. Close doors.
    let doors: Vec<DoorId> = world
        .doors
        .iter()
        .filter(|d| d.closed_by.is_none())
        .map(|d| d.id)
        .collect();
    for door in pick(rng, &doors, params.doors_closed) {
        let leaf = changed.close_door(door)?;
        changes.push(WorldChange::DoorClosed { door, leaf });
    }
    // 2. Remove furniture.
    let furniture: Vec<ObstacleId> = world
        .obstacles
        .iter()
        .filter(|o| o.kind == ObstacleKind::Furniture)
        .map(|o| o.id)
        .collect();
    let removed = pick(rng, &furniture, params.furniture_removed);
    for &id in &removed {
        if let Some(obstacle) = changed.remove_obstacle(id) {
            changes.push(WorldChange::FurnitureRemoved {
                obstacle: id,
                room: obstacle.room,
                shape: obstacle.shape,
            });
        }
    }
    // 3. Move furniture within its room.
    let movable: Vec<ObstacleId> = furniture
        .iter()
        .copied()
        .filter(|id| !removed.contains(id))
        .collect();
    for id in pick(rng, &movable, params.furniture_moved) {
        let Some(obstacle) = changed.obstacle(id).cloned() else {
            continue;
        };
        let Some(room) = obstacle.room.and_then(|r| changed.room(r)).cloned() else {
            continue;
        };
        let Some(shape) = place_in_room(rng, &changed, room.id, &room.rect, Some(id)) else {
            continue;
        };
        if let Some(slot) = changed.obstacles.iter_mut().find(|o| o.id == id) {
            slot.shape = shape;
        }
        changes.push(WorldChange::FurnitureMoved {
            obstacle: id,
            room: Some(room.id),
            from: obstacle.shape,
            to: shape,
        });
    }
    // 4. Add furniture to random rooms.
    let rooms: Vec<RoomId> = world
        .rooms
        .iter()
        .filter(|r| matches!(r.kind, RoomKind::Office | RoomKind::Hall))
        .map(|r| r.id)
        .collect();
    for _ in 0..params.furniture_added {
        if rooms.is_empty() {
            break;
        }
        let room_id = rooms[rng.random_range(0..rooms.len())];
        let Some(rect) = changed.room(room_id).map(|r| r.rect) else {
            continue;
        };
        if let Some(shape) = place_in_room(rng, &changed, room_id, &rect, None) {
            let obstacle = changed.add_obstacle(ObstacleKind::Furniture, shape, Some(room_id));
            changes.push(WorldChange::FurnitureAdded {
                obstacle,
                room: Some(room_id),
                shape,
            });
        }
    }
    Ok((changed, changes))
}

/// Up to `count` distinct items of `items`, in random order (partial Fisher–Yates).
fn pick<T: Copy>(rng: &mut SimRng, items: &[T], count: usize) -> Vec<T> {
    let mut pool = items.to_vec();
    let count = count.min(pool.len());
    for i in 0..count {
        let j = rng.random_range(i..pool.len());
        pool.swap(i, j);
    }
    pool.truncate(count);
    pool
}

/// A free spot for one new piece in `room` (interior `rect`), away from its doors and from the
/// other obstacles in it (`ignore`: the piece being moved).
fn place_in_room(
    rng: &mut SimRng,
    world: &World,
    room: RoomId,
    rect: &Rect,
    ignore: Option<ObstacleId>,
) -> Option<Shape> {
    let origin = rect.min_m;
    let (width, depth) = (rect.width_m(), rect.height_m());
    let zones: Vec<Rect> = world
        .doors_of(room)
        .map(|door| {
            let local = door.center_m - origin;
            let half = 0.5 * door.width_m;
            // The wall the door is in, seen from the room: 0 bottom, 1 right, 2 top, 3 left.
            let (wall, along) = if (local.y - depth).abs() < 0.5 * door.wall_thickness_m + 0.05 {
                (2, local.x)
            } else if local.y.abs() < 0.5 * door.wall_thickness_m + 0.05 {
                (0, local.x)
            } else if (local.x - width).abs() < 0.5 * door.wall_thickness_m + 0.05 {
                (1, local.y)
            } else {
                (3, local.y)
            };
            door_zone(wall, along - half, along + half, width, depth)
        })
        .collect();
    let existing: Vec<Rect> = world
        .obstacles
        .iter()
        .filter(|o| Some(o.id) != ignore && o.kind != ObstacleKind::Wall)
        .map(|o| o.shape.bounds())
        .filter(|b| b.overlaps(&rect.expanded(crate::furniture::FURNITURE_GAP_M)))
        .map(|b| b.translated(&-origin))
        .collect();
    let shapes = furnish(rng, width, depth, &zones, &existing, 1);
    shapes
        .first()
        .map(|shape| shape.transformed(&Se2::new(origin.x, origin.y, 0.0)))
}
