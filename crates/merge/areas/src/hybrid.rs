//! The hybrid map H = ⟨M, L, E⟩ (Ehlers et al., Sec. II-A): maps M (one per area, each in its
//! own frame), link points L (a pose known in two adjacent maps, placed at a door) and edges E
//! between the link points of one map (all of them: "all link-points on the same map are fully
//! connected"). Dijkstra over E gives routes between poses in any two maps (Sec. II-C), and the
//! chain of transforms along them. Link-point candidates are doors seen in one map and not
//! passed yet: known in one map only, they join no route until a passing makes them link
//! points.

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::Point2;
use petgraph::graph::{NodeIndex, UnGraph};
use serde::{Deserialize, Serialize};

use crate::environment::Environment;
use crate::error::AreasError;

/// One map of the hybrid map: a room, corridor or hall.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Area {
    /// Its id (its index).
    pub id: usize,
    /// The SLAM configuration it was built with.
    pub environment: Environment,
    /// Where its frame lies in the first area's frame (through the link-point chain).
    pub first_from_area: Se2,
}

/// A link point: one pose, known in two adjacent maps.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LinkPoint {
    /// Its id (its index).
    pub id: usize,
    /// The two maps (ids).
    pub areas: [usize; 2],
    /// The pose in each map's frame (`areas[i]`'s frame for `poses[i]`).
    pub poses: [Se2; 2],
}

impl LinkPoint {
    /// Its pose in `area`'s frame, if it belongs to `area`.
    pub fn pose_in(&self, area: usize) -> Option<Se2> {
        self.areas
            .iter()
            .position(|a| *a == area)
            .and_then(|i| self.poses.get(i).copied())
    }

    /// The transform `a_from_b` from map `b`'s frame to map `a`'s that it implies (both poses
    /// are one pose in the world), if it belongs to both.
    pub fn a_from_b(&self, a: usize, b: usize) -> Option<Se2> {
        Some(self.pose_in(a)?.compose(&self.pose_in(b)?.inverse()))
    }
}

/// A link-point candidate: a door seen in one map but not passed (yet).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LinkCandidate {
    /// Its id (its index).
    pub id: usize,
    /// The map it was seen in.
    pub area: usize,
    /// The doorway in that map's frame: its centre, heading along the door's normal away
    /// from where it was seen (into the unknown side).
    pub pose: Se2,
}

/// An edge between two link points of one map.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LinkEdge {
    /// Link point ids.
    pub from: usize,
    /// …
    pub to: usize,
    /// The map they share.
    pub area: usize,
    /// Their distance in that map (m).
    pub length_m: f64,
}

/// The hybrid map.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct HybridMap {
    /// M.
    pub areas: Vec<Area>,
    /// L.
    pub link_points: Vec<LinkPoint>,
    /// E, derived from L ([`HybridMap::connect`]).
    pub edges: Vec<LinkEdge>,
    /// Link-point candidates (doors seen, not passed).
    #[serde(default)]
    pub candidates: Vec<LinkCandidate>,
}

/// A route between two poses.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Route {
    /// The maps passed through, in order (the start's first, the goal's last).
    pub areas: Vec<usize>,
    /// The link points passed through, in order.
    pub link_points: Vec<usize>,
    /// Length (m): straight lines from the start to the first link point, between link
    /// points within their map, and from the last to the goal.
    pub length_m: f64,
    /// The transform from the goal map's frame to the start map's frame along the route.
    pub start_from_goal: Se2,
}

impl HybridMap {
    /// `Ok` when the map keeps its rules, which a file read from disk may break: every id is
    /// its index, every link point, candidate and edge names areas that exist, an edge joins
    /// two link points of its area, poses are finite and lengths finite and non-negative (a
    /// negative length is a negative cycle for the shortest-path search, every edge going
    /// both ways). The error names the first broken rule's item and field.
    pub fn validate(&self) -> Result<(), AreasError> {
        let bad = |what: String| Err(AreasError::Hybrid(what));
        let finite =
            |pose: &Se2| pose.x_m.is_finite() && pose.y_m.is_finite() && pose.theta_rad.is_finite();
        let areas = self.areas.len();
        // Every id is its index.
        let ids = |list: &str, ids: &mut dyn Iterator<Item = usize>| match ids
            .enumerate()
            .find(|(i, id)| i != id)
        {
            Some((i, id)) => bad(format!("{list}[{i}].id is {id}, not its index {i}")),
            None => Ok(()),
        };
        ids("areas", &mut self.areas.iter().map(|a| a.id))?;
        ids("link_points", &mut self.link_points.iter().map(|l| l.id))?;
        ids("candidates", &mut self.candidates.iter().map(|c| c.id))?;
        for (i, area) in self.areas.iter().enumerate() {
            if !finite(&area.first_from_area) {
                return bad(format!("areas[{i}].first_from_area is not finite"));
            }
        }
        for (i, link) in self.link_points.iter().enumerate() {
            if let Some(area) = link.areas.iter().find(|a| **a >= areas) {
                return bad(format!(
                    "link_points[{i}].areas: no area {area} (there are {areas})"
                ));
            }
            if link.areas[0] == link.areas[1] {
                return bad(format!(
                    "link_points[{i}].areas: joins area {} to itself",
                    link.areas[0]
                ));
            }
            if !link.poses.iter().all(finite) {
                return bad(format!("link_points[{i}].poses: not finite"));
            }
        }
        for (i, candidate) in self.candidates.iter().enumerate() {
            if candidate.area >= areas {
                return bad(format!(
                    "candidates[{i}].area: no area {} (there are {areas})",
                    candidate.area
                ));
            }
            if !finite(&candidate.pose) {
                return bad(format!("candidates[{i}].pose: not finite"));
            }
        }
        for (i, edge) in self.edges.iter().enumerate() {
            for end in [edge.from, edge.to] {
                let Some(link) = self.link_points.get(end) else {
                    return bad(format!(
                        "edges[{i}]: no link point {end} (there are {})",
                        self.link_points.len()
                    ));
                };
                if !link.areas.contains(&edge.area) {
                    return bad(format!(
                        "edges[{i}]: link point {end} is not in area {}",
                        edge.area
                    ));
                }
            }
            if !(edge.length_m.is_finite() && edge.length_m >= 0.0) {
                return bad(format!(
                    "edges[{i}].length_m is {}, not a finite length ≥ 0",
                    edge.length_m
                ));
            }
        }
        Ok(())
    }

    /// Rebuilds E from L: every two link points that share a map are joined by their
    /// distance in it.
    pub fn connect(&mut self) {
        let mut edges = Vec::new();
        for (i, a) in self.link_points.iter().enumerate() {
            for b in &self.link_points[i + 1..] {
                for area in a.areas {
                    if let (Some(pa), Some(pb)) = (a.pose_in(area), b.pose_in(area)) {
                        edges.push(LinkEdge {
                            from: a.id,
                            to: b.id,
                            area,
                            length_m: (pa.translation() - pb.translation()).norm(),
                        });
                    }
                }
            }
        }
        self.edges = edges;
    }

    /// The shortest route (Dijkstra over E) from `start` in map `start_area` to `goal` in map
    /// `goal_area` (positions in those maps' frames); `None` when a map is unknown, the hybrid
    /// map breaks its rules ([`HybridMap::validate`]) or no chain of link points joins them.
    pub fn route(
        &self,
        start_area: usize,
        start: Point2,
        goal_area: usize,
        goal: Point2,
    ) -> Option<Route> {
        // A map read from a file may break the rules the search relies on (a negative length
        // would never let it end): no route.
        if start_area >= self.areas.len()
            || goal_area >= self.areas.len()
            || self.validate().is_err()
        {
            return None;
        }
        if start_area == goal_area {
            return Some(Route {
                areas: vec![start_area],
                link_points: Vec::new(),
                length_m: (goal - start).norm(),
                start_from_goal: Se2::identity(),
            });
        }
        // Nodes: the link points, then the start and the goal.
        let n = self.link_points.len();
        let mut graph: UnGraph<(), (f64, usize)> = UnGraph::with_capacity(n + 2, 0);
        let nodes: Vec<NodeIndex> = (0..n + 2).map(|_| graph.add_node(())).collect();
        let (start_node, goal_node) = (nodes[n], nodes[n + 1]);
        for edge in &self.edges {
            if let (Some(a), Some(b)) = (nodes.get(edge.from), nodes.get(edge.to)) {
                graph.add_edge(*a, *b, (edge.length_m, edge.area));
            }
        }
        for link in &self.link_points {
            if let Some(p) = link.pose_in(start_area) {
                graph.add_edge(
                    start_node,
                    nodes[link.id], // < n: checked above
                    ((p.translation() - start).norm(), start_area),
                );
            }
            if let Some(p) = link.pose_in(goal_area) {
                graph.add_edge(
                    goal_node,
                    nodes[link.id],
                    ((p.translation() - goal).norm(), goal_area),
                );
            }
        }
        let (length_m, path) = petgraph::algo::astar(
            &graph,
            start_node,
            |node| node == goal_node,
            |e| e.weight().0,
            |_| 0.0,
        )?;
        // The map of each leg: the shortest edge joining its two nodes.
        let mut legs = Vec::with_capacity(path.len());
        for pair in path.windows(2) {
            let area = graph
                .edges_connecting(pair[0], pair[1])
                .min_by(|a, b| a.weight().0.total_cmp(&b.weight().0))
                .map(|e| e.weight().1)?;
            legs.push(area);
        }
        let link_points: Vec<usize> = path
            .iter()
            .filter(|node| node.index() < n)
            .map(|node| node.index())
            .collect();
        // Link point k lies between legs k and k + 1; where they differ, the route changes map.
        let mut areas = vec![start_area];
        let mut start_from_current = Se2::identity();
        for (k, id) in link_points.iter().enumerate() {
            let (Some(&from), Some(&to)) = (legs.get(k), legs.get(k + 1)) else {
                return None;
            };
            if from == to {
                continue;
            }
            let link = self.link_points.get(*id)?;
            let current_from_next = link.a_from_b(from, to)?;
            start_from_current = start_from_current.compose(&current_from_next);
            areas.push(to);
        }
        Some(Route {
            areas,
            link_points,
            length_m,
            start_from_goal: start_from_current,
        })
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use proptest::prelude::*;

    use super::*;

    /// A hybrid map of `areas` maps, each in a frame rotated and shifted from the world's,
    /// with link points at world positions `links` (area pairs) — the world positions are
    /// the ground truth routes are checked against.
    fn build(areas: usize, links: &[(usize, usize, f64, f64)]) -> (HybridMap, Vec<Se2>) {
        let world_from_area: Vec<Se2> = (0..areas)
            .map(|i| Se2::new(3.0 * i as f64, -(i as f64), 0.3 * i as f64))
            .collect();
        let mut map = HybridMap {
            areas: (0..areas)
                .map(|id| Area {
                    id,
                    environment: Environment::Indoor,
                    first_from_area: Se2::identity(),
                })
                .collect(),
            ..HybridMap::default()
        };
        for (id, (a, b, x, y)) in links.iter().enumerate() {
            let world = Se2::new(*x, *y, 0.1 * id as f64);
            map.link_points.push(LinkPoint {
                id,
                areas: [*a, *b],
                poses: [
                    world_from_area[*a].inverse().compose(&world),
                    world_from_area[*b].inverse().compose(&world),
                ],
            });
        }
        map.connect();
        (map, world_from_area)
    }

    #[test]
    fn a_route_through_three_maps_and_its_transform_chain() {
        // 0 —L0— 1 —L1— 2, and a longer way 0 —L2— 2.
        let (map, world) = build(3, &[(0, 1, 1.0, 0.0), (1, 2, 2.0, 0.0), (0, 2, 0.0, 10.0)]);
        let start = world[0].inverse().transform_point(&Point2::new(0.0, 0.0));
        let goal = world[2].inverse().transform_point(&Point2::new(3.0, 0.0));
        let route = map.route(0, start, 2, goal).unwrap();
        assert_eq!(route.areas, vec![0, 1, 2]);
        assert_eq!(route.link_points, vec![0, 1]);
        assert!((route.length_m - 3.0).abs() < 1e-9, "{}", route.length_m);
        let expected = world[0].inverse().compose(&world[2]);
        let error = expected.between(&route.start_from_goal);
        assert!(error.translation().norm() < 1e-9 && error.theta_rad.abs() < 1e-9);
        assert!(map.route(0, start, 7, goal).is_none(), "an unknown map");
    }

    /// Issue 67: a hybrid map read from a file that breaks a rule is refused by name, and
    /// has no route (a negative edge once made the search run out of memory).
    #[test]
    fn a_map_that_breaks_its_rules_is_refused_and_has_no_route() {
        let (good, _) = build(3, &[(0, 1, 1.0, 0.0), (1, 2, 2.0, 0.0), (0, 2, 0.0, 10.0)]);
        good.validate().unwrap();
        type Break = fn(&mut HybridMap);
        let cases: [(Break, &str); 9] = [
            (|m| m.link_points[0].id = 7, "link_points[0].id"),
            (|m| m.link_points[1].id = 0, "link_points[1].id"),
            (|m| m.areas[2].id = 1, "areas[2].id"),
            (
                |m| m.link_points[0].areas[1] = 9,
                "link_points[0].areas: no area 9",
            ),
            (
                |m| m.link_points[0].areas = [1, 1],
                "link_points[0].areas: joins",
            ),
            (
                |m| m.link_points[2].poses[0].x_m = f64::NAN,
                "link_points[2].poses",
            ),
            (|m| m.edges[0].length_m = -1.0, "edges[0].length_m"),
            (|m| m.edges[1].to = 5, "edges[1]: no link point 5"),
            (|m| m.edges[0].area = 2, "is not in area 2"),
        ];
        for (breaks, named) in cases {
            let mut map = good.clone();
            breaks(&mut map);
            let error = map.validate().unwrap_err().to_string();
            assert!(error.contains(named), "{error} should name {named}");
            assert!(
                map.route(0, Point2::zeros(), 2, Point2::zeros()).is_none(),
                "{named}"
            );
        }
    }

    #[test]
    fn unconnected_maps_have_no_route() {
        let (map, _) = build(4, &[(0, 1, 1.0, 0.0), (2, 3, 5.0, 0.0)]);
        assert!(map.route(0, Point2::zeros(), 3, Point2::zeros()).is_none());
        let same = map
            .route(2, Point2::zeros(), 2, Point2::new(3.0, 4.0))
            .unwrap();
        assert_eq!((same.areas.clone(), same.length_m), (vec![2], 5.0));
    }

    /// Brute force: Floyd–Warshall over the link points plus start and goal.
    fn brute_force(map: &HybridMap, sa: usize, s: Point2, ga: usize, g: Point2) -> Option<f64> {
        if sa == ga {
            return Some((g - s).norm());
        }
        let n = map.link_points.len() + 2;
        let mut d = vec![vec![f64::INFINITY; n]; n];
        for (i, row) in d.iter_mut().enumerate() {
            row[i] = 0.0;
        }
        for e in &map.edges {
            d[e.from][e.to] = d[e.from][e.to].min(e.length_m);
            d[e.to][e.from] = d[e.from][e.to];
        }
        for l in &map.link_points {
            if let Some(p) = l.pose_in(sa) {
                d[n - 2][l.id] = (p.translation() - s).norm();
                d[l.id][n - 2] = d[n - 2][l.id];
            }
            if let Some(p) = l.pose_in(ga) {
                d[n - 1][l.id] = (p.translation() - g).norm();
                d[l.id][n - 1] = d[n - 1][l.id];
            }
        }
        for k in 0..n {
            for i in 0..n {
                for j in 0..n {
                    if d[i][k] + d[k][j] < d[i][j] {
                        d[i][j] = d[i][k] + d[k][j];
                    }
                }
            }
        }
        d[n - 2][n - 1].is_finite().then_some(d[n - 2][n - 1])
    }

    proptest! {
        #[test]
        fn routes_agree_with_brute_force(
            areas in 2usize..8,
            links in proptest::collection::vec((0usize..8, 0usize..8, -20.0..20.0f64, -20.0..20.0f64), 0..14),
            sa in 0usize..8, ga in 0usize..8,
            (sx, sy, gx, gy) in (-20.0..20.0f64, -20.0..20.0f64, -20.0..20.0f64, -20.0..20.0f64),
        ) {
            let links: Vec<_> = links
                .into_iter()
                .map(|(a, b, x, y)| (a % areas, b % areas, x, y))
                .filter(|(a, b, _, _)| a != b)
                .collect();
            let (sa, ga) = (sa % areas, ga % areas);
            let (map, world) = build(areas, &links);
            let (s, g) = (Point2::new(sx, sy), Point2::new(gx, gy));
            let route = map.route(sa, s, ga, g);
            let expected = brute_force(&map, sa, s, ga, g);
            prop_assert_eq!(route.is_some(), expected.is_some());
            if let (Some(route), Some(expected)) = (route, expected) {
                prop_assert!((route.length_m - expected).abs() < 1e-6, "{} vs {}", route.length_m, expected);
                prop_assert_eq!(route.areas.first().copied(), Some(sa));
                prop_assert_eq!(route.areas.last().copied(), Some(ga));
                // The transform chain is the true one between the two frames.
                let truth = world[sa].inverse().compose(&world[ga]);
                let error = truth.between(&route.start_from_goal);
                prop_assert!(error.translation().norm() < 1e-6 && error.theta_rad.abs() < 1e-6);
            }
        }
    }
}
