//! Errors of the store. Each names the file and says what is wrong with it.

use std::path::PathBuf;

/// Why a store could not be opened, read or written.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// Another process holds the store.
    #[error("{path}: the store is in use by another process")]
    Locked {
        /// The store.
        path: PathBuf,
    },
    /// The store was written by a newer mapmerge; it is left untouched.
    #[error("{path}: schema version {found} is newer than this build's {supported}; upgrade mapmerge to open it")]
    NewerSchema {
        /// The store.
        path: PathBuf,
        /// Its schema version.
        found: i64,
        /// The newest this build knows.
        supported: i64,
    },
    /// The store was written by an older mapmerge and a read-only command cannot upgrade it.
    #[error("{path}: schema version {found} is older than this build's {supported}; a command that writes to the store (atlas --store, areas --store, store rollback) upgrades it")]
    OlderSchema {
        /// The store.
        path: PathBuf,
        /// Its schema version.
        found: i64,
        /// The newest this build knows.
        supported: i64,
    },
    /// The file is not a mapmerge store (another SQLite database, or not SQLite at all).
    #[error("{path}: not a mapmerge store ({reason})")]
    NotAStore {
        /// The file.
        path: PathBuf,
        /// What was found instead.
        reason: String,
    },
    /// The file is damaged.
    #[error("{path}: the store is corrupt: {reason}")]
    Corrupt {
        /// The store.
        path: PathBuf,
        /// SQLite's report.
        reason: String,
    },
    /// A version that is not in the store.
    #[error("{path}: no version {version}")]
    NoSuchVersion {
        /// The store.
        path: PathBuf,
        /// The version asked for.
        version: i64,
    },
    /// A version whose atlas is no longer kept (only its row in `versions` is).
    #[error("{path}: version {version} is no longer retained (only its summary is kept)")]
    NotRetained {
        /// The store.
        path: PathBuf,
        /// The version asked for.
        version: i64,
    },
    /// A retained version has no atlas (it was written by schema 1, which stored none).
    #[error("{path}: version {version} holds no atlas")]
    NoAtlas {
        /// The store.
        path: PathBuf,
        /// The version.
        version: i64,
    },
    /// An atlas to commit is inconsistent; nothing was written.
    #[error("{path}: refusing to commit an inconsistent atlas: {reason}")]
    BadAtlas {
        /// The store.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Areas to commit do not fit their sessions; nothing was written.
    #[error("{path}: refusing to commit areas that do not fit their sessions: {reason}")]
    BadAreas {
        /// The store.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Any other SQLite failure.
    #[error("{path}: {source}")]
    Sqlite {
        /// The store.
        path: PathBuf,
        /// SQLite's error.
        #[source]
        source: rusqlite::Error,
    },
}
