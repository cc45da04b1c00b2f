//! The warehouse generator: one large hall with identical rows of back-to-back racking (with
//! their uprights every bay), a cross aisle, a loading area with loose pallets and a couple
//! of offices along the front wall. Highly repetitive on purpose: every aisle looks like every
//! other to a laser.

use std::f64::consts::FRAC_PI_2;

use mapmerge_geometry::Se2;
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::furniture::furnish;
use crate::rng::{stream_rng, uniform, Stream};
use crate::shapes::{Rect, Shape};
use crate::world::{DoorKind, ObstacleKind, RoomKind, World};
use crate::{Point2, SimError};

/// How far the uprights stand out of the racking's faces (m).
const UPRIGHT_PROTRUSION_M: f64 = 0.04;
/// Side of an upright along the row (m).
const UPRIGHT_SIDE_M: f64 = 0.1;

/// Parameters of a warehouse hall (the `warehouse` preset). Lengths in metres.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WarehouseParams {
    /// Outer size along x (default: 40).
    pub width_m: f64,
    /// Outer size along y (default: 30).
    pub height_m: f64,
    /// Outer wall thickness (default: 0.3).
    pub outer_wall_m: f64,
    /// Inner (office) wall thickness (default: 0.15).
    pub inner_wall_m: f64,
    /// Depth of one rack; rows are two racks back to back (default: 1.1).
    pub rack_depth_m: f64,
    /// Clear width of the aisles between rows (default: 3.0).
    pub aisle_width_m: f64,
    /// Length of one bay; uprights stand between bays (default: 2.7).
    pub bay_length_m: f64,
    /// Bays per row block (default: 3). Fewer when the hall is too short.
    pub bays_per_block: usize,
    /// Row blocks along y, separated by cross aisles (default: 2).
    pub blocks: usize,
    /// Width of the cross aisles and of the front and back aisles (default: 3.0).
    pub cross_aisle_m: f64,
    /// Free width kept at the left end of the rows (default: 3.5).
    pub west_aisle_m: f64,
    /// Free width of the loading area at the right end (default: 7.0).
    pub dock_width_m: f64,
    /// Offices along the front wall, at the left (default: 2).
    pub office_count: usize,
    /// Office size along x (default: 5.0).
    pub office_width_m: f64,
    /// Office size along y (default: 4.0).
    pub office_depth_m: f64,
    /// Door width (default: 0.95).
    pub door_width_m: f64,
    /// Loose pallets in the loading area (default: 5).
    pub pallets: usize,
}

impl Default for WarehouseParams {
    fn default() -> Self {
        Self {
            width_m: 40.0,
            height_m: 30.0,
            outer_wall_m: 0.3,
            inner_wall_m: 0.15,
            rack_depth_m: 1.1,
            aisle_width_m: 3.0,
            bay_length_m: 2.7,
            bays_per_block: 3,
            blocks: 2,
            cross_aisle_m: 3.0,
            west_aisle_m: 3.5,
            dock_width_m: 7.0,
            office_count: 2,
            office_width_m: 5.0,
            office_depth_m: 4.0,
            door_width_m: 0.95,
            pallets: 5,
        }
    }
}

/// Generates a warehouse named `name`.
pub(crate) fn generate_warehouse(
    name: &str,
    p: &WarehouseParams,
    seed: u64,
) -> Result<World, SimError> {
    validate(p)?;
    let mut rng = stream_rng(seed, Stream::World, 0);
    let (w, h, to, ti) = (p.width_m, p.height_m, p.outer_wall_m, p.inner_wall_m);
    let mut world = World::new(name);
    world.footprint.push(Rect::new(0.0, 0.0, w, h));
    for rect in [
        Rect::new(0.0, 0.0, w, to),
        Rect::new(0.0, h - to, w, h),
        Rect::new(0.0, to, to, h - to),
        Rect::new(w - to, to, w, h - to),
    ] {
        world.add_obstacle(ObstacleKind::Wall, Shape::Rect(rect), None);
    }
    // Rows: x positions of the rows' left faces, as many as fit before the loading area.
    let row_depth = 2.0 * p.rack_depth_m;
    let rows_x0 = to + p.west_aisle_m;
    let rows_limit = w - to - p.dock_width_m;
    let mut row_xs = Vec::new();
    let mut x = rows_x0;
    while x + row_depth <= rows_limit + 1e-9 {
        row_xs.push(x);
        x += row_depth + p.aisle_width_m;
    }
    let rows_x1 = row_xs.last().map_or(rows_x0, |x| x + row_depth);
    // Blocks along y, above the offices and the front aisle.
    let front_y0 = to
        + if p.office_count > 0 {
            p.office_depth_m + ti
        } else {
            0.0
        };
    let blocks_y0 = front_y0 + p.cross_aisle_m;
    let available = h - to - p.cross_aisle_m - blocks_y0;
    let blocks = p.blocks.max(1);
    let mut bays = p.bays_per_block.max(1);
    while bays > 1
        && blocks as f64 * bays as f64 * p.bay_length_m + (blocks - 1) as f64 * p.cross_aisle_m
            > available
    {
        bays -= 1;
    }
    let block_length = bays as f64 * p.bay_length_m;
    if blocks as f64 * block_length + (blocks - 1) as f64 * p.cross_aisle_m > available
        || row_xs.is_empty()
    {
        return Err(SimError::InvalidParams {
            field: "warehouse.height_m",
            reason: "the hall is too small for one row of racking".to_owned(),
        });
    }
    let block_y0 = |b: usize| blocks_y0 + b as f64 * (block_length + p.cross_aisle_m);
    let blocks_y1 = block_y0(blocks - 1) + block_length;
    // Offices along the front wall, doors up into the front aisle.
    let mut offices = Vec::new();
    let mut ox = to;
    for k in 0..p.office_count {
        let rect = Rect::new(ox, to, ox + p.office_width_m, to + p.office_depth_m);
        let id = world.add_room(format!("office-{}", k + 1), RoomKind::Office, rect);
        offices.push((id, rect));
        ox += p.office_width_m + ti;
    }
    let front = world.add_room(
        "front-aisle",
        RoomKind::Hall,
        Rect::new(to, front_y0, rows_x1, blocks_y0),
    );
    world.add_room(
        "west-aisle",
        RoomKind::Hall,
        Rect::new(to, blocks_y0, rows_x0, blocks_y1),
    );
    world.add_room(
        "back-aisle",
        RoomKind::Hall,
        Rect::new(to, blocks_y1, rows_x1, h - to),
    );
    let dock = world.add_room(
        "dock",
        RoomKind::Hall,
        Rect::new(rows_x1, to, w - to, h - to),
    );
    for b in 0..blocks.saturating_sub(1) {
        let y0 = block_y0(b) + block_length;
        world.add_room(
            format!("cross-aisle-{}", b + 1),
            RoomKind::Hall,
            Rect::new(rows_x0, y0, rows_x1, y0 + p.cross_aisle_m),
        );
    }
    // Aisles between rows: all look alike (one alias group), frames at their lower-left corner.
    let mut aisle_number = 0;
    for b in 0..blocks {
        for pair in row_xs.windows(2) {
            aisle_number += 1;
            let rect = Rect::new(
                pair[0] + row_depth,
                block_y0(b),
                pair[1],
                block_y0(b) + block_length,
            );
            let id = world.add_room(format!("aisle-{aisle_number:02}"), RoomKind::Aisle, rect);
            if let Some(room) = world.rooms.iter_mut().find(|r| r.id == id) {
                room.alias_group = Some(0);
                room.world_from_room = Se2::new(rect.min_m.x, rect.min_m.y, 0.0);
            }
        }
    }
    // Office walls: a front wall with one door per office, and side walls.
    if !offices.is_empty() {
        let wall_y0 = to + p.office_depth_m;
        let mut openings = Vec::new();
        for &(id, rect) in &offices {
            let door_x0 =
                rect.min_m.x + uniform(&mut rng, 0.3, rect.width_m() - p.door_width_m - 0.3);
            world.add_door(
                DoorKind::Entrance,
                Point2::new(door_x0 + 0.5 * p.door_width_m, wall_y0 + 0.5 * ti),
                p.door_width_m,
                ti,
                FRAC_PI_2,
                [id, front],
            );
            openings.push((door_x0, door_x0 + p.door_width_m));
        }
        let mut cursor = to;
        for (a, b) in openings {
            world.add_obstacle(
                ObstacleKind::Wall,
                Shape::Rect(Rect::new(cursor, wall_y0, a, wall_y0 + ti)),
                None,
            );
            cursor = b;
        }
        world.add_obstacle(
            ObstacleKind::Wall,
            Shape::Rect(Rect::new(cursor, wall_y0, ox, wall_y0 + ti)),
            None,
        );
        for &(_, rect) in &offices {
            world.add_obstacle(
                ObstacleKind::Wall,
                Shape::Rect(Rect::new(rect.max_m.x, to, rect.max_m.x + ti, wall_y0)),
                None,
            );
        }
    }
    // Racking: a solid double rack per row and block, uprights standing out every bay.
    for b in 0..blocks {
        let y0 = block_y0(b);
        for &x0 in &row_xs {
            world.add_obstacle(
                ObstacleKind::Shelf,
                Shape::Rect(Rect::new(x0, y0, x0 + row_depth, y0 + block_length)),
                None,
            );
            for k in 0..=bays {
                let y = (y0 + k as f64 * p.bay_length_m).clamp(
                    y0 + 0.5 * UPRIGHT_SIDE_M,
                    y0 + block_length - 0.5 * UPRIGHT_SIDE_M,
                );
                world.add_obstacle(
                    ObstacleKind::Shelf,
                    Shape::Rect(Rect::new(
                        x0 - UPRIGHT_PROTRUSION_M,
                        y - 0.5 * UPRIGHT_SIDE_M,
                        x0 + row_depth + UPRIGHT_PROTRUSION_M,
                        y + 0.5 * UPRIGHT_SIDE_M,
                    )),
                    None,
                );
            }
        }
    }
    // Furniture: desks in the offices, pallets in the loading area (kept off its left edge so
    // the ends of the aisles stay open).
    for &(id, rect) in &offices {
        let count = rng.random_range(1..=3);
        let zone = office_door_zone(&world, id, &rect);
        let shapes = furnish(&mut rng, rect.width_m(), rect.height_m(), &zone, &[], count);
        for shape in shapes {
            world.add_obstacle(
                ObstacleKind::Furniture,
                shape.transformed(&Se2::new(rect.min_m.x, rect.min_m.y, 0.0)),
                Some(id),
            );
        }
    }
    if let Some(dock_room) = world.room(dock).cloned() {
        let rect = dock_room.rect;
        let lane = Rect::new(0.0, 0.0, 1.5, rect.height_m());
        let mut pallet_rng = stream_rng(seed, Stream::Furniture, 0);
        let mut taken = vec![lane];
        for _ in 0..p.pallets {
            for _ in 0..40 {
                let size = if pallet_rng.random::<bool>() {
                    Point2::new(1.2, 0.8)
                } else {
                    Point2::new(0.8, 1.2)
                };
                let center = Point2::new(
                    uniform(&mut pallet_rng, 1.5 + 0.6, rect.width_m() - 0.6),
                    uniform(&mut pallet_rng, 0.6, rect.height_m() - 0.6),
                );
                let candidate = Rect::from_center(center, size);
                if !taken
                    .iter()
                    .any(|t| t.overlaps(&candidate.expanded(crate::furniture::FURNITURE_GAP_M)))
                {
                    taken.push(candidate);
                    world.add_obstacle(
                        ObstacleKind::Furniture,
                        Shape::Rect(candidate.translated(&rect.min_m)),
                        Some(dock),
                    );
                    break;
                }
            }
        }
    }
    Ok(world)
}

/// The door zone of an office in its own frame (lower-left corner at the origin).
fn office_door_zone(world: &World, id: crate::RoomId, rect: &Rect) -> Vec<Rect> {
    world
        .doors_of(id)
        .map(|door| {
            let x = door.center_m.x - rect.min_m.x;
            crate::furniture::door_zone(
                2,
                x - 0.5 * door.width_m,
                x + 0.5 * door.width_m,
                rect.width_m(),
                rect.height_m(),
            )
        })
        .collect()
}

fn validate(p: &WarehouseParams) -> Result<(), SimError> {
    let positive = [
        ("warehouse.width_m", p.width_m),
        ("warehouse.height_m", p.height_m),
        ("warehouse.outer_wall_m", p.outer_wall_m),
        ("warehouse.inner_wall_m", p.inner_wall_m),
        ("warehouse.rack_depth_m", p.rack_depth_m),
        ("warehouse.aisle_width_m", p.aisle_width_m),
        ("warehouse.bay_length_m", p.bay_length_m),
        ("warehouse.cross_aisle_m", p.cross_aisle_m),
        ("warehouse.west_aisle_m", p.west_aisle_m),
        ("warehouse.dock_width_m", p.dock_width_m),
        ("warehouse.office_width_m", p.office_width_m),
        ("warehouse.office_depth_m", p.office_depth_m),
        ("warehouse.door_width_m", p.door_width_m),
    ];
    for (field, value) in positive {
        if !(value.is_finite() && value > 0.0) {
            return Err(SimError::InvalidParams {
                field,
                reason: "must be positive and finite".to_owned(),
            });
        }
    }
    if p.office_width_m < p.door_width_m + 0.6 {
        return Err(SimError::InvalidParams {
            field: "warehouse.office_width_m",
            reason: "the door does not fit".to_owned(),
        });
    }
    let offices_end = p.outer_wall_m + p.office_count as f64 * (p.office_width_m + p.inner_wall_m);
    if offices_end > p.width_m - p.outer_wall_m - p.dock_width_m {
        return Err(SimError::InvalidParams {
            field: "warehouse.office_count",
            reason: "the offices do not fit along the front wall".to_owned(),
        });
    }
    Ok(())
}
