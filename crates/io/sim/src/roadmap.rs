//! Where the robot can go: a probabilistic-roadmap-style graph (Kavraki et al. 1996) whose
//! nodes are a regular lattice of free points plus every doorway's centre and approach
//! points, and whose edges are short straight moves that keep the robot's clearance from
//! every obstacle. Routes are shortest paths (Dijkstra) on it, then straightened by dropping
//! every waypoint the robot can skip while keeping its clearance ("string pulling").
//!
//! Closed doors are obstacles like any other, so a session's roadmap never passes them.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use crate::world::{RoomId, World};
use crate::{Point2, RayCaster, Rect};

/// Clearance the generators check their worlds with (m): [`crate::RobotParams`]' default.
pub(crate) const DEFAULT_CLEARANCE_M: f64 = 0.3;
/// Spacing of the lattice of free points (m).
const LATTICE_M: f64 = 0.5;
/// Longest roadmap edge (m): a lattice point links to its neighbours up to two cells away.
const LINK_RADIUS_M: f64 = 1.2;
/// How far a door's approach points lie from the door's centre, beyond half the wall (m).
const DOOR_APPROACH_M: f64 = 0.45;
/// Clearance required to hop from an arbitrary pose onto the roadmap (m): the robot may have
/// stopped closer to an obstacle than the roadmap's clearance.
const ENTRY_CLEARANCE_M: f64 = 0.05;
/// How far to look for a node to hop onto (m).
const ENTRY_SEARCH_M: f64 = 3.0;

/// The free-space graph of one world for a robot needing `clearance_m` from obstacles.
#[derive(Clone, Debug)]
pub struct Roadmap {
    caster: RayCaster,
    clearance_m: f64,
    nodes: Vec<Point2>,
    adjacency: Vec<Vec<(u32, f64)>>,
    component: Vec<u32>,
    main_component: u32,
    buckets: Buckets,
}

/// Nodes sorted into square cells of `LINK_RADIUS_M` for neighbour searches.
#[derive(Clone, Debug)]
struct Buckets {
    origin_m: Point2,
    columns: usize,
    rows: usize,
    cells: Vec<Vec<u32>>,
}

impl Buckets {
    fn new(bounds: &Rect, nodes: &[Point2]) -> Self {
        let origin_m = bounds.min_m;
        let columns = ((bounds.width_m() / LINK_RADIUS_M).ceil() as usize).max(1);
        let rows = ((bounds.height_m() / LINK_RADIUS_M).ceil() as usize).max(1);
        let mut buckets = Self {
            origin_m,
            columns,
            rows,
            cells: vec![Vec::new(); columns * rows],
        };
        for (index, p) in nodes.iter().enumerate() {
            let (c, r) = buckets.cell_of(p);
            buckets.cells[r * columns + c].push(index as u32);
        }
        buckets
    }

    fn cell_of(&self, p: &Point2) -> (usize, usize) {
        let c = ((p.x - self.origin_m.x) / LINK_RADIUS_M)
            .floor()
            .clamp(0.0, (self.columns - 1) as f64);
        let r = ((p.y - self.origin_m.y) / LINK_RADIUS_M)
            .floor()
            .clamp(0.0, (self.rows - 1) as f64);
        (c as usize, r as usize)
    }

    /// Nodes in cells within `reach` cells of `p`'s cell, cell by cell.
    fn near(&self, p: &Point2, reach: usize) -> impl Iterator<Item = u32> + '_ {
        let (c, r) = self.cell_of(p);
        let (c0, c1) = (c.saturating_sub(reach), (c + reach).min(self.columns - 1));
        let (r0, r1) = (r.saturating_sub(reach), (r + reach).min(self.rows - 1));
        (r0..=r1).flat_map(move |row| {
            (c0..=c1).flat_map(move |col| self.cells[row * self.columns + col].iter().copied())
        })
    }
}

impl Roadmap {
    /// The roadmap of `world` for a robot that keeps `clearance_m` from every obstacle.
    pub fn build(world: &World, clearance_m: f64) -> Self {
        let caster = RayCaster::new(world);
        let clearance_m = if clearance_m.is_finite() {
            clearance_m.max(0.0)
        } else {
            DEFAULT_CLEARANCE_M
        };
        let bounds = world.bounds();
        let free = |p: &Point2| {
            world.is_inside_building(p)
                && caster.clearance_m(p, clearance_m) >= clearance_m
                && !world.is_inside_obstacle(p)
        };
        let mut nodes = Vec::new();
        // Doors first (centre, then both approach points), then room centres, then the lattice.
        for door in &world.doors {
            let reach = 0.5 * door.wall_thickness_m + DOOR_APPROACH_M;
            for p in [
                door.center_m,
                door.approach_point(0, reach),
                door.approach_point(1, reach),
            ] {
                if free(&p) {
                    nodes.push(p);
                }
            }
        }
        for room in &world.rooms {
            let p = room.rect.center_m();
            if free(&p) {
                nodes.push(p);
            }
        }
        let columns = (bounds.width_m() / LATTICE_M).floor() as usize;
        let rows = (bounds.height_m() / LATTICE_M).floor() as usize;
        for row in 0..rows {
            for column in 0..columns {
                let p = bounds.min_m
                    + Point2::new(
                        (column as f64 + 0.5) * LATTICE_M,
                        (row as f64 + 0.5) * LATTICE_M,
                    );
                if free(&p) {
                    nodes.push(p);
                }
            }
        }
        let buckets = Buckets::new(&bounds, &nodes);
        let mut adjacency: Vec<Vec<(u32, f64)>> = vec![Vec::new(); nodes.len()];
        for i in 0..nodes.len() {
            let mut neighbours: Vec<u32> = buckets
                .near(&nodes[i], 1)
                .filter(|&j| j as usize > i)
                .collect();
            neighbours.sort_unstable();
            for j in neighbours {
                let length = (nodes[j as usize] - nodes[i]).norm();
                if length <= LINK_RADIUS_M
                    && caster.is_clear(&nodes[i], &nodes[j as usize], clearance_m)
                {
                    adjacency[i].push((j, length));
                    adjacency[j as usize].push((i as u32, length));
                }
            }
        }
        let (component, main_component) = components(&adjacency);
        Self {
            caster,
            clearance_m,
            nodes,
            adjacency,
            component,
            main_component,
            buckets,
        }
    }

    /// The ray caster of the world the roadmap was built for.
    pub fn caster(&self) -> &RayCaster {
        &self.caster
    }

    /// The clearance every edge keeps (m).
    pub fn clearance_m(&self) -> f64 {
        self.clearance_m
    }

    /// Node positions.
    pub fn nodes(&self) -> &[Point2] {
        &self.nodes
    }

    /// Number of edges.
    pub fn edge_count(&self) -> usize {
        self.adjacency.iter().map(Vec::len).sum::<usize>() / 2
    }

    /// Nodes of the largest connected part of the free space (where sessions start).
    pub fn main_nodes(&self) -> Vec<usize> {
        (0..self.nodes.len())
            .filter(|&i| self.component[i] == self.main_component)
            .collect()
    }

    /// Nodes of the largest connected part that lie inside `rect`.
    pub fn main_nodes_in(&self, rect: &Rect) -> Vec<usize> {
        (0..self.nodes.len())
            .filter(|&i| self.component[i] == self.main_component && rect.contains(&self.nodes[i]))
            .collect()
    }

    /// True when node `index` belongs to the largest connected part.
    pub fn is_main(&self, index: usize) -> bool {
        self.component.get(index) == Some(&self.main_component)
    }

    /// A route from `from_m` to `to_m` as waypoints (starting with `from_m`, ending with
    /// `to_m`), or `None` when they are not connected. Every leg keeps the roadmap's clearance,
    /// except the hops from `from_m` and onto `to_m`, which keep at least 5 cm.
    pub fn plan(&self, from_m: &Point2, to_m: &Point2) -> Option<Vec<Point2>> {
        let start = self.entry_node(from_m)?;
        let goal = self.entry_node(to_m)?;
        let nodes = self.shortest_path(start, goal)?;
        let mut path = Vec::with_capacity(nodes.len() + 2);
        path.push(*from_m);
        path.extend(nodes.iter().map(|&n| self.nodes[n]));
        path.push(*to_m);
        path.dedup_by(|a, b| (*a - *b).norm() < 1e-9);
        Some(self.straighten(&path))
    }

    /// The nearest node reachable from `p_m` in a straight line, if any lies within 3 m.
    pub fn entry_node(&self, p_m: &Point2) -> Option<usize> {
        let reach = (ENTRY_SEARCH_M / LINK_RADIUS_M).ceil() as usize;
        let mut candidates: Vec<(f64, u32)> = self
            .buckets
            .near(p_m, reach)
            .map(|j| ((self.nodes[j as usize] - p_m).norm(), j))
            .filter(|(d, _)| *d <= ENTRY_SEARCH_M)
            .collect();
        candidates.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let entry_clearance = ENTRY_CLEARANCE_M.min(self.clearance_m);
        candidates
            .into_iter()
            .find(|&(_, j)| {
                self.caster
                    .is_clear(p_m, &self.nodes[j as usize], entry_clearance)
            })
            .map(|(_, j)| j as usize)
    }

    /// Dijkstra's shortest path between two nodes (ties broken by node index).
    fn shortest_path(&self, start: usize, goal: usize) -> Option<Vec<usize>> {
        if self.component[start] != self.component[goal] {
            return None;
        }
        let mut cost = vec![f64::INFINITY; self.nodes.len()];
        let mut previous = vec![u32::MAX; self.nodes.len()];
        let mut heap = BinaryHeap::new();
        cost[start] = 0.0;
        heap.push(Visit {
            cost: 0.0,
            node: start as u32,
        });
        while let Some(Visit { cost: c, node }) = heap.pop() {
            let node = node as usize;
            if node == goal {
                break;
            }
            if c > cost[node] {
                continue;
            }
            for &(next, length) in &self.adjacency[node] {
                let candidate = c + length;
                if candidate < cost[next as usize] {
                    cost[next as usize] = candidate;
                    previous[next as usize] = node as u32;
                    heap.push(Visit {
                        cost: candidate,
                        node: next,
                    });
                }
            }
        }
        if !cost[goal].is_finite() {
            return None;
        }
        let mut path = vec![goal];
        let mut node = goal;
        while node != start {
            node = previous[node] as usize;
            path.push(node);
        }
        path.reverse();
        Some(path)
    }

    /// Drops every waypoint that can be skipped keeping the clearance.
    fn straighten(&self, path: &[Point2]) -> Vec<Point2> {
        let Some(&first) = path.first() else {
            return Vec::new();
        };
        let mut out = vec![first];
        let mut i = 0;
        while i + 1 < path.len() {
            let mut j = path.len() - 1;
            while j > i + 1 && !self.caster.is_clear(&path[i], &path[j], self.clearance_m) {
                j -= 1;
            }
            out.push(path[j]);
            i = j;
        }
        out
    }
}

/// A Dijkstra queue entry, ordered so that `BinaryHeap` pops the cheapest (then lowest node).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Visit {
    cost: f64,
    node: u32,
}

impl Eq for Visit {}

impl Ord for Visit {
    fn cmp(&self, other: &Self) -> Ordering {
        other
            .cost
            .total_cmp(&self.cost)
            .then_with(|| other.node.cmp(&self.node))
    }
}

impl PartialOrd for Visit {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// Connected components (labels in order of first node) and the largest one (the first of
/// equal size).
fn components(adjacency: &[Vec<(u32, f64)>]) -> (Vec<u32>, u32) {
    let mut label = vec![u32::MAX; adjacency.len()];
    let mut sizes: Vec<usize> = Vec::new();
    let mut stack = Vec::new();
    for seed in 0..adjacency.len() {
        if label[seed] != u32::MAX {
            continue;
        }
        let current = sizes.len() as u32;
        let mut size = 0;
        label[seed] = current;
        stack.push(seed);
        while let Some(node) = stack.pop() {
            size += 1;
            for &(next, _) in &adjacency[node] {
                if label[next as usize] == u32::MAX {
                    label[next as usize] = current;
                    stack.push(next as usize);
                }
            }
        }
        sizes.push(size);
    }
    let mut main = 0u32;
    for (index, &size) in sizes.iter().enumerate() {
        if size > sizes[main as usize] {
            main = index as u32;
        }
    }
    (label, main)
}

/// Destination rooms of `world` that a robot with the default clearance cannot reach from the
/// largest free area.
pub(crate) fn unreachable_destinations(world: &World) -> Vec<RoomId> {
    let roadmap = Roadmap::build(world, DEFAULT_CLEARANCE_M);
    world
        .rooms
        .iter()
        .filter(|room| room.kind.is_destination() && roadmap.main_nodes_in(&room.rect).is_empty())
        .map(|room| room.id)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::{DoorKind, ObstacleKind, RoomKind};
    use crate::Shape;

    /// Two 4 × 4 rooms side by side, a 0.2 m wall between them with a 1 m door.
    fn two_rooms() -> (World, crate::DoorId) {
        let mut world = World::new("two-rooms");
        world.footprint.push(Rect::new(-0.2, -0.2, 8.4, 4.2));
        let walls = [
            Rect::new(-0.2, -0.2, 8.4, 0.0),
            Rect::new(-0.2, 4.0, 8.4, 4.2),
            Rect::new(-0.2, 0.0, 0.0, 4.0),
            Rect::new(8.2, 0.0, 8.4, 4.0),
            Rect::new(4.0, 0.0, 4.2, 1.5),
            Rect::new(4.0, 2.5, 4.2, 4.0),
        ];
        for wall in walls {
            world.add_obstacle(ObstacleKind::Wall, Shape::Rect(wall), None);
        }
        let a = world.add_room("a", RoomKind::Office, Rect::new(0.0, 0.0, 4.0, 4.0));
        let b = world.add_room("b", RoomKind::Office, Rect::new(4.2, 0.0, 8.2, 4.0));
        let door = world.add_door(
            DoorKind::Connecting,
            Point2::new(4.1, 2.0),
            1.0,
            0.2,
            0.0,
            [a, b],
        );
        (world, door)
    }

    #[test]
    fn plans_through_an_open_door_and_not_through_a_closed_one() {
        let (mut world, door) = two_rooms();
        let roadmap = Roadmap::build(&world, 0.3);
        let (from, to) = (Point2::new(1.0, 1.0), Point2::new(7.0, 3.0));
        let path = roadmap.plan(&from, &to).unwrap();
        assert_eq!(path.first(), Some(&from));
        assert_eq!(path.last(), Some(&to));
        for leg in path.windows(2) {
            assert!(roadmap.caster().is_clear(&leg[0], &leg[1], 0.05));
        }
        assert!(unreachable_destinations(&world).is_empty());
        world.close_door(door).unwrap();
        let closed = Roadmap::build(&world, 0.3);
        assert!(closed.plan(&from, &to).is_none());
        assert_eq!(unreachable_destinations(&world).len(), 1);
    }
}
