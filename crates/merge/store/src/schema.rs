//! The schema and its migrations (docs/formats.md, "The lifelong store").
//!
//! A store is a SQLite file whose `PRAGMA application_id` is [`APPLICATION_ID`] and whose
//! `PRAGMA user_version` is its schema version. `MIGRATIONS[k]` takes a store from schema
//! version `k` to `k + 1` (version 0 is the empty file); every migration runs in the
//! transaction that opens the store, so an upgrade is all or nothing.

/// "mmrg": marks a SQLite file as a mapmerge store.
pub const APPLICATION_ID: i64 = 0x6d6d_7267;

/// The newest schema this build reads and writes.
pub const SCHEMA_VERSION: i64 = MIGRATIONS.len() as i64;

/// The migrations, oldest first (see the module documentation).
pub(crate) const MIGRATIONS: [&str; 1] = [
    // 0 → 1: map versions, one per committed session.
    "CREATE TABLE versions (
         version INTEGER PRIMARY KEY,
         parent INTEGER REFERENCES versions(version),
         session TEXT NOT NULL,
         created_unix_s INTEGER NOT NULL,
         nodes INTEGER NOT NULL,
         edges INTEGER NOT NULL,
         keyframes INTEGER NOT NULL,
         local_maps INTEGER NOT NULL,
         mapped_area_m2 REAL NOT NULL,
         bytes INTEGER NOT NULL
     ) STRICT;",
];
