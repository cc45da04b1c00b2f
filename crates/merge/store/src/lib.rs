//! The lifelong store (iRobot, Sec. 4 and 5.4): one SQLite file per site, opened by one process
//! at a time, holding map versions. Each committed session is a version: the atlas's counters,
//! graphs, keyframes and backups (rows shared by the versions they are valid in), its events
//! and a summary ([`Store::commit_session`], [`Store::load`]). A version can be rolled back to;
//! the newest [`Store::keep_versions`] keep their atlas. The map manager's areas (Ehlers et
//! al.) are versioned beside the atlas ([`Store::commit_areas`], [`Store::load_areas`]): a
//! version of either keeps the other as its parent had it.
//!
//! Opening never modifies a store it refuses: a store from a newer schema, a corrupt file or a
//! store locked by another process is an error before anything is written.

mod area_rows;
mod atlas_rows;
mod error;
mod legacy;
mod schema;
mod store;

pub use area_rows::{AreasCommit, StoredAreas};
pub use atlas_rows::{SessionCommit, StoredAtlas};
pub use error::StoreError;
pub use schema::SCHEMA_VERSION;
pub use store::{
    store_files, Store, StoreInfo, VersionInfo, DEFAULT_KEEP_VERSIONS, RECLAIM_FROM_FRACTION,
};
