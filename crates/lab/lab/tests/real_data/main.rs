//! The lab's tests on real data: initialisation, optimisation, SLAM and place recognition.
//! One test binary for the crate: each module was a test file of its own, and one binary
//! builds and links once.

mod init_real_data;
mod place_benchmark;
mod slam_intel;
mod slam_sim;
mod solve_outliers;
mod solve_real_data;
