//! Opening a store, its lock, its check and its versions.

use std::path::{Path, PathBuf};

use rusqlite::ffi::{SQLITE_CANTOPEN, SQLITE_READONLY_DIRECTORY};
use rusqlite::{Connection, ErrorCode, OpenFlags, OptionalExtension, TransactionBehavior};
use serde::{Deserialize, Serialize};

use crate::error::StoreError;
use crate::schema::{
    expected_objects, schema_objects, APPLICATION_ID, MIGRATIONS, SCHEMA_VERSION, VERSIONED_TABLES,
};

/// One map version (a committed session), as `mapmerge store versions --json` prints it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VersionInfo {
    /// Its number, from 1, increasing.
    pub version: i64,
    /// The version it continued (none for the first).
    pub parent: Option<i64>,
    /// The session's name (e.g. its log).
    pub session: String,
    /// When it was committed (Unix seconds).
    pub created: i64,
    /// Pose-graph vertices over every graph.
    pub nodes: i64,
    /// Pose-graph edges over every graph.
    pub edges: i64,
    /// Keyframes (views).
    pub keyframes: i64,
    /// Local maps.
    pub local_maps: i64,
    /// Area of the known cells of the rendered map (m²).
    pub mapped_area_m2: f64,
    /// Size of the store's database with this version committed (bytes).
    pub bytes: i64,
    /// Whether its atlas is still stored (older versions keep only this row; see
    /// [`Store::keep_versions`]).
    pub retained: bool,
    /// The map manager's areas (0: none stored).
    #[serde(default)]
    pub areas: i64,
    /// … and link points.
    #[serde(default)]
    pub link_points: i64,
}

/// What `mapmerge store info --json` prints about a store: its schema, how many versions it
/// has, and the newest version's counts (0 without versions).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StoreInfo {
    /// The store's schema version.
    pub schema_version: i64,
    /// Committed versions.
    pub versions: usize,
    /// The newest version's number (none without versions).
    pub newest_version: Option<i64>,
    /// The newest version's session.
    pub session: Option<String>,
    /// The newest version's pose-graph vertices.
    pub nodes: i64,
    /// … edges,
    pub edges: i64,
    /// … keyframes,
    pub keyframes: i64,
    /// … local maps …
    pub local_maps: i64,
    /// … mapped area (m²) …
    pub mapped_area_m2: f64,
    /// … areas …
    pub areas: i64,
    /// … and link points.
    pub link_points: i64,
    /// Size of the store's files on disk now (bytes).
    pub bytes: u64,
}

/// Versions whose atlas a store keeps by default (older ones keep their row in `versions`).
pub const DEFAULT_KEEP_VERSIONS: usize = 10;

/// Space holding no data (free pages and the unused bytes of pages in use) is reclaimed once
/// it is this fraction of the file ([`Store::reclaim`]). A freshly rewritten store has about
/// 2 % of it (B-tree pages are not full), so the file stays within about 8 % of its data.
pub const RECLAIM_FROM_FRACTION: f64 = 0.1;

/// An open store, held by this process until dropped.
pub struct Store {
    pub(crate) path: PathBuf,
    pub(crate) connection: Connection,
    pub(crate) keep_versions: usize,
}

impl std::fmt::Debug for Store {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Store")
            .field("path", &self.path)
            .finish_non_exhaustive()
    }
}

/// How a store is opened.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Access {
    /// For writing; a missing file becomes a new store.
    Create,
    /// For writing; the store must exist.
    Existing,
    /// For reading only: nothing is ever written, not even an upgrade.
    ReadOnly,
}

/// The files of the store at `path`: the database, its write-ahead log and the log's index
/// (SQLite's `-wal` and `-shm`, present while it is open or after a crash).
pub fn store_files(path: &Path) -> [PathBuf; 3] {
    ["", "-wal", "-shm"].map(|suffix| {
        let mut name = path.as_os_str().to_owned();
        name.push(suffix);
        PathBuf::from(name)
    })
}

impl Store {
    /// Opens the store at `path` for writing, creating it when there is no file, and upgrades
    /// an older schema. A store is checked ([`Store::check`]) before anything is written to
    /// it; refused stores (locked, newer, not a store, corrupt) are not modified.
    pub fn open(path: &Path) -> Result<Self, StoreError> {
        Self::open_with(path, Access::Create)
    }

    /// Opens an existing store for writing, as [`Store::open`]; a missing or empty file is an
    /// error.
    pub fn open_existing(path: &Path) -> Result<Self, StoreError> {
        Self::open_with(path, Access::Existing)
    }

    /// Opens an existing store for reading only (its file may be read-only): every write
    /// fails, and a store of an older schema is refused rather than upgraded.
    pub fn open_read_only(path: &Path) -> Result<Self, StoreError> {
        Self::open_with(path, Access::ReadOnly)
    }

    fn open_with(path: &Path, access: Access) -> Result<Self, StoreError> {
        let mut flags = OpenFlags::SQLITE_OPEN_NO_MUTEX;
        flags |= match access {
            Access::Create => OpenFlags::SQLITE_OPEN_READ_WRITE | OpenFlags::SQLITE_OPEN_CREATE,
            Access::Existing => OpenFlags::SQLITE_OPEN_READ_WRITE,
            Access::ReadOnly => OpenFlags::SQLITE_OPEN_READ_ONLY,
        };
        let classify = |e: rusqlite::Error| classify(path, e);
        let mut connection = Connection::open_with_flags(path, flags).map_err(classify)?;
        // One writer at a time: its first access takes the file's lock and keeps it until
        // the connection closes (no waiting for a busy store). A reader is refused while a
        // writer holds it.
        connection
            .busy_timeout(std::time::Duration::ZERO)
            .map_err(classify)?;
        if access != Access::ReadOnly {
            connection
                .pragma_update(None, "locking_mode", "EXCLUSIVE")
                .map_err(classify)?;
        }
        let behavior = match access {
            Access::ReadOnly => TransactionBehavior::Deferred,
            Access::Create | Access::Existing => TransactionBehavior::Exclusive,
        };
        let header = match read_header(&mut connection, behavior) {
            // A reader that cannot create the write-ahead log's files beside the store (a
            // directory it may not write) reads the file as it is on disk: nothing can be
            // coordinated with a writer there.
            Err(e)
                if access == Access::ReadOnly
                    && matches!(
                        e.sqlite_error().map(|e| e.extended_code),
                        Some(SQLITE_READONLY_DIRECTORY | SQLITE_CANTOPEN)
                    ) =>
            {
                drop(connection);
                connection = Connection::open_with_flags(
                    immutable_uri(path),
                    flags | OpenFlags::SQLITE_OPEN_URI,
                )
                .map_err(classify)?;
                read_header(&mut connection, behavior)
            }
            other => other,
        };
        let (application_id, schema_version, tables) = header.map_err(classify)?;
        let transaction = connection
            .transaction_with_behavior(behavior)
            .map_err(classify)?;
        let fresh = application_id == 0 && schema_version == 0 && tables == 0;
        if fresh && access != Access::Create {
            return Err(StoreError::NotAStore {
                path: path.to_path_buf(),
                reason: "an empty file".into(),
            });
        }
        if !fresh && application_id != APPLICATION_ID {
            return Err(StoreError::NotAStore {
                path: path.to_path_buf(),
                reason: format!("application id {application_id:#x}, {tables} schema objects"),
            });
        }
        if schema_version < 0 {
            return Err(StoreError::Corrupt {
                path: path.to_path_buf(),
                reason: format!("schema version {schema_version}"),
            });
        }
        if schema_version > SCHEMA_VERSION {
            return Err(StoreError::NewerSchema {
                path: path.to_path_buf(),
                found: schema_version,
                supported: SCHEMA_VERSION,
            });
        }
        if access == Access::ReadOnly && schema_version < SCHEMA_VERSION {
            return Err(StoreError::OlderSchema {
                path: path.to_path_buf(),
                found: schema_version,
                supported: SCHEMA_VERSION,
            });
        }
        // An older store's file and schema are checked before its upgrade writes to it.
        if !fresh && schema_version < SCHEMA_VERSION {
            check_file(&transaction, path, schema_version)?;
        }
        transaction.rollback().map_err(classify)?;
        let store = Self {
            path: path.to_path_buf(),
            connection,
            keep_versions: DEFAULT_KEEP_VERSIONS,
        };
        if access == Access::ReadOnly {
            return Ok(store);
        }
        // A current store is checked whole before anything is written to it.
        if !fresh && schema_version == SCHEMA_VERSION {
            store.check()?;
        }
        // Accepted: from here on the store may be written.
        store
            .connection
            .pragma_update(None, "journal_mode", "WAL")
            .map_err(classify)?;
        store
            .connection
            .pragma_update(None, "foreign_keys", true)
            .map_err(classify)?;
        if schema_version < SCHEMA_VERSION {
            // The upgrade is committed only once the upgraded store passes the check.
            let transaction = store.connection.unchecked_transaction().map_err(classify)?;
            let from = usize::try_from(schema_version).unwrap_or(0);
            for migration in MIGRATIONS.iter().skip(from) {
                transaction.execute_batch(migration.sql).map_err(classify)?;
                if let Some(step) = migration.then {
                    step(&transaction).map_err(classify)?;
                }
            }
            transaction
                .pragma_update(None, "application_id", APPLICATION_ID)
                .map_err(classify)?;
            transaction
                .pragma_update(None, "user_version", SCHEMA_VERSION)
                .map_err(classify)?;
            if !fresh {
                store.check()?;
            }
            transaction.commit().map_err(classify)?;
        }
        store
            .connection
            .pragma_update(None, "synchronous", "FULL")
            .map_err(classify)?;
        Ok(store)
    }

    /// The store's file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// `version`, or the newest version's number when none is given (`None` without
    /// versions).
    pub(crate) fn given_or_newest(&self, version: Option<i64>) -> Result<Option<i64>, StoreError> {
        if version.is_some() {
            return Ok(version);
        }
        self.connection
            .query_row("SELECT max(version) FROM versions", [], |row| row.get(0))
            .map_err(|e| classify(&self.path, e))
    }

    /// Every committed version, oldest first.
    pub fn versions(&self) -> Result<Vec<VersionInfo>, StoreError> {
        let classify = |e: rusqlite::Error| classify(&self.path, e);
        let mut statement = self
            .connection
            .prepare(
                "SELECT version, parent, session, created_unix_s, nodes, edges, keyframes,
                        local_maps, mapped_area_m2, bytes, retained, areas, link_points
                 FROM versions ORDER BY version",
            )
            .map_err(classify)?;
        let rows = statement
            .query_map([], |row| {
                Ok(VersionInfo {
                    version: row.get(0)?,
                    parent: row.get(1)?,
                    session: row.get(2)?,
                    created: row.get(3)?,
                    nodes: row.get(4)?,
                    edges: row.get(5)?,
                    keyframes: row.get(6)?,
                    local_maps: row.get(7)?,
                    mapped_area_m2: row.get(8)?,
                    bytes: row.get(9)?,
                    retained: row.get(10)?,
                    areas: row.get(11)?,
                    link_points: row.get(12)?,
                })
            })
            .map_err(classify)?;
        rows.collect::<Result<Vec<_>, _>>().map_err(classify)
    }

    /// The store's schema version, versions and size.
    pub fn info(&self) -> Result<StoreInfo, StoreError> {
        let versions = self.versions()?;
        // The database and its write-ahead log (the log's index holds no data).
        let [database, log, _] = store_files(&self.path);
        let bytes = [database, log]
            .iter()
            .filter_map(|file| std::fs::metadata(file).ok())
            .map(|m| m.len())
            .sum();
        let newest = versions.last();
        Ok(StoreInfo {
            schema_version: SCHEMA_VERSION,
            versions: versions.len(),
            newest_version: newest.map(|v| v.version),
            session: newest.map(|v| v.session.clone()),
            nodes: newest.map_or(0, |v| v.nodes),
            edges: newest.map_or(0, |v| v.edges),
            keyframes: newest.map_or(0, |v| v.keyframes),
            local_maps: newest.map_or(0, |v| v.local_maps),
            mapped_area_m2: newest.map_or(0.0, |v| v.mapped_area_m2),
            areas: newest.map_or(0, |v| v.areas),
            link_points: newest.map_or(0, |v| v.link_points),
            bytes,
        })
    }

    /// How many of the newest versions keep their atlas. A commit forgets the atlas of older
    /// versions: their rows in `versions` stay, rows no retained version sees are deleted,
    /// and their events go with them. Default [`DEFAULT_KEEP_VERSIONS`].
    pub fn keep_versions(&mut self, keep: std::num::NonZeroUsize) {
        self.keep_versions = keep.get();
    }

    /// Deletes every version after `version` (iRobot deletes bad versions) with the rows and
    /// events they added, and makes valid again what they removed. `version` must be stored
    /// and retained. Returns how many versions were deleted.
    pub fn rollback_to(&mut self, version: i64) -> Result<usize, StoreError> {
        let path = self.path.clone();
        let classify = |e: rusqlite::Error| classify(&path, e);
        let transaction = self
            .connection
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .map_err(classify)?;
        require_retained(&transaction, &path, version)?;
        for table in VERSIONED_TABLES {
            transaction
                .execute(
                    &format!(
                        "UPDATE {table} SET removed_version = NULL WHERE removed_version > ?1"
                    ),
                    [version],
                )
                .map_err(classify)?;
            transaction
                .execute(
                    &format!("DELETE FROM {table} WHERE added_version > ?1"),
                    [version],
                )
                .map_err(classify)?;
        }
        for table in ["events", "atlas_state"] {
            transaction
                .execute(
                    &format!("DELETE FROM {table} WHERE version > ?1"),
                    [version],
                )
                .map_err(classify)?;
        }
        // One statement: foreign keys are checked when it ends, children gone with parents.
        let deleted = transaction
            .execute("DELETE FROM versions WHERE version > ?1", [version])
            .map_err(classify)?;
        transaction.commit().map_err(classify)?;
        self.checkpoint()?;
        self.reclaim()?;
        Ok(deleted)
    }

    /// Moves the write-ahead log into the database file and empties it, so the file alone
    /// holds every committed version (and its size is the store's).
    pub(crate) fn checkpoint(&self) -> Result<(), StoreError> {
        self.connection
            .query_row("PRAGMA wal_checkpoint(TRUNCATE)", [], |_| Ok(()))
            .map_err(|e| classify(&self.path, e))
    }

    /// Reclaims the space that holds no data (SQLite's `VACUUM`) once it is at least
    /// [`RECLAIM_FROM_FRACTION`] of the file. Versions beyond [`Store::keep_versions`] and
    /// pruned views leave pages free, and rows deleted from pages still in use leave them part
    /// empty; SQLite reuses both but never returns them. Then the newest version's recorded
    /// size is the file's again. Returns the bytes reclaimed.
    pub(crate) fn reclaim(&self) -> Result<i64, StoreError> {
        let classify = |e: rusqlite::Error| classify(&self.path, e);
        let bytes = |sql: &str| -> Result<i64, StoreError> {
            self.connection
                .query_row(sql, [], |row| row.get(0))
                .map_err(classify)
        };
        let size = "SELECT page_count * page_size FROM pragma_page_count, pragma_page_size";
        let before = bytes(size)?;
        // `dbstat` lists the pages in use, not the free ones. Every table and index keeps
        // one page however little it holds, so a page each is not counted as reclaimable.
        let kept = bytes(
            "SELECT COALESCE(SUM(pgsize - unused), 0)
                  + COUNT(DISTINCT name) * (SELECT page_size FROM pragma_page_size)
             FROM dbstat",
        )?;
        if before <= 0 || ((before - kept) as f64) < RECLAIM_FROM_FRACTION * before as f64 {
            return Ok(0);
        }
        self.connection.execute_batch("VACUUM").map_err(classify)?;
        self.checkpoint()?;
        let after = bytes(size)?;
        self.connection
            .execute(
                "UPDATE versions SET bytes = ?1 WHERE version = (SELECT MAX(version) FROM versions)",
                [after],
            )
            .map_err(classify)?;
        self.checkpoint()?;
        Ok(before - after)
    }

    /// `Ok` when the store is intact: SQLite's integrity and foreign-key checks pass, every
    /// table and index of the schema is there, every version's parent is the version before it, every retained version has its atlas,
    /// every stored graph, backup, keyframe and counter decodes, and the newest version's
    /// atlas is consistent.
    pub fn check(&self) -> Result<(), StoreError> {
        let corrupt = |reason: String| StoreError::Corrupt {
            path: self.path.clone(),
            reason,
        };
        check_file(&self.connection, &self.path, SCHEMA_VERSION)?;
        let mut expected_parent = None;
        let versions = self.versions()?;
        for v in &versions {
            if v.parent != expected_parent {
                return Err(corrupt(format!(
                    "version {} continues {:?}, expected {:?}",
                    v.version, v.parent, expected_parent
                )));
            }
            expected_parent = Some(v.version);
        }
        self.check_rows(&versions)
    }
}

/// The file half of [`Store::check`] on a store of schema `schema_version`: SQLite's
/// integrity and foreign-key checks, and every table and index of that schema present.
fn check_file(connection: &Connection, path: &Path, schema_version: i64) -> Result<(), StoreError> {
    let classify = |e: rusqlite::Error| classify(path, e);
    let corrupt = |reason: String| StoreError::Corrupt {
        path: path.to_path_buf(),
        reason,
    };
    let integrity: String = connection
        .pragma_query_value(None, "integrity_check", |row| row.get(0))
        .map_err(classify)?;
    if integrity != "ok" {
        return Err(corrupt(integrity));
    }
    let dangling: i64 = connection
        .query_row("SELECT count(*) FROM pragma_foreign_key_check", [], |row| {
            row.get(0)
        })
        .map_err(classify)?;
    if dangling > 0 {
        return Err(corrupt(format!("{dangling} rows refer to missing rows")));
    }
    let present = schema_objects(connection).map_err(classify)?;
    let expected = expected_objects(schema_version).map_err(classify)?;
    // Tables before their indexes.
    let mut missing: Vec<&String> = expected.difference(&present).collect();
    missing.sort_by_key(|name| !name.starts_with("table"));
    if let Some(missing) = missing.first() {
        return Err(corrupt(format!("{missing} is missing")));
    }
    Ok(())
}

/// The store's application id, schema version and number of schema objects (the first
/// access, which takes the lock).
fn read_header(
    connection: &mut Connection,
    behavior: TransactionBehavior,
) -> rusqlite::Result<(i64, i64, i64)> {
    let transaction = connection.transaction_with_behavior(behavior)?;
    let application_id =
        transaction.pragma_query_value(None, "application_id", |row| row.get(0))?;
    let schema_version = transaction.pragma_query_value(None, "user_version", |row| row.get(0))?;
    let tables =
        transaction.query_row("SELECT count(*) FROM sqlite_schema", [], |row| row.get(0))?;
    transaction.rollback()?;
    Ok((application_id, schema_version, tables))
}

/// `path` as an SQLite URI that opens it immutable (read as it is, no locks, no log files).
fn immutable_uri(path: &Path) -> String {
    let mut uri = String::from("file:");
    for c in path.to_string_lossy().chars() {
        match c {
            '%' => uri.push_str("%25"),
            '?' => uri.push_str("%3f"),
            '#' => uri.push_str("%23"),
            c => uri.push(c),
        }
    }
    uri.push_str("?immutable=1");
    uri
}

/// `Ok` when `version` is stored and keeps its atlas; else which of the two it is not.
pub(crate) fn require_retained(
    connection: &Connection,
    path: &Path,
    version: i64,
) -> Result<(), StoreError> {
    let retained: Option<bool> = connection
        .query_row(
            "SELECT retained FROM versions WHERE version = ?1",
            [version],
            |row| row.get(0),
        )
        .optional()
        .map_err(|e| classify(path, e))?;
    let path = path.to_path_buf();
    match retained {
        None => Err(StoreError::NoSuchVersion { path, version }),
        Some(false) => Err(StoreError::NotRetained { path, version }),
        Some(true) => Ok(()),
    }
}

/// SQLite's error as the store's: busy is a lock, "not a database" and corruption are named.
pub(crate) fn classify(path: &Path, error: rusqlite::Error) -> StoreError {
    let path = path.to_path_buf();
    match error.sqlite_error_code() {
        Some(ErrorCode::DatabaseBusy | ErrorCode::DatabaseLocked) => StoreError::Locked { path },
        Some(ErrorCode::NotADatabase) => StoreError::NotAStore {
            path,
            reason: error.to_string(),
        },
        Some(ErrorCode::DatabaseCorrupt) => StoreError::Corrupt {
            path,
            reason: error.to_string(),
        },
        _ => StoreError::Sqlite {
            path,
            source: error,
        },
    }
}
