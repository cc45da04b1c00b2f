//! mapmerge on a live ROS 2 graph, without a ROS install: ros2-client on RustDDS (pure Rust),
//! speaking ROS 2's topic names (`rt/…`), type names (`pkg::msg::dds_::Type_`) and QoS.
//!
//! - [`run_slam_node`] (`mapmerge ros2 slam`): the lifelong engine on `/scan`, `/odom`, `/tf`
//!   and `/tf_static`; publishes `/tf` map → odom for every scan, `/map` at a period and the
//!   engine's events on `/mapmerge/events`; with a store, the session is committed at the end.
//! - [`run_merge_node`] (`mapmerge ros2 merge`): m-explore-ros2's `map_merge` topics: every
//!   `/<robot>/map` discovered, merged without initial poses (`grid-merge`'s framework), the
//!   merged map on `/map`, and each robot's state and why it is not merged.
//!
//! The messages are the bag reader's (`mapmerge_rosbag`): one declaration per ROS type.

mod merge;
mod ros;
mod slam;

pub use merge::{
    run_merge_node, MergeNodeOptions, MergeNodeReport, RobotReport, RobotState, EVENTS_TOPIC,
};
pub use ros::{check_domain, domain_from_env, Delivery, DOMAIN_ID_MAX};
pub use slam::{run_slam_node, LatencySummary, SlamNodeOptions, SlamNodeReport};
