//! The lifelong store (issue 17; iRobot, Sec. 4 and 5.4): one SQLite file per site, opened by
//! one process at a time, holding map versions. This is its foundation: the file, its schema
//! version and migrations, the lock, the integrity check and the version list. The atlas's
//! state is not stored yet.
//!
//! Opening never modifies a store it refuses: a store from a newer schema, a corrupt file or a
//! store locked by another process is an error before anything is written.

mod error;
mod schema;
mod store;

pub use error::StoreError;
pub use schema::SCHEMA_VERSION;
pub use store::{Store, StoreInfo, VersionInfo};
