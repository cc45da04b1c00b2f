//! The map manager of Ehlers et al. (`../shared/seeds/003_*`): a large site as one map per
//! room, corridor or hall, each built with the SLAM configuration that suits it, joined by
//! link points at doors.
//!
//! This crate holds, so far:
//! - Sec. II-B: detecting door passings from laser scans ([`DoorDetector`], three criteria of
//!   which two must hold) and choosing the next map's configuration from the scans' extents
//!   ([`Environment`], the presets `indoor` and `large`), scored against the simulator's
//!   doors ([`eval`]);
//! - Sec. II-A and II-C: splitting a log into areas at its door passings ([`segment`]) and the
//!   hybrid map of their maps, link points and edges ([`hybrid_map`], [`HybridMap`]), with
//!   routes by Dijkstra and the transform chain along them ([`HybridMap::route`]).
//!
//! Not yet: topological loop closure when a known door is passed again (each passing starts a
//! new area), global tracking (Sec. II-D, Eq. 3) and link-point optimisation.

mod door;
mod environment;
mod error;
pub mod eval;
mod hybrid;
mod manager;

pub use door::{passways, Criteria, DoorDetector, DoorParams, DoorPassingDetection, DoorSighting};
pub use environment::{Environment, EnvironmentParams, Extents, Preset};
pub use error::AreasError;
pub use hybrid::{Area, HybridMap, LinkEdge, LinkPoint, Route};
pub use manager::{
    manage, manage_sessions, segment, AreaSpan, Closure, ManagedMap, ManagerParams, Segmentation,
    SessionInput, TrackingParams, TrackingStep,
};
