//! The one error type of the jobs: the CLI's message and its exit code.

use std::error::Error;
use std::fmt::Display;

/// Why a job failed. The message is exactly what `mapmerge` prints after `mapmerge: error: `
/// (a cause chain joined by `": "`, as `anyhow`'s `{:#}` prints it); the variant is the exit
/// code it maps to.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum JobError {
    /// Unreadable or malformed input, bad arguments (exit code 2).
    #[error("{0}")]
    BadInput(String),
    /// Any other failure (exit code 1): an initialisation or a solver that gave up.
    #[error("{0}")]
    Failed(String),
}

impl JobError {
    /// Bad input with `reason` as the whole message.
    pub fn bad_input(reason: impl Display) -> Self {
        Self::BadInput(reason.to_string())
    }

    /// Bad input from a reader's error, its cause chain kept in the text (the CLI's
    /// `bad_file`).
    pub fn bad_file(err: &dyn Error) -> Self {
        Self::BadInput(error_chain(err))
    }

    /// A failure with its cause chain.
    pub fn failed(err: &dyn Error) -> Self {
        Self::Failed(error_chain(err))
    }

    /// A failure described by `context`, then the cause chain of `err` (`anyhow`'s
    /// `.context(…)` printed with `{:#}`).
    pub fn context(context: impl Display, err: &dyn Error) -> Self {
        Self::Failed(format!("{context}: {}", error_chain(err)))
    }

    /// A failure to write `path` (or create it, for a folder), with the cause chain of `err`:
    /// the user's output path, so bad input (exit code 2).
    pub fn writing(path: &std::path::Path, err: &dyn Error) -> Self {
        Self::BadInput(format!("writing {}: {}", path.display(), error_chain(err)))
    }

    /// The CLI's exit code: 2 for bad input, 1 otherwise.
    pub fn exit_code(&self) -> u8 {
        match self {
            Self::BadInput(_) => 2,
            Self::Failed(_) => 1,
        }
    }

    /// The message alone.
    pub fn message(&self) -> &str {
        match self {
            Self::BadInput(m) | Self::Failed(m) => m,
        }
    }
}

/// `err`, then each of its sources, joined by `": "`.
pub fn error_chain(err: &dyn Error) -> String {
    let mut message = err.to_string();
    let mut source = err.source();
    while let Some(cause) = source {
        message.push_str(&format!(": {cause}"));
        source = cause.source();
    }
    message
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, thiserror::Error)]
    #[error("outer")]
    struct Outer(#[source] std::io::Error);

    #[test]
    fn the_chain_joins_every_cause_as_anyhow_prints_it() {
        let err = Outer(std::io::Error::other("inner"));
        assert_eq!(error_chain(&err), "outer: inner");
        assert_eq!(
            JobError::context("writing x", &err),
            JobError::Failed("writing x: outer: inner".into())
        );
        assert_eq!(JobError::bad_file(&err).exit_code(), 2);
        assert_eq!(JobError::failed(&err).exit_code(), 1);
        assert_eq!(JobError::bad_input("no").to_string(), "no");
    }
}
