//! Integration tests of the file formats.
//! One test binary for the crate: each module was a test file of its own, and one binary
//! builds and links once.

mod carmen;
mod datasets;
mod errors;
mod kitti_never_panics;
mod mutation_smoke;
mod rosmap;
mod roundtrip;
mod tum_planar;
