//! The one error type of this crate.

/// What can go wrong when reading or writing a file. Every variant names the file (or the
/// `source` string given to [`crate::parse_graph`]).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum IoError {
    /// The text is not a valid graph; `line` is 1-based.
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
    /// The text holds no vertex, edge or fix line at all.
    #[error("{file}: no vertex or edge lines (empty graph file)")]
    Empty {
        /// The file (or source name) being parsed.
        file: String,
    },
    /// The graph holds something the chosen output format cannot express (a prior edge in
    /// TORO, a non-finite number).
    #[error("cannot write the graph as {format}: {reason}")]
    Unwritable {
        /// The requested output format (`"g2o"`, `"TORO"`, `"TUM"`).
        format: &'static str,
        /// What cannot be written.
        reason: String,
    },
}
