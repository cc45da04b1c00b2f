//! The one helper through which tests and benchmarks find the public datasets.
//!
//! The data folder is `$MAPMERGE_DATA`, else `../shared/data` beside the workspace. When it is
//! missing, [`shared_data`] prints why and returns `None` so the caller skips — except under
//! `CI=true`, where data tests must run and it panics instead.
//!
//! ```
//! if let Some(path) = mapmerge_testkit::shared_data("g2o/openslam_g2o/intel.g2o") {
//!     assert!(path.is_file());
//! }
//! ```

use std::path::PathBuf;

/// The data folder, or `None` (after printing why) when it is absent outside CI.
///
/// # Panics
/// Under `CI=true` when the folder is missing: CI must run the data tests.
pub fn shared_data_dir() -> Option<PathBuf> {
    let dir = std::env::var_os("MAPMERGE_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../../../../shared/data"
            ))
        });
    if dir.is_dir() {
        return Some(dir);
    }
    let why = format!(
        "data folder {} not found (set MAPMERGE_DATA)",
        dir.display()
    );
    #[allow(clippy::panic)]
    if std::env::var("CI").as_deref() == Ok("true") {
        panic!("{why}; under CI=true the data tests must run");
    }
    eprintln!("skipping: {why}");
    None
}

/// A file below the data folder, or `None` when the folder is absent outside CI.
///
/// # Panics
/// Under `CI=true` when the folder or the file is missing.
pub fn shared_data(relative: &str) -> Option<PathBuf> {
    let path = shared_data_dir()?.join(relative);
    #[allow(clippy::panic)]
    if !path.exists() {
        panic!("{} is missing from the data folder", path.display());
    }
    Some(path)
}

/// The program (or interpreter) an environment variable names, for tests that run a tool of
/// the field (evo, a Python with rosbags): `None` (after printing why) when the variable is
/// unset outside CI.
///
/// # Panics
/// Under `CI=true` when the variable is unset: `.ci/run` installs the tools and sets it.
pub fn tool_from_env(variable: &str, what: &str) -> Option<PathBuf> {
    if let Some(path) = std::env::var_os(variable) {
        return Some(PathBuf::from(path));
    }
    let why = format!("{variable} is unset ({what})");
    #[allow(clippy::panic)]
    if std::env::var("CI").as_deref() == Ok("true") {
        panic!("{why}; under CI=true it must be set (.ci/run installs the tool)");
    }
    eprintln!("skipping: {why}");
    None
}

/// The 13 public corrected CARMEN logs (`carmen/NAME-corrected.log.xz`), by name.
pub const PUBLIC_LOGS: [&str; 13] = [
    "acapulco",
    "aces",
    "belgioioso",
    "csail",
    "edmonton",
    "fhw",
    "freiburg-079",
    "freiburg-101",
    "freiburg-campus",
    "infinite-corridor",
    "intel",
    "orebro",
    "seattle",
];
