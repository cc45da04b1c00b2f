//! The error type of this crate.

use mapmerge_grid::GridError;

use crate::{DoorId, RoomId};

/// Why a world could not be generated, a simulation could not run or a log could not be given
/// odometry noise.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SimError {
    /// No preset has this name.
    #[error("unknown world preset `{name}`; valid presets: {valid}")]
    UnknownPreset {
        /// The name asked for.
        name: String,
        /// The valid names, comma-separated.
        valid: String,
    },
    /// No odometry noise profile has this name.
    #[error("unknown odometry noise profile `{name}`; known: {valid}")]
    UnknownNoiseProfile {
        /// The name asked for.
        name: String,
        /// The known names, comma-separated.
        valid: String,
    },
    /// A parameter is out of its range.
    #[error("invalid parameter `{field}`: {reason}")]
    InvalidParams {
        /// The parameter (dotted path inside its params struct).
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// A start room named in the parameters does not exist or cannot be reached.
    #[error("start room `{name}` of session {session} does not exist or has no free space")]
    UnknownStartRoom {
        /// The session whose start it was.
        session: usize,
        /// The name asked for.
        name: String,
    },
    /// A room id that the world does not have.
    #[error("{0} does not exist")]
    UnknownRoom(RoomId),
    /// A door id that the world does not have.
    #[error("{0} does not exist")]
    UnknownDoor(DoorId),
    /// The world has no free space the robot fits in.
    #[error("world `{0}` has no free space for the robot")]
    NoFreeSpace(String),
    /// A scan of a laser log carries no robot pose (e.g. `RAWLASER*`), so the log has no
    /// trajectory to add odometry noise to.
    #[error("scan {scan} carries no robot pose")]
    MissingPose {
        /// Index of the scan in the log.
        scan: usize,
    },
    /// The ground-truth grid could not be made.
    #[error("ground-truth grid: {0}")]
    Grid(#[from] GridError),
}
