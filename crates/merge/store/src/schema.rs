//! The schema and its migrations (docs/formats.md, "The lifelong store").
//!
//! A store is a SQLite file whose `PRAGMA application_id` is [`APPLICATION_ID`] and whose
//! `PRAGMA user_version` is its schema version. `MIGRATIONS[k]` takes a store from schema
//! version `k` to `k + 1` (version 0 is the empty file): its SQL, then its step in Rust for
//! what SQL cannot do (re-encoding blobs whose type grew). Every migration runs in the
//! transaction that opens the store, so an upgrade is all or nothing.

use std::collections::BTreeSet;

use rusqlite::{Connection, Transaction};

/// One migration: SQL, then an optional step in Rust.
pub(crate) struct Migration {
    pub(crate) sql: &'static str,
    pub(crate) then: Option<fn(&Transaction<'_>) -> rusqlite::Result<()>>,
}

/// "mmrg": marks a SQLite file as a mapmerge store.
pub const APPLICATION_ID: i64 = 0x6d6d_7267;

/// The newest schema this build reads and writes.
pub const SCHEMA_VERSION: i64 = MIGRATIONS.len() as i64;

/// The migrations, oldest first (see the module documentation).
pub(crate) const MIGRATIONS: [Migration; 4] = [
    // 0 → 1: map versions, one per committed session.
    Migration {
        sql: "CREATE TABLE versions (
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
        then: None,
    },
    // 1 → 2: the atlas itself. Every blob has the CRC-32 of its bytes beside it. Rows of
    // graphs, keyframes and backups are shared by the versions they are valid in: version v
    // sees a row when added_version <= v < removed_version (no removed_version: still valid).
    Migration {
        sql: "ALTER TABLE versions ADD COLUMN retained INTEGER NOT NULL DEFAULT 1;
     CREATE TABLE atlas_state (
         version INTEGER PRIMARY KEY REFERENCES versions(version),
         counters BLOB NOT NULL,
         checksum INTEGER NOT NULL
     ) STRICT;
     CREATE TABLE graphs (
         id INTEGER PRIMARY KEY,
         slot INTEGER NOT NULL,
         added_version INTEGER NOT NULL REFERENCES versions(version),
         removed_version INTEGER REFERENCES versions(version),
         body BLOB NOT NULL,
         checksum INTEGER NOT NULL
     ) STRICT;
     CREATE INDEX graphs_by_validity ON graphs(removed_version, added_version);
     CREATE TABLE keyframes (
         node INTEGER PRIMARY KEY,
         added_version INTEGER NOT NULL REFERENCES versions(version),
         removed_version INTEGER REFERENCES versions(version),
         travel_m REAL NOT NULL,
         local_x_m REAL NOT NULL,
         local_y_m REAL NOT NULL,
         local_yaw_rad REAL NOT NULL,
         submap INTEGER,
         reference_x_m REAL,
         reference_y_m REAL,
         reference_yaw_rad REAL,
         points BLOB NOT NULL,
         checksum INTEGER NOT NULL
     ) STRICT;
     CREATE INDEX keyframes_by_validity ON keyframes(removed_version, added_version);
     CREATE TABLE backups (
         merge INTEGER PRIMARY KEY,
         added_version INTEGER NOT NULL REFERENCES versions(version),
         removed_version INTEGER REFERENCES versions(version),
         body BLOB NOT NULL,
         checksum INTEGER NOT NULL
     ) STRICT;
     CREATE TABLE events (
         seq INTEGER PRIMARY KEY,
         version INTEGER NOT NULL REFERENCES versions(version),
         body TEXT NOT NULL
     ) STRICT;
     CREATE INDEX events_by_version ON events(version);",
        then: None,
    },
    // 2 → 3: local maps (iRobot Sec. 3.3), one per anchor vertex (a new row when it is
    // edited), postcard `LocalMapGrid` bodies; the counters gain the maintenance sessions,
    // the views' use and the recent sessions' first vertices.
    Migration {
        sql: "CREATE TABLE local_maps (
         id INTEGER PRIMARY KEY,
         anchor INTEGER NOT NULL,
         added_version INTEGER NOT NULL REFERENCES versions(version),
         removed_version INTEGER REFERENCES versions(version),
         body BLOB NOT NULL,
         checksum INTEGER NOT NULL
     ) STRICT;
     CREATE INDEX local_maps_by_validity ON local_maps(removed_version, added_version);",
        then: Some(crate::legacy::counters_2_to_3),
    },
    // 3 → 4: the map manager's areas (Ehlers et al.): each session as mapped (postcard
    // `MappedSession`, by its index) and the managed map built from them (one slot), shared
    // between versions like the atlas's rows. Versions count their areas and link points.
    Migration {
        sql: "ALTER TABLE versions ADD COLUMN areas INTEGER NOT NULL DEFAULT 0;
     ALTER TABLE versions ADD COLUMN link_points INTEGER NOT NULL DEFAULT 0;
     CREATE TABLE area_sessions (
         session INTEGER PRIMARY KEY,
         added_version INTEGER NOT NULL REFERENCES versions(version),
         removed_version INTEGER REFERENCES versions(version),
         body BLOB NOT NULL,
         checksum INTEGER NOT NULL
     ) STRICT;
     CREATE INDEX area_sessions_by_validity ON area_sessions(removed_version, added_version);
     CREATE TABLE area_maps (
         id INTEGER PRIMARY KEY,
         slot INTEGER NOT NULL,
         added_version INTEGER NOT NULL REFERENCES versions(version),
         removed_version INTEGER REFERENCES versions(version),
         body BLOB NOT NULL,
         checksum INTEGER NOT NULL
     ) STRICT;
     CREATE INDEX area_maps_by_validity ON area_maps(removed_version, added_version);",
        then: None,
    },
];

/// The slot of the active graph in `graphs` (an inactive graph's slot is its map id).
pub(crate) const ACTIVE_SLOT: i64 = -1;

/// The tables whose rows carry `added_version` and `removed_version`.
pub(crate) const VERSIONED_TABLES: [&str; 6] = [
    "graphs",
    "keyframes",
    "backups",
    "local_maps",
    "area_sessions",
    "area_maps",
];

/// The tables and indexes of `connection`'s schema, as `"table events"`, `"index …"`.
pub(crate) fn schema_objects(connection: &Connection) -> rusqlite::Result<BTreeSet<String>> {
    let mut statement = connection.prepare(
        "SELECT type || ' ' || name FROM sqlite_schema
         WHERE type IN ('table', 'index') AND name NOT LIKE 'sqlite_%'",
    )?;
    let names = statement.query_map([], |row| row.get(0))?;
    names.collect()
}

/// The tables and indexes a store of schema `version` has: the first `version` migrations
/// applied to an empty database in memory.
pub(crate) fn expected_objects(version: i64) -> rusqlite::Result<BTreeSet<String>> {
    let mut connection = Connection::open_in_memory()?;
    let transaction = connection.transaction()?;
    let count = usize::try_from(version).unwrap_or(0);
    for migration in MIGRATIONS.iter().take(count) {
        transaction.execute_batch(migration.sql)?;
        if let Some(step) = migration.then {
            step(&transaction)?;
        }
    }
    schema_objects(&transaction)
}
