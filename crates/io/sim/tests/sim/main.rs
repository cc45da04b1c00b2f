//! Integration tests of the simulator.
//! One test binary for the crate: each module was a test file of its own, and one binary
//! builds and links once.

mod common;

mod changes;
mod determinism;
mod kidnap;
mod lidar;
mod odometry;
mod sessions;
mod symmetric_hall;
mod walls;
mod worlds;
