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
