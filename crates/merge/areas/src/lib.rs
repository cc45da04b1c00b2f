//! The map manager of Ehlers et al. (`../shared/seeds/003_*`): a large site as one map per
//! room, corridor or hall, each built with the SLAM configuration that suits it, joined by
//! link points at doors.
//!
//! - Sec. II-B: detecting door passings from laser scans ([`DoorDetector`], three criteria of
//!   which two must hold) and choosing the next map's configuration from the scans' extents
//!   ([`Environment`], the presets `indoor` and `large`); `mapmerge-lab` scores both against
//!   the simulator's doors;
//! - Sec. II-A and II-C: splitting a log into areas at its door passings ([`segment`]) and the
//!   hybrid map of their maps, link points and edges ([`HybridMap`]), with routes by Dijkstra
//!   and the transform chain along them ([`HybridMap::route`]);
//! - Sec. II-C and II-D: global tracking through the link-point chain (Eq. 3's radius),
//!   topological loop closure at a door passed again, link-point optimisation, and a later
//!   session placed by a global search over the placed areas ([`manage_sessions`]);
//! - sessions as mapped and stored ([`MappedSession`]), so that the lifelong store can keep a
//!   site's areas and a later run can add to them ([`manage_mapped`]).

mod door;
mod environment;
mod error;
mod hybrid;
mod manager;
mod session;

pub use door::{
    passways, Criteria, DoorDetector, DoorParams, DoorPassingDetection, DoorSighting, UnpassedDoor,
};
pub use environment::{Environment, EnvironmentParams, Extents, Preset};
pub use error::AreasError;
pub use hybrid::{Area, HybridMap, LinkCandidate, LinkEdge, LinkPoint, Route};
pub use manager::{
    manage, manage_sessions, segment, AreaSpan, CandidateClosure, Closure, ManagedMap,
    ManagerParams, Segmentation, SessionInput, TrackingParams, TrackingStep,
};
pub use session::{manage_mapped, map_session, MapSpan, MappedSession};
