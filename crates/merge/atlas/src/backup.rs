//! Backups of inactive graphs taken before a merge (Holoch et al., Sec. III-B: "store it in
//! RAM or on disk, depending on the available memory").

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use mapmerge_posegraph::PoseGraph2;

use crate::error::AtlasError;
use crate::ids::MergeId;

/// Where backups live. A backup is the inactive graph exactly as it was before the merge
/// (poses, edges with their ids, the edge counter, metadata); scans are not part of it (they
/// stay in the atlas's [`crate::ScanStore`]). Loading must return a graph equal bit for bit to
/// the stored one.
pub trait BackupStore {
    /// Stores the graph under `merge` (replacing an older backup with that id).
    fn store(&mut self, merge: MergeId, graph: &PoseGraph2) -> Result<(), AtlasError>;
    /// The graph stored under `merge`.
    fn load(&self, merge: MergeId) -> Result<PoseGraph2, AtlasError>;
    /// Forgets the backup (the merge was undone or became final); missing ones are ignored.
    fn remove(&mut self, merge: MergeId) -> Result<(), AtlasError>;
    /// The ids of the stored backups, ascending.
    fn stored(&self) -> Vec<MergeId>;
}

/// Backups in RAM (the default): a clone of each graph.
#[derive(Clone, Debug, Default)]
pub struct MemoryBackups {
    graphs: BTreeMap<MergeId, PoseGraph2>,
}

impl BackupStore for MemoryBackups {
    fn store(&mut self, merge: MergeId, graph: &PoseGraph2) -> Result<(), AtlasError> {
        self.graphs.insert(merge, graph.clone());
        Ok(())
    }

    fn load(&self, merge: MergeId) -> Result<PoseGraph2, AtlasError> {
        self.graphs
            .get(&merge)
            .cloned()
            .ok_or(AtlasError::MissingBackup(merge))
    }

    fn remove(&mut self, merge: MergeId) -> Result<(), AtlasError> {
        self.graphs.remove(&merge);
        Ok(())
    }

    fn stored(&self) -> Vec<MergeId> {
        self.graphs.keys().copied().collect()
    }
}

/// Backups on disk, one postcard file per merge (`merge-<id>.postcard` in a folder).
/// Postcard writes every `f64` as its 8 bytes, so a loaded graph is the stored one bit for bit.
#[derive(Clone, Debug)]
pub struct DiskBackups {
    dir: PathBuf,
}

impl DiskBackups {
    /// Backups in `dir`, created if missing.
    pub fn new(dir: impl Into<PathBuf>) -> Result<Self, AtlasError> {
        let dir = dir.into();
        std::fs::create_dir_all(&dir).map_err(|source| AtlasError::Io {
            path: dir.clone(),
            source,
        })?;
        Ok(Self { dir })
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    fn path(&self, merge: MergeId) -> PathBuf {
        self.dir.join(format!("merge-{}.postcard", merge.0))
    }
}

impl BackupStore for DiskBackups {
    fn store(&mut self, merge: MergeId, graph: &PoseGraph2) -> Result<(), AtlasError> {
        let path = self.path(merge);
        let bytes = postcard::to_stdvec(graph).map_err(|source| AtlasError::Encoding {
            path: path.clone(),
            source,
        })?;
        std::fs::write(&path, bytes).map_err(|source| AtlasError::Io { path, source })
    }

    fn load(&self, merge: MergeId) -> Result<PoseGraph2, AtlasError> {
        let path = self.path(merge);
        let bytes = match std::fs::read(&path) {
            Ok(bytes) => bytes,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(AtlasError::MissingBackup(merge))
            }
            Err(source) => return Err(AtlasError::Io { path, source }),
        };
        postcard::from_bytes(&bytes).map_err(|source| AtlasError::Encoding { path, source })
    }

    fn remove(&mut self, merge: MergeId) -> Result<(), AtlasError> {
        let path = self.path(merge);
        match std::fs::remove_file(&path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                Err(AtlasError::Io { path, source: e })
            }
            _ => Ok(()),
        }
    }

    fn stored(&self) -> Vec<MergeId> {
        let mut ids: Vec<MergeId> = std::fs::read_dir(&self.dir)
            .into_iter()
            .flatten()
            .filter_map(|entry| {
                let name = entry.ok()?.file_name().into_string().ok()?;
                let id = name.strip_prefix("merge-")?.strip_suffix(".postcard")?;
                id.parse().ok().map(MergeId)
            })
            .collect();
        ids.sort();
        ids
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapmerge_geometry::Se2;
    use mapmerge_posegraph::{Edge, EdgeKind, NodeId, Vertex};
    use nalgebra::Matrix3;

    fn graph() -> PoseGraph2 {
        let mut g = PoseGraph2::new();
        g.add_vertex(NodeId(3), Vertex::new(Se2::new(0.1, 0.2, 0.3)))
            .unwrap();
        g.add_vertex(NodeId(9), Vertex::new(Se2::new(1.0 / 3.0, -2.0, 3.0)))
            .unwrap();
        g.add_edge(Edge {
            from: NodeId(3),
            to: NodeId(9),
            measurement: Se2::new(0.7, 0.1, -0.2),
            information: Matrix3::identity() * std::f64::consts::PI,
            kind: EdgeKind::Odometry,
        })
        .unwrap();
        g
    }

    #[test]
    fn disk_backups_round_trip_bit_for_bit() {
        let dir =
            std::env::temp_dir().join(format!("mapmerge-atlas-backup-{}", std::process::id()));
        let mut store = DiskBackups::new(&dir).unwrap();
        let g = graph();
        store.store(MergeId(4), &g).unwrap();
        assert_eq!(store.stored(), vec![MergeId(4)]);
        let back = store.load(MergeId(4)).unwrap();
        assert_eq!(back, g);
        assert_eq!(
            postcard::to_stdvec(&back).unwrap(),
            postcard::to_stdvec(&g).unwrap()
        );
        store.remove(MergeId(4)).unwrap();
        assert!(matches!(
            store.load(MergeId(4)),
            Err(AtlasError::MissingBackup(MergeId(4)))
        ));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn memory_backups_round_trip() {
        let mut store = MemoryBackups::default();
        store.store(MergeId(1), &graph()).unwrap();
        assert_eq!(store.load(MergeId(1)).unwrap(), graph());
        store.remove(MergeId(1)).unwrap();
        assert!(store.stored().is_empty());
    }
}
