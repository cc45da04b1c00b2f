//! The map manager of Ehlers et al. (`../shared/seeds/003_*`): a large site as one map per
//! room, corridor or hall, each built with the SLAM configuration that suits it, joined by
//! link points at doors.
//!
//! This crate holds, so far, Sec. II-B: detecting door passings from laser scans
//! ([`DoorDetector`], three criteria of which two must hold), choosing the next map's
//! configuration from the scans' extents ([`Environment`], the presets `indoor` and `large`),
//! and scoring detection against the simulator's doors ([`eval`]).

mod door;
mod environment;
mod error;
pub mod eval;
mod hybrid;

pub use door::{passways, Criteria, DoorDetector, DoorParams, DoorPassingDetection, DoorSighting};
pub use environment::{Environment, EnvironmentParams, Extents, Preset};
pub use error::AreasError;
pub use hybrid::{Area, HybridMap, LinkEdge, LinkPoint, Route};
