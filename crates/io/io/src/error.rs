//! The one error type of this crate.

/// What can go wrong when reading or writing a file. Every variant names the file (or the
/// `source` string given to a `parse_*` function).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum IoError {
    /// A line of a text file is malformed (or, for a PGM, a header token); `line` is 1-based.
    #[error("{file}:{line}: {reason}")]
    Parse {
        /// The file (or source name) being parsed.
        file: String,
        /// 1-based line number of the offending line.
        line: usize,
        /// What is wrong with that line.
        reason: String,
    },
    /// The operating system refused a read or a write (or xz data is corrupt).
    #[error("{file}: cannot read or write the file")]
    Io {
        /// The file being read or written.
        file: String,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A file is malformed as a whole, not at one line: a missing YAML key, PGM pixel data
    /// shorter than its header says, a map whose pixels do not fill it.
    #[error("{file}: {reason}")]
    Invalid {
        /// The file (or source name).
        file: String,
        /// What is wrong.
        reason: String,
    },
    /// The text holds no vertex, edge or fix line at all.
    #[error("{file}: no vertex or edge lines (empty graph file)")]
    Empty {
        /// The file (or source name) being parsed.
        file: String,
    },
    /// The data holds something the chosen output format cannot express (a prior edge in
    /// TORO, a non-finite number, a map whose pixels do not match its size).
    #[error("cannot write the data as {format}: {reason}")]
    Unwritable {
        /// The requested output format (`"g2o"`, `"TORO"`, `"TUM"`, `"CARMEN"`, `"PGM"`,
        /// `"map_server YAML"`).
        format: &'static str,
        /// What cannot be written.
        reason: String,
    },
}
