//! The symmetric-hall generator: a lobby between two office wings whose whole block (the hall,
//! a row of rooms on each side of it, their walls, doors and furniture) is point-symmetric: a
//! turn by 180° about the hall's centre maps it onto itself. A laser sees the same from a pose
//! and from that pose turned about the centre, so places on opposite sides of the hall look
//! alike ("ambiguous views": a view observable from several distinct places), while the two
//! wings, generated independently, tell the places apart once the robot has travelled a bit.
//!
//! From west to east: the west wing (an office floor), the hall block, the east wing. The west
//! wing's lower corridor (`corridor-1`) opens into the hall at its south-west corner, the east
//! wing's upper corridor (`corridor-2`) at its north-east corner, the image of the first under
//! the turn. The hall block's south row of rooms (doors up into the hall) is turned into its
//! north row (doors down); the furniture and pillars of the hall's west half are turned into
//! its east half; a counter stands at the centre.
//!
//! Look-alikes: the two halves of the hall (`hall-west`, `hall-east`) form one alias group,
//! each south room and its turned north copy another, with room frames related by the turn,
//! so look-alike kidnaps put the robot on the opposite side of the hall, facing the other way.

use std::f64::consts::{FRAC_PI_2, PI};

use mapmerge_geometry::{LieGroup, Se2};
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::furniture::{door_zone, furnish, FURNITURE_GAP_M};
use crate::office::{generate_office, new_template, random_widths, OfficeParams, Template};
use crate::rng::{derive_seed, stream_rng, uniform, SimRng, Stream};
use crate::roadmap::unreachable_destinations;
use crate::shapes::{LineSegment, Rect, Shape};
use crate::world::{DoorKind, ObstacleKind, RoomId, RoomKind, World};
use crate::{Point2, SimError};

/// Side of a (square) pillar in the hall (m).
const PILLAR_SIDE_M: f64 = 0.4;
/// Shortest distance from a pillar's centre to the hall's walls (m).
const PILLAR_WALL_MARGIN_M: f64 = 1.5;
/// Shortest distance from a pillar's centre to the hall's centre line (m), so a pillar and
/// its turned copy stand well apart.
const PILLAR_CENTRE_MARGIN_M: f64 = 1.2;
/// Free gap kept around pillars and the counter (m).
const PILLAR_GAP_M: f64 = 1.0;
/// Half width of the strip along the hall's centre line kept free of furniture (m), so a
/// piece and its turned copy keep the furniture gap between them.
const CENTRE_STRIP_M: f64 = 0.5 * FURNITURE_GAP_M;
/// Depth of the zone kept free in front of a corridor's mouth, inside the hall (m).
const MOUTH_ZONE_DEPTH_M: f64 = 2.0;
/// Furnishing attempts before the furniture that blocks the robot is left out.
const FURNISH_ATTEMPTS: usize = 4;

/// Parameters of the `symmetric-hall` preset: a point-symmetric hall block between two
/// office wings. Lengths in metres.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SymmetricHallParams {
    /// Clear width of the hall (and of its two rows of rooms) between the wings (default:
    /// 14.0). Its depth is the space between the wings' two corridors.
    pub hall_width_m: f64,
    /// Pieces of furniture in the hall's west half, each turned into the east half
    /// (default: 3).
    pub hall_furniture: usize,
    /// Square pillars in the hall's west half, each turned into the east half (default: 2).
    pub hall_pillars: usize,
    /// The west wing: an office floor with two corridors whose lower one opens into the hall
    /// (default: 11 × 20 m, connectors at both ends). Its room, door and furniture ranges are
    /// also the hall's rooms'.
    pub west_wing: OfficeParams,
    /// The east wing: an office floor with two corridors whose upper one opens into the hall
    /// (default: 15 × 20 m, connectors at 0.35 and the far end). Its height, walls and
    /// corridor width must be the west wing's.
    pub east_wing: OfficeParams,
}

impl Default for SymmetricHallParams {
    fn default() -> Self {
        Self {
            hall_width_m: 14.0,
            hall_furniture: 3,
            hall_pillars: 2,
            west_wing: OfficeParams {
                width_m: 11.0,
                height_m: 20.0,
                connector_positions: vec![0.0, 1.0],
                ..OfficeParams::default()
            },
            east_wing: OfficeParams {
                width_m: 15.0,
                height_m: 20.0,
                connector_positions: vec![0.35, 1.0],
                ..OfficeParams::default()
            },
        }
    }
}

/// Where the hall block lies (world frame).
struct Frame {
    /// Outer and inner wall thickness, corridor width, building height.
    outer_m: f64,
    inner_m: f64,
    corridor_m: f64,
    height_m: f64,
    /// The hall's clear x range (the wings' outer walls lie just outside it).
    x0: f64,
    x1: f64,
    /// Bottom of the hall (the bottom of the west wing's `corridor-1`); its top is
    /// `height_m - y0`.
    y0: f64,
}

impl Frame {
    fn centre(&self) -> Point2 {
        Point2::new(0.5 * (self.x0 + self.x1), 0.5 * self.height_m)
    }

    /// `p` turned by 180° about the hall's centre.
    fn turn_point(&self, p: &Point2) -> Point2 {
        Point2::new(self.x0 + self.x1 - p.x, self.height_m - p.y)
    }

    fn turn_rect(&self, r: &Rect) -> Rect {
        let (a, b) = (self.turn_point(&r.min_m), self.turn_point(&r.max_m));
        Rect::new(a.x, a.y, b.x, b.y)
    }

    fn turn_shape(&self, shape: &Shape) -> Shape {
        match shape {
            Shape::Rect(r) => Shape::Rect(self.turn_rect(r)),
            Shape::Box {
                center_m,
                half_size_m,
                yaw_rad,
            } => Shape::oriented(self.turn_point(center_m), *half_size_m, yaw_rad + PI),
            Shape::Segment(s) => Shape::Segment(LineSegment::new(
                self.turn_point(&s.start_m),
                self.turn_point(&s.end_m),
            )),
        }
    }

    /// The turn as a pose: `turn · world_from_a` is the frame turned about the centre.
    fn turn(&self) -> Se2 {
        Se2::new(self.x0 + self.x1, self.height_m, PI)
    }

    /// Top of the south row of rooms.
    fn row_top(&self) -> f64 {
        self.y0 - self.inner_m
    }
}

/// One room of the south row (its turned copy is in the north row).
struct RowRoom {
    x0: f64,
    x1: f64,
    template: Template,
}

/// The random choices that do not depend on the furnishing attempt.
struct Plan {
    rooms: Vec<RowRoom>,
    /// The counter at the hall's centre (world frame).
    counter: Rect,
    /// Pillars of the west half (world frame).
    pillars: Vec<Rect>,
}

/// Generates the symmetric hall named `name`.
pub(crate) fn generate_symmetric_hall(
    name: &str,
    p: &SymmetricHallParams,
    seed: u64,
) -> Result<World, SimError> {
    validate(p)?;
    let west = generate_office("west", &p.west_wing, derive_seed(seed, Stream::World, 1))?;
    let east = generate_office("east", &p.east_wing, derive_seed(seed, Stream::World, 2))?;
    let frame = frame(p, &west, &east)?;
    let mut rng = stream_rng(seed, Stream::World, 3);
    let plan = plan(&mut rng, p, &frame);
    let mut hall_count = p.hall_furniture;
    let mut room_counts: Vec<usize> = plan
        .rooms
        .iter()
        .map(|r| r.template.furniture_count)
        .collect();
    for attempt in 0..=FURNISH_ATTEMPTS {
        let counts = Counts {
            hall: hall_count,
            rooms: &room_counts,
            attempt: attempt as u64,
        };
        let (world, row_ids) = assemble(name, p, &west, &east, &frame, &plan, &counts, seed);
        let blocked = unreachable_destinations(&world);
        if blocked.is_empty() || attempt == FURNISH_ATTEMPTS {
            return Ok(world);
        }
        let last = attempt + 1 == FURNISH_ATTEMPTS;
        let fewer = |n: usize| if last { 0 } else { n.saturating_sub(1) };
        let mut hall_blocks = false;
        for room in blocked {
            match row_ids.iter().position(|&(s, n)| s == room || n == room) {
                Some(i) => room_counts[i] = fewer(room_counts[i]),
                None => hall_blocks = true,
            }
        }
        if hall_blocks {
            hall_count = fewer(hall_count);
        }
    }
    Err(SimError::NoFreeSpace(name.to_owned()))
}

fn validate(p: &SymmetricHallParams) -> Result<(), SimError> {
    let bad = |field: &'static str, reason: &str| {
        Err(SimError::InvalidParams {
            field,
            reason: reason.to_owned(),
        })
    };
    if !(p.hall_width_m.is_finite() && p.hall_width_m >= 8.0) {
        return bad(
            "symmetric_hall.hall_width_m",
            "must be finite and at least 8",
        );
    }
    for (field, wing) in [
        ("symmetric_hall.west_wing.corridor_count", &p.west_wing),
        ("symmetric_hall.east_wing.corridor_count", &p.east_wing),
    ] {
        if wing.corridor_count != 2 {
            return bad(field, "must be 2: the wings' corridors open into the hall");
        }
    }
    let (w, e) = (&p.west_wing, &p.east_wing);
    if w.height_m != e.height_m
        || w.outer_wall_m != e.outer_wall_m
        || w.inner_wall_m != e.inner_wall_m
        || w.corridor_width_m != e.corridor_width_m
    {
        return bad(
            "symmetric_hall.east_wing",
            "height, wall thicknesses and corridor width must be the west wing's",
        );
    }
    Ok(())
}

fn frame(p: &SymmetricHallParams, west: &World, east: &World) -> Result<Frame, SimError> {
    let w = &p.west_wing;
    let corridor = |world: &World, name: &str| {
        world
            .room_by_name(name)
            .map(|r| r.rect)
            .ok_or(SimError::InvalidParams {
                field: "symmetric_hall.west_wing",
                reason: format!("the wing has no {name}"),
            })
    };
    let lower = corridor(west, "corridor-1")?;
    let upper = corridor(east, "corridor-2")?;
    let frame = Frame {
        outer_m: w.outer_wall_m,
        inner_m: w.inner_wall_m,
        corridor_m: w.corridor_width_m,
        height_m: w.height_m,
        x0: w.width_m,
        x1: w.width_m + p.hall_width_m,
        y0: lower.min_m.y,
    };
    // The wings' bands are symmetric about mid-height, so the east wing's upper corridor is
    // the west wing's lower one turned about the hall's centre.
    let expected = frame.height_m - frame.y0;
    if (upper.max_m.y - expected).abs() > 1e-9 || (lower.height_m() - frame.corridor_m).abs() > 1e-9
    {
        return Err(SimError::InvalidParams {
            field: "symmetric_hall.east_wing",
            reason: "the wings' corridors do not line up".to_owned(),
        });
    }
    if frame.height_m - 2.0 * frame.y0 < 2.0 * frame.corridor_m + 1.0 {
        return Err(SimError::InvalidParams {
            field: "symmetric_hall.west_wing.height_m",
            reason: "too low: the hall between the corridors would be too shallow".to_owned(),
        });
    }
    Ok(frame)
}

/// The south row of rooms, the counter and the pillars.
fn plan(rng: &mut SimRng, p: &SymmetricHallParams, f: &Frame) -> Plan {
    let depth = f.row_top() - f.outer_m;
    let mut templates = Vec::new();
    let mut rooms = Vec::new();
    let mut x = f.x0;
    let widths = random_widths(rng, &p.west_wing, f.x1 - f.x0);
    let count = widths.len();
    for (i, w) in widths.into_iter().enumerate() {
        let index = new_template(rng, &p.west_wing, &mut templates, w, depth);
        // The last room ends exactly at the hall's east end.
        let x1 = if i + 1 == count { f.x1 } else { x + w };
        rooms.push(RowRoom {
            x0: x,
            x1,
            template: templates[index].clone(),
        });
        x = x1 + f.inner_m;
    }
    let centre = f.centre();
    let (long, short) = (uniform(rng, 1.6, 2.4), uniform(rng, 0.8, 1.1));
    let size = if rng.random::<bool>() {
        Point2::new(long, short)
    } else {
        Point2::new(short, long)
    };
    let counter = Rect::from_center(centre, size);
    let zones = hall_zones(f, &rooms);
    let mut taken = vec![counter];
    let mut pillars = Vec::new();
    let (u0, u1) = (
        f.x0 + PILLAR_WALL_MARGIN_M,
        centre.x - PILLAR_CENTRE_MARGIN_M,
    );
    let (v0, v1) = (
        f.y0 + PILLAR_WALL_MARGIN_M,
        f.height_m - f.y0 - PILLAR_WALL_MARGIN_M,
    );
    for _ in 0..p.hall_pillars {
        for _ in 0..60 {
            let at = Point2::new(uniform(rng, u0, u1), uniform(rng, v0, v1));
            let pillar = Rect::from_center(at, Point2::new(PILLAR_SIDE_M, PILLAR_SIDE_M));
            let grown = pillar.expanded(PILLAR_GAP_M);
            if u1 > u0
                && v1 > v0
                && !zones.iter().any(|z| z.overlaps(&pillar.expanded(0.5)))
                && !taken.iter().any(|t| t.overlaps(&grown))
            {
                taken.push(pillar);
                pillars.push(pillar);
                break;
            }
        }
    }
    Plan {
        rooms,
        counter,
        pillars,
    }
}

/// Zones of the hall kept free (world frame): in front of the corridors' mouths and of the
/// rooms' doors. The set is point-symmetric.
fn hall_zones(f: &Frame, rooms: &[RowRoom]) -> Vec<Rect> {
    let mouth = Rect::new(
        f.x0,
        f.y0,
        f.x0 + MOUTH_ZONE_DEPTH_M,
        f.y0 + f.corridor_m + 0.5,
    );
    let hall_depth = f.height_m - 2.0 * f.y0;
    let mut zones = vec![mouth, f.turn_rect(&mouth)];
    for room in rooms {
        let t = &room.template;
        let gap = room.x0 + t.door_offset_m;
        // The door's zone on the hall's side (in the hall's bottom wall, seen from the hall).
        let zone = door_zone(0, gap, gap + t.door_width_m, f.x1, hall_depth)
            .translated(&Point2::new(0.0, f.y0));
        zones.push(zone);
        zones.push(f.turn_rect(&zone));
    }
    zones
}

/// Furniture counts of one furnishing attempt.
struct Counts<'a> {
    hall: usize,
    rooms: &'a [usize],
    attempt: u64,
}

/// The whole world; also the ids of each (south, north) pair of row rooms.
#[allow(clippy::too_many_arguments)]
fn assemble(
    name: &str,
    p: &SymmetricHallParams,
    west: &World,
    east: &World,
    f: &Frame,
    plan: &Plan,
    counts: &Counts<'_>,
    seed: u64,
) -> (World, Vec<(RoomId, RoomId)>) {
    let (to, ti, h) = (f.outer_m, f.inner_m, f.height_m);
    let total_width = f.x1 + p.east_wing.width_m;
    let mut world = World::new(name);
    world.footprint.push(Rect::new(0.0, 0.0, total_width, h));
    // The wings, without the outer walls facing the hall (the hall block has its own).
    let w = p.west_wing.width_m;
    append(
        &mut world,
        west,
        0.0,
        "west-",
        &Rect::new(w - to, to, w, h - to),
    );
    append(
        &mut world,
        east,
        f.x1,
        "east-",
        &Rect::new(0.0, to, to, h - to),
    );
    let group = world
        .rooms
        .iter()
        .filter_map(|r| r.alias_group)
        .max()
        .map_or(0, |g| g + 1);
    let turn = f.turn();
    let centre = f.centre();
    // The hall, in two halves that are each other's turned copies.
    let top = h - f.y0;
    let west_half = world.add_room(
        "hall-west",
        RoomKind::Hall,
        Rect::new(f.x0, f.y0, centre.x, top),
    );
    let east_half = world.add_room(
        "hall-east",
        RoomKind::Hall,
        Rect::new(centre.x, f.y0, f.x1, top),
    );
    let west_frame = Se2::new(f.x0, f.y0, 0.0);
    set_frame(&mut world, west_half, west_frame, group);
    set_frame(&mut world, east_half, turn.compose(&west_frame), group);
    let half_of = |x: f64| if x < centre.x { west_half } else { east_half };
    // The rows of rooms: south ones first, then their turned copies.
    let row_top = f.row_top();
    let n = plan.rooms.len();
    let mut row_ids = Vec::with_capacity(n);
    for (i, room) in plan.rooms.iter().enumerate() {
        let kind = if room.template.storage {
            RoomKind::Storage
        } else {
            RoomKind::Office
        };
        let rect = Rect::new(room.x0, to, room.x1, row_top);
        let south = world.add_room(format!("hall-room-{:02}", i + 1), kind, rect);
        row_ids.push((south, south));
        set_frame(
            &mut world,
            south,
            Se2::new(room.x0, to, 0.0),
            group + 1 + i as u32,
        );
    }
    for (i, room) in plan.rooms.iter().enumerate() {
        let rect = f.turn_rect(&Rect::new(room.x0, to, room.x1, row_top));
        let kind = if room.template.storage {
            RoomKind::Storage
        } else {
            RoomKind::Office
        };
        let north = world.add_room(format!("hall-room-{:02}", n + i + 1), kind, rect);
        row_ids[i].1 = north;
        let south_frame = Se2::new(room.x0, to, 0.0);
        set_frame(
            &mut world,
            north,
            turn.compose(&south_frame),
            group + 1 + i as u32,
        );
    }
    // Doors from the rooms into the hall, and the wall between them.
    let mut gaps = Vec::with_capacity(n);
    for (room, &(south, north)) in plan.rooms.iter().zip(&row_ids) {
        let t = &room.template;
        let (a, b) = (
            room.x0 + t.door_offset_m,
            room.x0 + t.door_offset_m + t.door_width_m,
        );
        let centre_m = Point2::new(0.5 * (a + b), row_top + 0.5 * ti);
        world.add_door(
            DoorKind::Entrance,
            centre_m,
            t.door_width_m,
            ti,
            FRAC_PI_2,
            [south, half_of(centre_m.x)],
        );
        let turned = f.turn_point(&centre_m);
        world.add_door(
            DoorKind::Entrance,
            turned,
            t.door_width_m,
            ti,
            -FRAC_PI_2,
            [north, half_of(turned.x)],
        );
        gaps.push((a, b));
    }
    // Walls of the block's south half; each is added with its turned copy.
    let mut walls = vec![
        Rect::new(f.x0, 0.0, f.x1, to),
        Rect::new(f.x0 - to, to, f.x0, f.y0),
        Rect::new(f.x0 - to, f.y0 + f.corridor_m, f.x0, h - to),
    ];
    for pair in plan.rooms.windows(2) {
        walls.push(Rect::new(pair[0].x1, to, pair[1].x0, row_top));
    }
    let mut cursor = f.x0;
    for &(a, b) in &gaps {
        if a > cursor {
            walls.push(Rect::new(cursor, row_top, a, f.y0));
        }
        cursor = b;
    }
    if f.x1 > cursor {
        walls.push(Rect::new(cursor, row_top, f.x1, f.y0));
    }
    for pillar in &plan.pillars {
        walls.push(*pillar);
    }
    for wall in walls {
        let shape = Shape::Rect(wall);
        world.add_obstacle(ObstacleKind::Wall, shape, None);
        world.add_obstacle(ObstacleKind::Wall, f.turn_shape(&shape), None);
    }
    // The counter at the centre is its own turned copy.
    world.add_obstacle(ObstacleKind::Furniture, Shape::Rect(plan.counter), None);
    // Furniture of the rooms, turned into their copies.
    for (i, (room, &(south, north))) in plan.rooms.iter().zip(&row_ids).enumerate() {
        let t = &room.template;
        let zone = door_zone(
            2,
            t.door_offset_m,
            t.door_offset_m + t.door_width_m,
            t.width_m,
            t.depth_m,
        );
        let mut rng = stream_rng(
            seed,
            Stream::Furniture,
            (i as u64 + 1) * 16 + counts.attempt,
        );
        let world_from_room = Se2::new(room.x0, to, 0.0);
        let count = counts.rooms.get(i).copied().unwrap_or(0);
        for shape in furnish(&mut rng, t.width_m, t.depth_m, &[zone], &[], count) {
            let placed = shape.transformed(&world_from_room);
            world.add_obstacle(ObstacleKind::Furniture, placed, Some(south));
            world.add_obstacle(ObstacleKind::Furniture, f.turn_shape(&placed), Some(north));
        }
    }
    // Furniture of the hall's west half, turned into the east half.
    let hall_width = centre.x - f.x0;
    let hall_depth = top - f.y0;
    let to_half = |r: &Rect| r.translated(&Point2::new(-f.x0, -f.y0));
    // Zones kept free, plus the strip along the centre line: a piece and its turned copy
    // then keep the furniture gap between them.
    let strip = Rect::new(
        centre.x - CENTRE_STRIP_M,
        f.y0,
        centre.x + CENTRE_STRIP_M,
        top,
    );
    let zones: Vec<Rect> = hall_zones(f, &plan.rooms)
        .iter()
        .chain(std::iter::once(&strip))
        .map(to_half)
        .collect();
    let existing: Vec<Rect> = std::iter::once(&plan.counter)
        .chain(&plan.pillars)
        .map(to_half)
        .collect();
    let mut rng = stream_rng(seed, Stream::Furniture, counts.attempt);
    for shape in furnish(
        &mut rng,
        hall_width,
        hall_depth,
        &zones,
        &existing,
        counts.hall,
    ) {
        let placed = shape.transformed(&west_frame);
        world.add_obstacle(ObstacleKind::Furniture, placed, Some(west_half));
        world.add_obstacle(
            ObstacleKind::Furniture,
            f.turn_shape(&placed),
            Some(east_half),
        );
    }
    (world, row_ids)
}

fn set_frame(world: &mut World, id: RoomId, world_from_room: Se2, group: u32) {
    if let Some(room) = world.rooms.iter_mut().find(|r| r.id == id) {
        room.world_from_room = world_from_room;
        room.alias_group = Some(group);
    }
}

/// Adds `part` shifted by `dx` along x, its rooms' names prefixed, its alias groups renumbered
/// after `world`'s, without the wall `skip`.
fn append(world: &mut World, part: &World, dx: f64, prefix: &str, skip: &Rect) {
    let offset = Point2::new(dx, 0.0);
    let shift = Se2::new(dx, 0.0, 0.0);
    let group_base = world
        .rooms
        .iter()
        .filter_map(|r| r.alias_group)
        .max()
        .map_or(0, |g| g + 1);
    let mut ids = Vec::with_capacity(part.rooms.len());
    for room in &part.rooms {
        let id = world.add_room(
            format!("{prefix}{}", room.name),
            room.kind,
            room.rect.translated(&offset),
        );
        if let Some(added) = world.rooms.iter_mut().find(|r| r.id == id) {
            added.world_from_room = shift.compose(&room.world_from_room);
            added.alias_group = room.alias_group.map(|g| g + group_base);
        }
        ids.push((room.id, id));
    }
    let map = |id: RoomId| {
        ids.iter()
            .find(|(old, _)| *old == id)
            .map_or(id, |(_, new)| *new)
    };
    for door in &part.doors {
        world.add_door(
            door.kind,
            door.center_m + offset,
            door.width_m,
            door.wall_thickness_m,
            door.passage_yaw_rad,
            [map(door.rooms[0]), map(door.rooms[1])],
        );
    }
    for obstacle in &part.obstacles {
        if obstacle.kind == ObstacleKind::Wall && obstacle.shape == Shape::Rect(*skip) {
            continue;
        }
        let shape = match obstacle.shape {
            Shape::Rect(r) => Shape::Rect(r.translated(&offset)),
            Shape::Box {
                center_m,
                half_size_m,
                yaw_rad,
            } => Shape::Box {
                center_m: center_m + offset,
                half_size_m,
                yaw_rad,
            },
            Shape::Segment(s) => {
                Shape::Segment(LineSegment::new(s.start_m + offset, s.end_m + offset))
            }
        };
        world.add_obstacle(obstacle.kind, shape, obstacle.room.map(map));
    }
}
