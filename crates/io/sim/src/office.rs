//! The office-floor generator: horizontal bands of rooms and corridors (double-loaded
//! corridors, the common plan of office buildings), vertical connector corridors through the
//! middle band (which close corridor loops), doors from every room to a corridor and a few
//! between neighbouring rooms, furniture in every room, and optionally deliberately repeated
//! rooms and corridor sections (perceptual aliasing).
//!
//! Bands from the bottom, with two corridors:
//! `rooms (doors up) | corridor-1 | rooms (doors up or down) + connectors | corridor-2 | rooms (doors down)`;
//! with one corridor: `rooms (doors up) | corridor-1 | rooms (doors down)`.
//!
//! Every room is an instance of a template (size, door, furniture in the room's own frame);
//! copies share a template and are placed upright (door up) or turned by 180° (door down),
//! so copies look identical to a laser up to a rigid motion.

use std::f64::consts::{FRAC_PI_2, PI};

use mapmerge_geometry::{LieGroup, Se2};
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::furniture::{door_zone, furnish, DOOR_ZONE_DEPTH_M, DOOR_ZONE_SIDE_M};
use crate::rng::{stream_rng, uniform, SimRng, Stream};
use crate::roadmap::unreachable_destinations;
use crate::shapes::{Rect, Shape};
use crate::world::{DoorKind, ObstacleKind, RoomId, RoomKind, World};
use crate::{Point2, SimError};

/// Narrowest gap that becomes a (storage) room rather than solid wall (m).
const MIN_STORAGE_WIDTH_M: f64 = 1.6;
/// Shortest distance from a door's jamb to the room's corner (m).
const DOOR_CORNER_MARGIN_M: f64 = 0.25;
/// Furnishing attempts before rooms that the robot cannot reach are left empty.
const FURNISH_ATTEMPTS: u64 = 4;

/// Parameters of an office floor (the `office`, `office-aliased` and `corridor-loop`
/// presets, and the wings of `symmetric-hall`). Lengths in metres.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OfficeParams {
    /// Outer size of the building along x (default: 30).
    pub width_m: f64,
    /// Outer size of the building along y (default: 20).
    pub height_m: f64,
    /// Horizontal corridors, 1 or 2 (default: 2). Two corridors make three room bands, the
    /// middle one crossed by the connectors.
    pub corridor_count: usize,
    /// Clear width of every corridor (default: 2.0).
    pub corridor_width_m: f64,
    /// Vertical connector corridors through the middle band, as fractions of the building's
    /// inner width: 0 at the left end, 1 at the right end (default: `[0.0, 0.55]`). Two
    /// corridors plus connectors at 0 and 1 make a ring. Ignored with one corridor.
    pub connector_positions: Vec<f64>,
    /// Thickness of the outer walls (default: 0.3).
    pub outer_wall_m: f64,
    /// Thickness of the inner walls (default: 0.15).
    pub inner_wall_m: f64,
    /// Narrowest room (default: 3.0). Leftover gaps narrower than this become storage rooms.
    pub room_width_min_m: f64,
    /// Widest room (default: 8.0).
    pub room_width_max_m: f64,
    /// Narrowest door gap (default: 0.9).
    pub door_width_min_m: f64,
    /// Widest door gap (default: 1.0).
    pub door_width_max_m: f64,
    /// Fewest pieces of furniture per office (default: 1).
    pub furniture_min: usize,
    /// Most pieces of furniture per office (default: 4). Small rooms may get fewer.
    pub furniture_max: usize,
    /// Probability of a door between two neighbouring unique rooms (default: 0.2).
    pub connecting_door_probability: f64,
    /// Copies of one room template placed side by side in the top band (default: 0 = none;
    /// 2 or more makes look-alike rooms).
    pub aliased_room_copies: usize,
    /// Width of the aliased rooms (default: 4.5).
    pub aliased_room_width_m: f64,
    /// Copies of one corridor section (a stretch of all bands: rooms on both sides of the
    /// corridors, with their doors and furniture) placed one after another (default: 0 = none).
    pub repeated_section_copies: usize,
    /// Length of the repeated section along x (default: 9.0).
    pub repeated_section_width_m: f64,
}

impl Default for OfficeParams {
    fn default() -> Self {
        Self {
            width_m: 30.0,
            height_m: 20.0,
            corridor_count: 2,
            corridor_width_m: 2.0,
            connector_positions: vec![0.0, 0.55],
            outer_wall_m: 0.3,
            inner_wall_m: 0.15,
            room_width_min_m: 3.0,
            room_width_max_m: 8.0,
            door_width_min_m: 0.9,
            door_width_max_m: 1.0,
            furniture_min: 1,
            furniture_max: 4,
            connecting_door_probability: 0.2,
            aliased_room_copies: 0,
            aliased_room_width_m: 4.5,
            repeated_section_copies: 0,
            repeated_section_width_m: 9.0,
        }
    }
}

/// Where a room band's doors may go.
#[derive(Clone, Copy, Debug, PartialEq)]
enum DoorSide {
    Up,
    Down,
    Either,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum BandKind {
    Rooms(DoorSide),
    Corridor,
}

#[derive(Clone, Copy, Debug)]
struct Band {
    kind: BandKind,
    y0: f64,
    y1: f64,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum SlotKind {
    Room { template: usize, door_up: bool },
    Connector,
}

#[derive(Clone, Copy, Debug)]
struct Slot {
    x0: f64,
    x1: f64,
    kind: SlotKind,
}

/// A room's size, main door and furniture in its own frame: `[0, width] × [0, depth]`, the
/// main door in the top wall (`y = depth`) from `door_offset` to `door_offset + door_width`.
#[derive(Clone, Debug)]
pub(crate) struct Template {
    pub(crate) width_m: f64,
    pub(crate) depth_m: f64,
    pub(crate) door_offset_m: f64,
    pub(crate) door_width_m: f64,
    pub(crate) storage: bool,
    pub(crate) furniture_count: usize,
    uses: usize,
}

/// A block of slots at a fixed place (connectors, the repeated section, the aliased rooms).
struct Block {
    start_x: f64,
    slots: Vec<(f64, SlotKind)>,
}

/// A room placed in the world, with what furnishing it needs.
struct PlacedRoom {
    id: RoomId,
    template: usize,
    world_from_room: Se2,
    /// Door zones in the room's frame.
    keep_out: Vec<Rect>,
}

/// Generates an office floor named `name`.
pub(crate) fn generate_office(
    name: &str,
    params: &OfficeParams,
    seed: u64,
) -> Result<World, SimError> {
    validate(params)?;
    let mut rng = stream_rng(seed, Stream::World, 0);
    let bands = bands(params);
    let mut templates: Vec<Template> = Vec::new();
    let slots = layout_slots(&mut rng, params, &bands, &mut templates)?;
    let (shell, placed) = build_shell(&mut rng, name, params, &bands, &slots, &mut templates);
    furnish_and_check(&shell, &placed, &templates, seed)
}

fn validate(p: &OfficeParams) -> Result<(), SimError> {
    let bad = |field: &'static str, reason: &str| {
        Err(SimError::InvalidParams {
            field,
            reason: reason.to_owned(),
        })
    };
    let positive = [
        ("office.width_m", p.width_m),
        ("office.height_m", p.height_m),
        ("office.corridor_width_m", p.corridor_width_m),
        ("office.outer_wall_m", p.outer_wall_m),
        ("office.inner_wall_m", p.inner_wall_m),
        ("office.room_width_min_m", p.room_width_min_m),
        ("office.door_width_min_m", p.door_width_min_m),
        ("office.aliased_room_width_m", p.aliased_room_width_m),
        (
            "office.repeated_section_width_m",
            p.repeated_section_width_m,
        ),
    ];
    for (field, value) in positive {
        if !(value.is_finite() && value > 0.0) {
            return bad(field, "must be positive and finite");
        }
    }
    if !(1..=2).contains(&p.corridor_count) {
        return bad("office.corridor_count", "must be 1 or 2");
    }
    if !(p.room_width_max_m >= p.room_width_min_m && p.room_width_max_m.is_finite()) {
        return bad(
            "office.room_width_max_m",
            "must be at least room_width_min_m",
        );
    }
    if !(p.door_width_max_m >= p.door_width_min_m && p.door_width_max_m.is_finite()) {
        return bad(
            "office.door_width_max_m",
            "must be at least door_width_min_m",
        );
    }
    if p.door_width_max_m + 2.0 * DOOR_CORNER_MARGIN_M > MIN_STORAGE_WIDTH_M.min(p.room_width_min_m)
    {
        return bad(
            "office.door_width_max_m",
            "doors must fit the narrowest (storage) rooms, 1.6 m wide",
        );
    }
    if p.furniture_max < p.furniture_min {
        return bad("office.furniture_max", "must be at least furniture_min");
    }
    if !(0.0..=1.0).contains(&p.connecting_door_probability) {
        return bad("office.connecting_door_probability", "must lie in [0, 1]");
    }
    if p.connector_positions
        .iter()
        .any(|f| !(0.0..=1.0).contains(f))
    {
        return bad("office.connector_positions", "fractions must lie in [0, 1]");
    }
    if p.inner_width_m() < 2.0 * p.room_width_min_m {
        return bad("office.width_m", "too narrow for two rooms");
    }
    for band in bands(p) {
        if band.kind != BandKind::Corridor && band.y1 - band.y0 < 2.5 {
            return bad(
                "office.height_m",
                "too low: room bands would be shallower than 2.5 m",
            );
        }
    }
    Ok(())
}

impl OfficeParams {
    fn inner_width_m(&self) -> f64 {
        self.width_m - 2.0 * self.outer_wall_m
    }
}

/// The bands from the bottom up, with their interior y ranges.
fn bands(p: &OfficeParams) -> Vec<Band> {
    let (kinds, shares): (Vec<BandKind>, Vec<f64>) = if p.corridor_count >= 2 {
        (
            vec![
                BandKind::Rooms(DoorSide::Up),
                BandKind::Corridor,
                BandKind::Rooms(DoorSide::Either),
                BandKind::Corridor,
                BandKind::Rooms(DoorSide::Down),
            ],
            vec![0.3, 0.0, 0.4, 0.0, 0.3],
        )
    } else {
        (
            vec![
                BandKind::Rooms(DoorSide::Up),
                BandKind::Corridor,
                BandKind::Rooms(DoorSide::Down),
            ],
            vec![0.5, 0.0, 0.5],
        )
    };
    let inner_height = p.height_m - 2.0 * p.outer_wall_m;
    let corridors = kinds.iter().filter(|k| **k == BandKind::Corridor).count() as f64;
    let rooms_total =
        inner_height - corridors * p.corridor_width_m - (kinds.len() - 1) as f64 * p.inner_wall_m;
    let mut y = p.outer_wall_m;
    let mut out = Vec::with_capacity(kinds.len());
    for (i, (kind, share)) in kinds.iter().zip(&shares).enumerate() {
        let depth = match kind {
            BandKind::Corridor => p.corridor_width_m,
            BandKind::Rooms(_) => share * rooms_total,
        };
        let y1 = if i + 1 == kinds.len() {
            p.height_m - p.outer_wall_m
        } else {
            y + depth
        };
        out.push(Band {
            kind: *kind,
            y0: y,
            y1,
        });
        y = y1 + p.inner_wall_m;
    }
    out
}

/// Slots of every band (empty for corridor bands).
fn layout_slots(
    rng: &mut SimRng,
    p: &OfficeParams,
    bands: &[Band],
    templates: &mut Vec<Template>,
) -> Result<Vec<Vec<Slot>>, SimError> {
    let (x_lo, x_hi) = (p.outer_wall_m, p.width_m - p.outer_wall_m);
    let ti = p.inner_wall_m;
    let cw = p.corridor_width_m;
    let room_bands: Vec<usize> = (0..bands.len())
        .filter(|&i| bands[i].kind != BandKind::Corridor)
        .collect();
    let middle = (p.corridor_count >= 2).then_some(2usize);
    let connectors: Vec<f64> = match middle {
        Some(_) => {
            let mut xs: Vec<f64> = p
                .connector_positions
                .iter()
                .map(|f| x_lo + f * (p.inner_width_m() - cw))
                .collect();
            xs.sort_by(f64::total_cmp);
            xs.dedup_by(|a, b| (*a - *b).abs() < cw + ti);
            xs
        }
        None => Vec::new(),
    };
    let section_start = match connectors.first() {
        Some(&x) if x - x_lo < 1e-9 => x_lo + cw + ti,
        _ => x_lo,
    };
    let mut blocks: Vec<Vec<Block>> = bands.iter().map(|_| Vec::new()).collect();
    if let Some(m) = middle {
        for &x in &connectors {
            blocks[m].push(Block {
                start_x: x,
                slots: vec![(cw, SlotKind::Connector)],
            });
        }
    }
    // The repeated corridor section: one random stretch per room band, copied.
    let mut section_end = section_start - ti;
    if p.repeated_section_copies >= 1 {
        for &b in &room_bands {
            let depth = bands[b].y1 - bands[b].y0;
            let widths = random_widths(rng, p, p.repeated_section_width_m);
            let module: Vec<(f64, SlotKind)> = widths
                .iter()
                .map(|&w| {
                    let door_up = door_up_for(rng, bands[b].kind);
                    let template = new_template(rng, p, templates, w, depth);
                    (w, SlotKind::Room { template, door_up })
                })
                .collect();
            let mut slots = Vec::new();
            for _ in 0..p.repeated_section_copies {
                for &(w, kind) in &module {
                    if let SlotKind::Room { template, .. } = kind {
                        templates[template].uses += 1;
                    }
                    slots.push((w, kind));
                }
            }
            let length: f64 = slots.iter().map(|(w, _)| w + ti).sum::<f64>() - ti;
            section_end = section_start + length;
            blocks[b].push(Block {
                start_x: section_start,
                slots,
            });
        }
    }
    // Look-alike rooms: copies of one template side by side in the top band.
    if p.aliased_room_copies >= 1 {
        if let Some(&top) = room_bands.last() {
            let depth = bands[top].y1 - bands[top].y0;
            let width = p.aliased_room_width_m;
            let template = new_template(rng, p, templates, width, depth);
            templates[template].uses = p.aliased_room_copies;
            let door_up = door_up_for(rng, bands[top].kind);
            let start_x = if p.repeated_section_copies >= 1 {
                section_end + ti
            } else {
                section_start
            };
            blocks[top].push(Block {
                start_x,
                slots: vec![(width, SlotKind::Room { template, door_up }); p.aliased_room_copies],
            });
        }
    }
    let mut out = Vec::with_capacity(bands.len());
    for (b, band) in bands.iter().enumerate() {
        if band.kind == BandKind::Corridor {
            out.push(Vec::new());
            continue;
        }
        let mut band_blocks = std::mem::take(&mut blocks[b]);
        band_blocks.sort_by(|a, c| a.start_x.total_cmp(&c.start_x));
        let depth = band.y1 - band.y0;
        let mut slots = Vec::new();
        let mut cursor = x_lo;
        let fill = |rng: &mut SimRng,
                    templates: &mut Vec<Template>,
                    from: f64,
                    to: f64,
                    slots: &mut Vec<Slot>| {
            let mut x = from;
            for w in random_widths(rng, p, to - from) {
                let door_up = door_up_for(rng, band.kind);
                let template = new_template(rng, p, templates, w, depth);
                templates[template].uses = 1;
                slots.push(Slot {
                    x0: x,
                    x1: x + w,
                    kind: SlotKind::Room { template, door_up },
                });
                x += w + ti;
            }
        };
        for block in &band_blocks {
            if block.start_x < cursor - 1e-9 {
                return Err(SimError::InvalidParams {
                    field: "office.connector_positions",
                    reason: "connectors, the repeated section and the aliased rooms overlap"
                        .to_owned(),
                });
            }
            if block.start_x - cursor > 1e-9 {
                fill(rng, templates, cursor, block.start_x - ti, &mut slots);
            }
            let mut x = block.start_x;
            for &(w, kind) in &block.slots {
                slots.push(Slot {
                    x0: x,
                    x1: x + w,
                    kind,
                });
                x += w + ti;
            }
            cursor = x;
        }
        if cursor > x_hi + ti + 1e-9 {
            return Err(SimError::InvalidParams {
                field: "office.width_m",
                reason: "the repeated section and the aliased rooms do not fit".to_owned(),
            });
        }
        if x_hi - cursor > 1e-9 {
            fill(rng, templates, cursor, x_hi, &mut slots);
        }
        out.push(slots);
    }
    Ok(out)
}

fn door_up_for(rng: &mut SimRng, kind: BandKind) -> bool {
    match kind {
        BandKind::Rooms(DoorSide::Up) => true,
        BandKind::Rooms(DoorSide::Down) | BandKind::Corridor => false,
        BandKind::Rooms(DoorSide::Either) => rng.random::<bool>(),
    }
}

/// Widths of rooms filling `length_m` with inner walls between them (empty when the gap is
/// too narrow even for a storage room).
pub(crate) fn random_widths(rng: &mut SimRng, p: &OfficeParams, length_m: f64) -> Vec<f64> {
    let ti = p.inner_wall_m;
    let (w_min, w_max) = (p.room_width_min_m, p.room_width_max_m);
    if length_m < MIN_STORAGE_WIDTH_M {
        return Vec::new();
    }
    if length_m < w_min {
        return vec![length_m];
    }
    let n_min = ((length_m + ti) / (w_max + ti)).ceil().max(1.0) as usize;
    let n_max = (((length_m + ti) / (w_min + ti)).floor() as usize).max(n_min);
    let n = rng.random_range(n_min..=n_max);
    let usable = length_m - (n - 1) as f64 * ti;
    for _ in 0..50 {
        let weights: Vec<f64> = (0..n).map(|_| uniform(rng, 0.6, 1.4)).collect();
        let total: f64 = weights.iter().sum();
        let widths: Vec<f64> = weights.iter().map(|w| usable * w / total).collect();
        if widths
            .iter()
            .all(|w| *w >= w_min - 1e-9 && *w <= w_max + 1e-9)
        {
            return widths;
        }
    }
    vec![usable / n as f64; n]
}

/// A new template of the given size with a random door; returns its index.
pub(crate) fn new_template(
    rng: &mut SimRng,
    p: &OfficeParams,
    templates: &mut Vec<Template>,
    width_m: f64,
    depth_m: f64,
) -> usize {
    let door_width_m = uniform(rng, p.door_width_min_m, p.door_width_max_m);
    let free = (width_m - door_width_m - DOOR_CORNER_MARGIN_M).max(DOOR_CORNER_MARGIN_M);
    // Most office doors sit next to a corner.
    let door_offset_m = if rng.random::<f64>() < 0.6 {
        let near = uniform(
            rng,
            DOOR_CORNER_MARGIN_M,
            (DOOR_CORNER_MARGIN_M + 0.4).min(free),
        );
        if rng.random::<bool>() {
            near
        } else {
            (width_m - door_width_m - near).max(DOOR_CORNER_MARGIN_M)
        }
    } else {
        uniform(rng, DOOR_CORNER_MARGIN_M, free)
    };
    let storage = width_m < p.room_width_min_m;
    let furniture_count = if storage {
        rng.random_range(0..=1)
    } else {
        rng.random_range(p.furniture_min..=p.furniture_max)
    };
    templates.push(Template {
        width_m,
        depth_m,
        door_offset_m,
        door_width_m,
        storage,
        furniture_count,
        uses: 0,
    });
    templates.len() - 1
}

/// Walls, rooms and doors (no furniture yet), and the rooms to furnish.
fn build_shell(
    rng: &mut SimRng,
    name: &str,
    p: &OfficeParams,
    bands: &[Band],
    slots: &[Vec<Slot>],
    templates: &mut [Template],
) -> (World, Vec<PlacedRoom>) {
    let (w, h, to, ti) = (p.width_m, p.height_m, p.outer_wall_m, p.inner_wall_m);
    let (x_lo, x_hi) = (to, w - to);
    let mut world = World::new(name);
    world.footprint.push(Rect::new(0.0, 0.0, w, h));
    // Alias groups: templates used more than once, numbered by first use.
    let mut groups: Vec<Option<u32>> = vec![None; templates.len()];
    let mut next_group = 0u32;
    // Rooms, bottom band first, left to right; corridors where their band comes.
    let mut band_room: Vec<Option<RoomId>> = vec![None; bands.len()];
    let mut slot_rooms: Vec<Vec<RoomId>> = vec![Vec::new(); bands.len()];
    let mut placed = Vec::new();
    let (mut corridor_number, mut connector_number, mut room_number) = (0, 0, 0);
    for (b, band) in bands.iter().enumerate() {
        if band.kind == BandKind::Corridor {
            corridor_number += 1;
            let id = world.add_room(
                format!("corridor-{corridor_number}"),
                RoomKind::Corridor,
                Rect::new(x_lo, band.y0, x_hi, band.y1),
            );
            band_room[b] = Some(id);
            continue;
        }
        for slot in &slots[b] {
            let rect = Rect::new(slot.x0, band.y0, slot.x1, band.y1);
            let id = match slot.kind {
                SlotKind::Connector => {
                    connector_number += 1;
                    world.add_room(
                        format!("connector-{connector_number}"),
                        RoomKind::Corridor,
                        rect,
                    )
                }
                SlotKind::Room { template, door_up } => {
                    room_number += 1;
                    let t = &templates[template];
                    let kind = if t.storage {
                        RoomKind::Storage
                    } else {
                        RoomKind::Office
                    };
                    let id = world.add_room(format!("room-{room_number:02}"), kind, rect);
                    let world_from_room = if door_up {
                        Se2::new(slot.x0, band.y0, 0.0)
                    } else {
                        Se2::new(slot.x1, band.y1, PI)
                    };
                    if t.uses >= 2 && groups[template].is_none() {
                        groups[template] = Some(next_group);
                        next_group += 1;
                    }
                    if let Some(room) = world.rooms.iter_mut().find(|r| r.id == id) {
                        room.world_from_room = world_from_room;
                        room.alias_group = groups[template];
                    }
                    let keep_out = vec![door_zone(
                        2,
                        t.door_offset_m,
                        t.door_offset_m + t.door_width_m,
                        t.width_m,
                        t.depth_m,
                    )];
                    placed.push(PlacedRoom {
                        id,
                        template,
                        world_from_room,
                        keep_out,
                    });
                    id
                }
            };
            slot_rooms[b].push(id);
        }
    }
    // Openings in the horizontal walls, per band boundary: (x0, x1).
    let mut horizontal_openings: Vec<Vec<(f64, f64)>> = vec![Vec::new(); bands.len()];
    for (b, band) in bands.iter().enumerate() {
        for (slot, &room) in slots[b].iter().zip(&slot_rooms[b]) {
            match slot.kind {
                SlotKind::Connector => {
                    if b > 0 {
                        horizontal_openings[b - 1].push((slot.x0, slot.x1));
                    }
                    if b + 1 < bands.len() {
                        horizontal_openings[b].push((slot.x0, slot.x1));
                    }
                }
                SlotKind::Room { template, door_up } => {
                    let t = &templates[template];
                    let (boundary, neighbour) = if door_up {
                        (b, b + 1)
                    } else {
                        (b.wrapping_sub(1), b.wrapping_sub(1))
                    };
                    let Some(corridor) = band_room.get(neighbour).copied().flatten() else {
                        continue;
                    };
                    let (x0, x1, y, yaw) = if door_up {
                        let x0 = slot.x0 + t.door_offset_m;
                        (x0, x0 + t.door_width_m, band.y1 + 0.5 * ti, FRAC_PI_2)
                    } else {
                        let x1 = slot.x1 - t.door_offset_m;
                        (x1 - t.door_width_m, x1, band.y0 - 0.5 * ti, -FRAC_PI_2)
                    };
                    world.add_door(
                        DoorKind::Entrance,
                        Point2::new(0.5 * (x0 + x1), y),
                        t.door_width_m,
                        ti,
                        yaw,
                        [room, corridor],
                    );
                    horizontal_openings[boundary].push((x0, x1));
                }
            }
        }
    }
    // Outer walls.
    for rect in [
        Rect::new(0.0, 0.0, w, to),
        Rect::new(0.0, h - to, w, h),
        Rect::new(0.0, to, to, h - to),
        Rect::new(w - to, to, w, h - to),
    ] {
        world.add_obstacle(ObstacleKind::Wall, Shape::Rect(rect), None);
    }
    // Walls between bands, with their openings.
    for b in 0..bands.len().saturating_sub(1) {
        let (y0, y1) = (bands[b].y1, bands[b + 1].y0);
        for (x0, x1) in complement(x_lo, x_hi, &mut horizontal_openings[b]) {
            world.add_obstacle(
                ObstacleKind::Wall,
                Shape::Rect(Rect::new(x0, y0, x1, y1)),
                None,
            );
        }
    }
    // Walls between the slots of each room band, some with connecting doors.
    for (b, band) in bands.iter().enumerate() {
        if band.kind == BandKind::Corridor {
            continue;
        }
        let band_slots = &slots[b];
        let mut edges: Vec<f64> = vec![x_lo];
        for slot in band_slots {
            edges.push(slot.x0);
            edges.push(slot.x1);
        }
        edges.push(x_hi);
        for (i, pair) in edges.chunks(2).enumerate() {
            let (x0, x1) = (pair[0], pair[1]);
            if x1 - x0 < 1e-9 {
                continue;
            }
            let mut openings = Vec::new();
            // A connecting door when both neighbours are unique offices and the wall is thin.
            let neighbours = (
                i.checked_sub(1).and_then(|k| band_slots.get(k)),
                band_slots.get(i),
            );
            if let (Some(left), Some(right)) = neighbours {
                if let (SlotKind::Room { template: tl, .. }, SlotKind::Room { template: tr, .. }) =
                    (left.kind, right.kind)
                {
                    let unique = |t: &Template| t.uses <= 1 && !t.storage;
                    if unique(&templates[tl])
                        && unique(&templates[tr])
                        && x1 - x0 < ti + 1e-6
                        && rng.random::<f64>() < p.connecting_door_probability
                    {
                        let dw = uniform(rng, p.door_width_min_m, p.door_width_max_m);
                        let lo = band.y0 + DOOR_CORNER_MARGIN_M + 0.5 * dw;
                        let hi = band.y1 - DOOR_CORNER_MARGIN_M - 0.5 * dw;
                        let yc = uniform(rng, lo, hi);
                        let (left_id, right_id) = (slot_rooms[b][i - 1], slot_rooms[b][i]);
                        world.add_door(
                            DoorKind::Connecting,
                            Point2::new(0.5 * (x0 + x1), yc),
                            dw,
                            x1 - x0,
                            0.0,
                            [left_id, right_id],
                        );
                        openings.push((yc - 0.5 * dw, yc + 0.5 * dw));
                        let (zone_lo, zone_hi) = (
                            yc - 0.5 * dw - DOOR_ZONE_SIDE_M,
                            yc + 0.5 * dw + DOOR_ZONE_SIDE_M,
                        );
                        // The zone lies left of the wall in the left room, right of it in the right one.
                        for (room_id, wall_x, into) in [(left_id, x0, -1.0), (right_id, x1, 1.0)] {
                            let zone_world = Rect::new(
                                wall_x,
                                zone_lo,
                                wall_x + into * DOOR_ZONE_DEPTH_M,
                                zone_hi,
                            );
                            if let Some(room) = placed.iter_mut().find(|r| r.id == room_id) {
                                let zone = Shape::Rect(zone_world)
                                    .transformed(&room.world_from_room.inverse());
                                room.keep_out.push(zone.bounds());
                            }
                        }
                    }
                }
            }
            for (y0, y1) in complement(band.y0, band.y1, &mut openings) {
                world.add_obstacle(
                    ObstacleKind::Wall,
                    Shape::Rect(Rect::new(x0, y0, x1, y1)),
                    None,
                );
            }
        }
    }
    (world, placed)
}

/// The parts of `[lo, hi]` not covered by `openings` (which get sorted).
fn complement(lo: f64, hi: f64, openings: &mut [(f64, f64)]) -> Vec<(f64, f64)> {
    openings.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut out = Vec::new();
    let mut cursor = lo;
    for &(a, b) in openings.iter() {
        if a - cursor > 1e-9 {
            out.push((cursor, a.min(hi)));
        }
        cursor = cursor.max(b);
    }
    if hi - cursor > 1e-9 {
        out.push((cursor, hi));
    }
    out
}

/// Furnishes every room from its template; a template whose rooms the robot cannot reach is
/// furnished again with fewer pieces (and finally left empty).
fn furnish_and_check(
    shell: &World,
    placed: &[PlacedRoom],
    templates: &[Template],
    seed: u64,
) -> Result<World, SimError> {
    let mut counts: Vec<usize> = templates.iter().map(|t| t.furniture_count).collect();
    let mut attempt = vec![0u64; templates.len()];
    for round in 0..=FURNISH_ATTEMPTS {
        let mut world = shell.clone();
        let mut furniture: Vec<Option<Vec<Shape>>> = vec![None; templates.len()];
        for room in placed {
            let t = &templates[room.template];
            let shapes = furniture[room.template].get_or_insert_with(|| {
                // Every room of a template has the same door zones in its own frame.
                let zones: Vec<Rect> = placed
                    .iter()
                    .filter(|r| r.template == room.template)
                    .flat_map(|r| r.keep_out.iter().copied())
                    .collect();
                let mut rng = stream_rng(
                    seed,
                    Stream::Furniture,
                    room.template as u64 * 16 + attempt[room.template],
                );
                furnish(
                    &mut rng,
                    t.width_m,
                    t.depth_m,
                    &zones,
                    &[],
                    counts[room.template],
                )
            });
            for shape in shapes.iter() {
                world.add_obstacle(
                    ObstacleKind::Furniture,
                    shape.transformed(&room.world_from_room),
                    Some(room.id),
                );
            }
        }
        let blocked = unreachable_destinations(&world);
        if blocked.is_empty() || round == FURNISH_ATTEMPTS {
            return Ok(world);
        }
        for room in placed.iter().filter(|r| blocked.contains(&r.id)) {
            let t = room.template;
            counts[t] = if round + 1 == FURNISH_ATTEMPTS {
                0
            } else {
                counts[t].saturating_sub(1)
            };
            attempt[t] += 1;
        }
    }
    Ok(shell.clone())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn complement_of_openings() {
        let mut openings = vec![(5.0, 6.0), (1.0, 2.0), (1.5, 2.5)];
        let parts = complement(0.0, 10.0, &mut openings);
        assert_eq!(parts, vec![(0.0, 1.0), (2.5, 5.0), (6.0, 10.0)]);
        assert!(complement(0.0, 1.0, &mut [(0.0, 1.0)]).is_empty());
    }

    #[test]
    fn bands_fill_the_building() {
        let p = OfficeParams::default();
        let b = bands(&p);
        assert_eq!(b.len(), 5);
        assert!((b[0].y0 - p.outer_wall_m).abs() < 1e-12);
        assert!((b[4].y1 - (p.height_m - p.outer_wall_m)).abs() < 1e-12);
        for pair in b.windows(2) {
            assert!((pair[1].y0 - pair[0].y1 - p.inner_wall_m).abs() < 1e-9);
        }
        assert!((b[1].y1 - b[1].y0 - p.corridor_width_m).abs() < 1e-9);
    }

    #[test]
    fn widths_stay_in_range() {
        let p = OfficeParams::default();
        let mut rng = crate::rng::seeded(5);
        for i in 0..200 {
            let length = 3.0 + i as f64 * 0.2;
            let widths = random_widths(&mut rng, &p, length);
            let total: f64 =
                widths.iter().sum::<f64>() + (widths.len() - 1) as f64 * p.inner_wall_m;
            assert!((total - length).abs() < 1e-9);
            assert!(
                widths.iter().all(|w| (3.0 - 1e-9..=8.0 + 1e-9).contains(w)),
                "{widths:?}"
            );
        }
        assert!(random_widths(&mut rng, &p, 1.0).is_empty());
        assert_eq!(random_widths(&mut rng, &p, 2.0), vec![2.0]);
    }
}
