//! `mapmerge ros2 merge`: m-explore-ros2's `map_merge` topics, merged without initial poses.
//! Robots publish `/<robot>/map` (nav_msgs/OccupancyGrid); the node discovers them, places
//! each map in the reference robot's map by Andersone's framework (`grid-merge`: decision
//! table, Carpin's matching, Bayes fusion), directly or through a robot already placed, and
//! publishes the merged map on `/map`. Each robot's state, and why it is not merged, goes to
//! `/mapmerge/events` (JSON in std_msgs/String) and to the report.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{ClassThresholds, OccupancyGrid};
use mapmerge_gridmatch::GridMatchParams;
use mapmerge_gridmerge::{fuse, FusionParams};
use mapmerge_io::RosMap;
use mapmerge_jobs::{map_from_grid, merge_loaded, JobError, TransformReport};
use mapmerge_rosbag::{
    occupancy_grid_message, ros_map_of_message, Header, OccupancyGridMessage, Quaternion,
    OCCUPANCY_GRID_TYPE,
};
use ros2_client::Subscription;
use serde::Serialize;

use crate::ros::{
    advertise, latched, now_s, open_node, stamp_of, subscribe, take_all, MapWriter, STRING_TYPE,
};

/// The events topic both nodes publish on.
pub const EVENTS_TOPIC: &str = "/mapmerge/events";

/// The DDS type name of OccupancyGrid, as discovery reports it.
const OCCUPANCY_GRID_DDS: &str = "nav_msgs::msg::dds_::OccupancyGrid_";

/// Seconds between looks for new robots.
const DISCOVERY_PERIOD_S: f64 = 1.0;

/// How long the loop sleeps when there is nothing to do.
const IDLE: Duration = Duration::from_millis(10);

/// What `mapmerge ros2 merge` does.
#[derive(Clone, Debug)]
pub struct MergeNodeOptions {
    /// The DDS domain (`ROS_DOMAIN_ID`).
    pub domain: u16,
    /// The robots' map topic under their namespace (m-explore's `robot_map_topic`).
    pub robot_map_topic: String,
    /// The merged map's topic (m-explore's `merged_map_topic`, absolute).
    pub merged_map_topic: String,
    /// The robot whose map frame the merged map takes; the first robot by name without.
    pub reference: Option<String>,
    /// Matching parameters (as `grid-merge --config`).
    pub params: GridMatchParams,
    /// Seconds between merges (when a map changed) and publications.
    pub period_s: f64,
    /// Stop after this long (s); `None` runs until stopped.
    pub duration_s: Option<f64>,
}

impl Default for MergeNodeOptions {
    fn default() -> Self {
        Self {
            domain: 0,
            robot_map_topic: "map".into(),
            merged_map_topic: "/map".into(),
            reference: None,
            params: GridMatchParams::default(),
            period_s: 1.0,
            duration_s: None,
        }
    }
}

/// Where a robot is.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RobotState {
    /// Discovered, no map received yet.
    Waiting,
    /// Its map frame is the merged map's.
    Reference,
    /// Placed in the merged map.
    Merged,
    /// Received, but not placed: `reason` says why.
    NotMerged,
}

/// One robot, as the report and the events give it.
#[derive(Clone, Debug, Serialize)]
pub struct RobotReport {
    /// Its namespace (`robot1` for `/robot1/map`).
    pub robot: String,
    /// Its map topic.
    pub topic: String,
    /// Maps received.
    pub maps_received: usize,
    /// Where it is.
    pub state: RobotState,
    /// Why it is not merged (also a map that could not be read).
    pub reason: Option<String>,
    /// Its map frame in the merged map's frame (m, rad), once merged.
    pub transform: Option<TransformReport>,
    /// Birk & Carpin's acceptance index of the placement.
    pub acceptance: Option<f64>,
    /// The robot whose map it was matched against.
    pub via: Option<String>,
}

/// What the node did: the `--json` object of `mapmerge ros2 merge`.
#[derive(Clone, Debug, Serialize)]
pub struct MergeNodeReport {
    /// Every robot discovered, by name.
    pub robots: Vec<RobotReport>,
    /// Merged maps published.
    pub published: usize,
    /// Pairs matched (each pair of map versions once).
    pub matches: usize,
    /// Time spent matching (s).
    pub match_seconds: f64,
    /// Wall time (s).
    pub seconds: f64,
}

/// One pair's outcome for given map versions.
#[derive(Clone, Debug)]
struct PairOutcome {
    versions: (u64, u64),
    /// `a_grid_from_b_grid` when accepted.
    accepted: Option<Se2>,
    acceptance: Option<f64>,
    reason: Option<String>,
}

struct Robot {
    subscription: Subscription<OccupancyGridMessage>,
    map: Option<(RosMap, OccupancyGrid)>,
    version: u64,
    report: RobotReport,
    /// `reference_grid_from_grid` once placed.
    placed: Option<Se2>,
}

/// The robot of a discovered DDS topic `rt/<robot>/<map_topic>` of OccupancyGrid, except the
/// merged map's own topic.
fn robot_of_topic(
    dds_name: &str,
    type_name: &str,
    map_topic: &str,
    merged: &str,
) -> Option<String> {
    if type_name != OCCUPANCY_GRID_DDS {
        return None;
    }
    let ros_name = dds_name.strip_prefix("rt")?;
    if ros_name == merged {
        return None;
    }
    let robot = ros_name
        .strip_suffix(map_topic)?
        .strip_suffix('/')?
        .trim_start_matches('/');
    (!robot.is_empty()).then(|| robot.to_owned())
}

/// Runs the node until `stop` is set (or the duration is over), calling `say` with each line
/// worth a user's attention (a robot found, merged, or why not).
pub fn run_merge_node(
    options: &MergeNodeOptions,
    stop: &AtomicBool,
    mut say: impl FnMut(&str),
) -> Result<MergeNodeReport, JobError> {
    options
        .params
        .validate()
        .map_err(|e| JobError::bad_input(format!("matching parameters: {e}")))?;
    if !(options.period_s.is_finite() && options.period_s > 0.0) {
        return Err(JobError::bad_input(
            "--period must be a positive number of seconds",
        ));
    }
    let started = Instant::now();
    let (context, mut node) = open_node(options.domain, "mapmerge_map_merge")?;
    let map_topic = options.robot_map_topic.trim_matches('/').to_owned();
    let map_publisher = MapWriter::new(&context, &mut node, &options.merged_map_topic)?;
    let events = advertise::<String>(&mut node, EVENTS_TOPIC, STRING_TYPE, latched(100))?;
    let mut robots: BTreeMap<String, Robot> = BTreeMap::new();
    let mut outcomes: BTreeMap<(String, String), PairOutcome> = BTreeMap::new();
    let mut last_discovery: Option<Instant> = None;
    let mut last_merge: Option<Instant> = None;
    let mut merged_versions: Vec<(String, u64)> = Vec::new();
    let mut report = MergeNodeReport {
        robots: Vec::new(),
        published: 0,
        matches: 0,
        match_seconds: 0.0,
        seconds: 0.0,
    };
    let mut bad_messages = 0usize;
    let thresholds = ClassThresholds::default();
    let fusion = FusionParams::default();
    while !stop.load(Ordering::Relaxed)
        && options
            .duration_s
            .is_none_or(|d| started.elapsed().as_secs_f64() < d)
    {
        // 1. Robots: m-explore's `/<robot>/map` topics.
        if last_discovery.is_none_or(|t| t.elapsed().as_secs_f64() >= DISCOVERY_PERIOD_S) {
            last_discovery = Some(Instant::now());
            for found in context.discovered_topics() {
                let Some(robot) = robot_of_topic(
                    &found.name,
                    &found.type_name,
                    &map_topic,
                    &options.merged_map_topic,
                ) else {
                    continue;
                };
                if robots.contains_key(&robot) {
                    continue;
                }
                let topic = format!("/{robot}/{map_topic}");
                // m-explore's QoS: reliable and transient-local, so a map published before
                // the node started is heard.
                let subscription = subscribe(&mut node, &topic, OCCUPANCY_GRID_TYPE, latched(1))?;
                say(&format!(
                    "robot {robot}: found {topic}, waiting for its map"
                ));
                robots.insert(
                    robot.clone(),
                    Robot {
                        subscription,
                        map: None,
                        version: 0,
                        report: RobotReport {
                            robot,
                            topic,
                            maps_received: 0,
                            state: RobotState::Waiting,
                            reason: Some("no map received yet".into()),
                            transform: None,
                            acceptance: None,
                            via: None,
                        },
                        placed: None,
                    },
                );
            }
        }
        // 2. Their newest maps.
        let mut heard = false;
        for robot in robots.values_mut() {
            let mut taken = take_all(&robot.subscription, &mut bad_messages);
            robot.report.maps_received += taken.len();
            // Only the newest map of a robot counts.
            let Some(message) = taken.pop() else {
                continue;
            };
            heard = true;
            match ros_map_of_message(&message).and_then(|map| {
                map.to_grid()
                    .map(|grid| (map, grid))
                    .map_err(|e| e.to_string())
            }) {
                Ok(read) => {
                    robot.map = Some(read);
                    robot.version += 1;
                }
                Err(reason) => {
                    let reason = format!("its map cannot be read: {reason}");
                    say(&format!("robot {}: {reason}", robot.report.robot));
                    robot.report.reason = Some(reason);
                }
            }
        }
        // 3. Merge when a map changed and the period is over.
        let versions: Vec<(String, u64)> = robots
            .iter()
            .map(|(name, robot)| (name.clone(), robot.version))
            .collect();
        let due = last_merge.is_none_or(|t| t.elapsed().as_secs_f64() >= options.period_s);
        if !(due && versions != merged_versions) {
            if !heard {
                std::thread::sleep(IDLE);
            }
            continue;
        }
        last_merge = Some(Instant::now());
        merged_versions = versions;
        let before: Vec<(RobotState, Option<String>)> = robots
            .values()
            .map(|r| (r.report.state.clone(), r.report.reason.clone()))
            .collect();
        let merged = place_robots(options, &mut robots, &mut outcomes, &mut report)?;
        for (robot, (state, reason)) in robots.values().zip(before) {
            if robot.report.state != state || robot.report.reason != reason {
                say(&describe(&robot.report));
                let event = serde_json::json!({ "event": "robot", "robot": &robot.report });
                // An event that cannot be sent is not worth stopping for: the report has it.
                let _ = events.publish(event.to_string());
            }
        }
        let Some((reference_map, grid)) = merged else {
            continue;
        };
        // 4. Fuse and publish.
        let mut fused = grid;
        for robot in robots.values() {
            if let (Some(placed), Some((_, robot_grid)), RobotState::Merged) =
                (robot.placed, &robot.map, &robot.report.state)
            {
                fused = fuse(&fused, robot_grid, &placed, &fusion)
                    .map_err(|e| JobError::context("fusing the maps", &e))?
                    .merged;
            }
        }
        let header = Header {
            stamp: stamp_of(now_s()),
            frame_id: "map".into(),
        };
        let mut message = occupancy_grid_message(&fused, &thresholds, header);
        message.info.origin.orientation = Quaternion::from_yaw(reference_map.origin_yaw_rad);
        if map_publisher.publish(message) {
            report.published += 1;
        }
    }
    // The last merged map reaches every subscriber before the node leaves.
    map_publisher.flush(std::time::Duration::from_secs(5));
    report.robots = robots.into_values().map(|r| r.report).collect();
    report.seconds = started.elapsed().as_secs_f64();
    Ok(report)
}

/// A robot's state in words.
fn describe(robot: &RobotReport) -> String {
    match (&robot.state, &robot.transform) {
        (RobotState::Reference, _) => {
            format!("robot {}: reference (its map frame is /map's)", robot.robot)
        }
        (RobotState::Merged, Some(t)) => format!(
            "robot {}: merged at x {:.3} m, y {:.3} m, yaw {:.2}° (acceptance {:.3}, via {})",
            robot.robot,
            t.x,
            t.y,
            t.yaw.to_degrees(),
            robot.acceptance.unwrap_or(0.0),
            robot.via.as_deref().unwrap_or("?")
        ),
        _ => format!(
            "robot {}: not merged: {}",
            robot.robot,
            robot.reason.as_deref().unwrap_or("no reason")
        ),
    }
}

/// Places every robot with a map: the reference first, then each other robot against a robot
/// already placed (the reference first), until no more can be placed. Returns the reference's
/// map and grid.
fn place_robots(
    options: &MergeNodeOptions,
    robots: &mut BTreeMap<String, Robot>,
    outcomes: &mut BTreeMap<(String, String), PairOutcome>,
    report: &mut MergeNodeReport,
) -> Result<Option<(RosMap, OccupancyGrid)>, JobError> {
    let with_maps: Vec<String> = robots
        .iter()
        .filter(|(_, r)| r.map.is_some())
        .map(|(n, _)| n.clone())
        .collect();
    let reference = match &options.reference {
        Some(name) if with_maps.contains(name) => name.clone(),
        Some(name) => {
            for robot in robots.values_mut() {
                robot.placed = None;
                if robot.map.is_some() {
                    robot.report.state = RobotState::NotMerged;
                    robot.report.reason =
                        Some(format!("the reference robot {name} has no map yet"));
                }
            }
            return Ok(None);
        }
        None => match with_maps.first() {
            Some(first) => first.clone(),
            None => return Ok(None),
        },
    };
    let mut placed: Vec<(String, Se2)> = vec![(reference.clone(), Se2::identity())];
    let mut pending: Vec<String> = with_maps.into_iter().filter(|n| *n != reference).collect();
    let mut last_tries: BTreeMap<String, (Option<f64>, String)> = BTreeMap::new();
    let mut placed_via: BTreeMap<String, (String, Option<f64>)> = BTreeMap::new();
    loop {
        let mut progress = false;
        let mut still = Vec::new();
        for name in pending {
            let mut done = None;
            for (anchor, reference_from_anchor) in &placed {
                let (Some(a), Some(b)) = (robots.get(anchor), robots.get(&name)) else {
                    continue;
                };
                let (Some(a_map), Some(b_map)) = (&a.map, &b.map) else {
                    continue;
                };
                let key = (anchor.clone(), name.clone());
                let versions = (a.version, b.version);
                let outcome = match outcomes.get(&key) {
                    Some(o) if o.versions == versions => o.clone(),
                    _ => {
                        let matched = merge_loaded(
                            (&a_map.0, &a_map.1),
                            (&b_map.0, &b_map.1),
                            &options.params,
                            0,
                            None,
                        )?;
                        report.matches += 1;
                        report.match_seconds += matched.report.match_seconds;
                        let outcome = PairOutcome {
                            versions,
                            accepted: matched
                                .a_grid_from_b_grid
                                .filter(|_| matched.report.accepted),
                            acceptance: matched.report.acceptance,
                            reason: matched.report.reason.clone(),
                        };
                        outcomes.insert(key, outcome.clone());
                        outcome
                    }
                };
                match outcome.accepted {
                    Some(a_from_b) => {
                        done = Some(reference_from_anchor.compose(&a_from_b));
                        placed_via.insert(name.clone(), (anchor.clone(), outcome.acceptance));
                        break;
                    }
                    None => {
                        last_tries.insert(
                            name.clone(),
                            (
                                outcome.acceptance,
                                format!(
                                    "against {anchor}: {}",
                                    outcome.reason.as_deref().unwrap_or("not accepted")
                                ),
                            ),
                        );
                    }
                }
            }
            match done {
                Some(t) => {
                    placed.push((name, t));
                    progress = true;
                }
                None => still.push(name),
            }
        }
        pending = still;
        if !progress || pending.is_empty() {
            break;
        }
    }
    let reference_read = robots
        .get(&reference)
        .and_then(|r| r.map.clone())
        .ok_or_else(|| JobError::bad_input("the reference robot has no map"))?;
    let reference_map_from_grid = map_from_grid(&reference_read.0);
    for (name, robot) in robots.iter_mut() {
        robot.placed = None;
        robot.report.transform = None;
        robot.report.acceptance = None;
        robot.report.via = None;
        if robot.map.is_none() {
            continue;
        }
        if let Some((_, t)) = placed.iter().find(|(n, _)| n == name) {
            robot.placed = Some(*t);
            if *name == reference {
                robot.report.state = RobotState::Reference;
                robot.report.reason = None;
                continue;
            }
            let map_from_map = robot.map.as_ref().map(|(map, _)| {
                reference_map_from_grid
                    .compose(t)
                    .compose(&map_from_grid(map).inverse())
            });
            robot.report.state = RobotState::Merged;
            robot.report.reason = None;
            robot.report.transform = map_from_map.map(|m| TransformReport {
                x: m.x_m,
                y: m.y_m,
                yaw: m.theta_rad,
            });
            if let Some((via, acceptance)) = placed_via.get(name) {
                robot.report.via = Some(via.clone());
                robot.report.acceptance = *acceptance;
            }
        } else {
            robot.report.state = RobotState::NotMerged;
            let (acceptance, reason) = last_tries
                .get(name)
                .cloned()
                .unwrap_or((None, "no robot placed to match against".into()));
            robot.report.acceptance = acceptance;
            robot.report.reason = Some(reason);
        }
    }
    Ok(Some(reference_read))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn robots_are_the_namespaces_of_map_topics() {
        let robot = |name: &str| robot_of_topic(name, OCCUPANCY_GRID_DDS, "map", "/map");
        assert_eq!(robot("rt/robot1/map").as_deref(), Some("robot1"));
        assert_eq!(robot("rt/fleet/tb3_2/map").as_deref(), Some("fleet/tb3_2"));
        assert_eq!(robot("rt/map"), None, "the merged map itself");
        assert_eq!(robot("rt/robot1/costmap"), None);
        assert_eq!(robot("rt/robot1/map_updates"), None);
        assert_eq!(
            robot_of_topic(
                "rt/robot1/map",
                "std_msgs::msg::dds_::String_",
                "map",
                "/map"
            ),
            None
        );
    }
}
