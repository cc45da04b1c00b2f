//! Typed ids of the atlas: epochs, inactive maps, merges.

use mapmerge_posegraph::{SessionId, VertexMeta};
use serde::{Deserialize, Serialize};

/// An epoch: one stretch of uninterrupted localisation (Holoch et al., Sec. III: "an epoch
/// ends whenever incremental localization methods get disrupted").
///
/// Stamped on every vertex as [`VertexMeta::session`]: in the atlas a vertex's `SessionId` *is*
/// its epoch id (`SessionId(e.0)`), so `mapmerge-posegraph` is unchanged and every graph
/// written by the atlas (g2o, pictures coloured by session) shows the epochs. A log that is
/// cut by kidnaps spans several epochs.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize,
)]
#[serde(transparent)]
pub struct EpochId(pub u32);

impl EpochId {
    /// The session id that stamps this epoch on a vertex.
    pub fn session(self) -> SessionId {
        SessionId(self.0)
    }

    /// The epoch stamped on a vertex.
    pub fn of(meta: &VertexMeta) -> Self {
        Self(meta.session.0)
    }
}

impl From<EpochId> for SessionId {
    fn from(epoch: EpochId) -> Self {
        epoch.session()
    }
}

impl std::fmt::Display for EpochId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "epoch {}", self.0)
    }
}

/// An inactive graph `G_I` of the atlas. It keeps its id while it is merged into the active
/// graph, so an unmerge puts it back under the same id.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct MapId(pub u32);

impl std::fmt::Display for MapId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "map {}", self.0)
    }
}

/// One merge of an inactive graph into the active graph; names its backup.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct MergeId(pub u64);

impl std::fmt::Display for MergeId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "merge {}", self.0)
    }
}

/// The name a graph of the atlas goes by in files: `active` for the active graph, else
/// `inactive-K` (`atlas/<name>.g2o`, `maps/<name>/`).
pub fn map_name(map: Option<MapId>) -> String {
    match map {
        None => "active".to_owned(),
        Some(id) => format!("inactive-{}", id.0),
    }
}
