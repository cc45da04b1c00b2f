//! The atlas's errors.

use std::path::PathBuf;

use mapmerge_posegraph::{GraphError, NodeId};

use crate::ids::{EpochId, MapId, MergeId};

/// What can go wrong in the atlas. Every failing operation leaves the atlas as it was.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AtlasError {
    /// The parameters are invalid.
    #[error("invalid parameters: {0}")]
    Config(String),
    /// A keyframe insertion was refused.
    #[error("keyframe {node}: {reason}")]
    BadKeyframe {
        /// The keyframe's node.
        node: NodeId,
        /// Why.
        reason: String,
    },
    /// A graph edit failed (duplicate or missing id, malformed edge).
    #[error("graph edit failed: {0}")]
    Graph(#[from] GraphError),
    /// The optimiser refused the problem (invalid parameters, malformed graph).
    #[error("re-optimisation failed: {0}")]
    Solve(#[from] mapmerge_solve::SolveError),
    /// No inactive graph with this id.
    #[error("no inactive {0}")]
    MissingMap(MapId),
    /// The vertex is in no graph of the atlas (or not in the graph the call needs).
    #[error("vertex {node} is not in the {graph} graph")]
    MissingVertex {
        /// The vertex.
        node: NodeId,
        /// Which graph was looked in ("active", "inactive", "any").
        graph: &'static str,
    },
    /// A merge needs the robot's current pose: the active graph has no vertex yet.
    #[error("the active graph of {0} has no vertex yet")]
    EmptyActive(EpochId),
    /// A merge request is malformed (no edge joins the two graphs, non-finite transform, ...).
    #[error("bad merge request into {map}: {reason}")]
    BadMerge {
        /// The inactive graph to merge.
        map: MapId,
        /// What is wrong.
        reason: String,
    },
    /// Pruning would touch other-epoch data while a merge can still be undone
    /// (Holoch et al., Sec. III-B).
    #[error("vertex {node} of {epoch} cannot be pruned while merges into the active graph can be undone")]
    PruneRefused {
        /// The vertex.
        node: NodeId,
        /// Its epoch.
        epoch: EpochId,
    },
    /// A snapshot to restore is inconsistent.
    #[error("inconsistent atlas snapshot: {0}")]
    BadSnapshot(String),
    /// A backup is missing from the store.
    #[error("no backup of {0}")]
    MissingBackup(MergeId),
    /// Reading or writing a backup or an event log failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// A backup file could not be encoded or decoded.
    #[error("{path}: backup encoding: {source}")]
    Encoding {
        /// The file.
        path: PathBuf,
        /// The error.
        source: postcard::Error,
    },
    /// An event could not be written or parsed.
    #[error("event log line {line}: {source}")]
    Event {
        /// 1-based line number (0 when writing).
        line: usize,
        /// The error.
        source: serde_json::Error,
    },
}
