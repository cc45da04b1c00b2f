//! The simulator: mapmerge's own data source for the hard cases of map merging. It generates
//! office floors and warehouses that look real to a laser (thick walls, ~1 m doors, 2 m
//! corridors, furniture, deliberately repeated rooms and corridor sections, a point-symmetric
//! hall whose opposite sides look alike), drives a differential-drive robot from room to room
//! through them, and records what its wheel odometry (with noise and slip) and 2D lidar saw,
//! over several sessions with kidnaps and with the world changing between sessions (doors
//! closed, furniture moved). Everything is deterministic for a given seed.
//!
//! Entry points:
//! - [`simulate`] with [`SimParams`]: a multi-session [`Dataset`] (laser logs plus ground
//!   truth, kidnaps, slips, world changes, each session's world).
//! - [`generate_world`] with [`WorldParams`] (or a named [`WorldPreset`]): a [`World`], which
//!   [`World::to_grid`] rasterises into the ground-truth occupancy grid.
//! - [`Lidar`] and [`Roadmap`]: scans from any pose, and routes that keep clear of obstacles,
//!   in any world (generated or hand-made).
//! - [`add_odometry_noise`]: the simulator's wheel-odometry model (random noise, calibration,
//!   slips; [`OdometryNoiseParams`]) applied to a *corrected* laser log, so a SLAM front-end can
//!   be scored against the corrected poses ([`OdometryNoiseProfile`]: `default`, `harsh`,
//!   `none`).
//!
//! ```
//! use mapmerge_sim::{simulate, SimParams, WorldPreset};
//! let params = SimParams::default()
//!     .with_preset(WorldPreset::OfficeAliased)
//!     .with_sessions(2)
//!     .with_duration_secs(20.0);
//! let dataset = simulate(&params, 7).unwrap();
//! assert_eq!(dataset.sessions.len(), 2);
//! let session = &dataset.sessions[1];
//! assert_eq!(session.log.scans.len(), session.truth.len()); // 10 Hz for 20 s: 201 scans
//! assert_eq!(session.log.scans[0].scan.ranges_m.len(), 360);
//! assert_eq!(session.log.odometry.len(), 401); // 20 Hz
//! let grid = dataset.world.to_grid(0.05).unwrap(); // the ground-truth map
//! assert!(grid.geometry().width > 800);
//! ```

#![warn(missing_docs)]

mod changes;
mod doors;
mod error;
mod furniture;
mod hall;
mod kidnap;
mod lidar;
mod motion;
mod noisy_log;
mod odometry;
mod office;
mod preset;
mod raster;
mod ray_caster;
mod rng;
mod roadmap;
mod shapes;
mod simulate;
mod warehouse;
mod world;

pub use changes::{ChangeParams, WorldChange};
pub use doors::{door_passings, DoorPassing};
pub use error::SimError;
pub use hall::SymmetricHallParams;
pub use kidnap::{Kidnap, KidnapParams, KidnapTarget};
pub use lidar::{Lidar, LidarParams};
pub use mapmerge_geometry::Point2;
pub use motion::{MotionInfo, RobotParams};
pub use noisy_log::{
    add_odometry_noise, scan_poses, NoisyLog, OdometryNoiseProfile, NOISE_PROFILE_NAMES,
};
pub use odometry::{OdometryNoiseParams, SlipEvent, SlipKind, SlipSchedule, SlipSpan};
pub use office::OfficeParams;
pub use preset::{generate_world, LayoutParams, WorldParams, WorldPreset};
pub use ray_caster::{RayCaster, DEFAULT_CELL_M};
pub use rng::{exponential, gaussian, gaussian_pair, seeded, uniform, uniform_drawn, SimRng};
pub use roadmap::Roadmap;
pub use shapes::{LineSegment, Rect, Shape};
pub use simulate::{
    simulate, simulate_session_alone, Dataset, SessionData, SimParams, SCAN_SOURCE_TAG,
};
pub use warehouse::WarehouseParams;
pub use world::{
    Door, DoorId, DoorKind, Obstacle, ObstacleId, ObstacleKind, Room, RoomId, RoomKind, World,
    DOOR_LEAF_THICKNESS_M,
};
