//! Integration tests of the `mapmerge` binary, by command.
//! One test binary for the crate: each module was a test file of its own, and one binary
//! builds and links once.

mod common;

mod areas_commands;
mod assemble_commands;
mod atlas_commands;
mod bag_commands;
mod config_mutation;
mod crash_store;
mod eval_commands;
mod eval_slam;
mod grid_commands;
mod grid_merge_commands;
mod invalid_merge_commands;
mod ros_tools_agree;
mod sim_commands;
mod slam_commands;
mod split_command;
mod store_commands;
