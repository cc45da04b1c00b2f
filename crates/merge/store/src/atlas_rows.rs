//! The atlas in the store: one transaction per committed session, rows shared between the
//! versions they are valid in (docs/formats.md, "The lifelong store").

use std::collections::{BTreeMap, BTreeSet};
use std::time::{SystemTime, UNIX_EPOCH};

use mapmerge_areas::{ManagedMap, MappedSession};
use mapmerge_atlas::{
    points_from_le_bytes, points_to_le_bytes, AtlasCounters, AtlasSnapshot, KeyframeRecord,
    LocalMapGrid, MapId, MergeId,
};
use mapmerge_geometry::Se2;
use mapmerge_posegraph::{NodeId, PoseGraph2};
use rusqlite::{params, OptionalExtension, Transaction, TransactionBehavior};

use crate::error::StoreError;
use crate::schema::ACTIVE_SLOT;
use crate::store::{classify, require_retained, Store, VersionInfo};

/// One session to commit as a new version.
#[derive(Clone, Copy, Debug)]
pub struct SessionCommit<'a> {
    /// The session's name (e.g. its log).
    pub session: &'a str,
    /// The atlas at the end of the session.
    pub atlas: &'a AtlasSnapshot,
    /// The session's events, one JSON document each (appended to the event log).
    pub events: &'a [String],
    /// Reference poses of keyframes (simulation truth, or a corrected log's poses), kept
    /// beside the keyframes this version adds.
    pub reference_poses: &'a BTreeMap<NodeId, Se2>,
}

/// A version's atlas as loaded.
#[derive(Clone, Debug, PartialEq)]
pub struct StoredAtlas {
    /// The version.
    pub version: i64,
    /// Its atlas.
    pub atlas: AtlasSnapshot,
    /// The reference poses stored with its keyframes.
    pub reference_poses: BTreeMap<NodeId, Se2>,
}

/// The rows a version `?1` sees.
pub(crate) const VISIBLE: &str =
    "added_version <= ?1 AND (removed_version IS NULL OR removed_version > ?1)";

/// Cell side of the rendered map that measures a version's mapped area (m).
const AREA_RESOLUTION_M: f64 = 0.05;

/// The CRC-32 stored beside every blob.
pub(crate) fn crc(bytes: &[u8]) -> i64 {
    i64::from(crc32fast::hash(bytes))
}

/// Postcard's encoding, its error as SQLite's (it fails the transaction).
pub(crate) fn encode<T: serde::Serialize>(value: &T) -> rusqlite::Result<Vec<u8>> {
    postcard::to_stdvec(value).map_err(|e| rusqlite::Error::ToSqlConversionFailure(Box::new(e)))
}

impl Store {
    /// Commits the session as a new version continuing the newest, in one transaction: the
    /// counters, every graph that changed, the keyframes and backups that are new (those
    /// gone are marked removed), the events, and the version's summary. Then versions
    /// beyond [`Store::keep_versions`] forget their atlas. Returns the new version's number.
    /// An inconsistent atlas is refused before anything is written.
    pub fn commit_session(&mut self, commit: &SessionCommit<'_>) -> Result<i64, StoreError> {
        let path = self.path.clone();
        let classify = |e: rusqlite::Error| classify(&path, e);
        let atlas = commit.atlas;
        atlas.validate().map_err(|reason| StoreError::BadAtlas {
            path: path.clone(),
            reason,
        })?;
        let keep = i64::try_from(self.keep_versions).unwrap_or(i64::MAX);
        let transaction = self
            .connection
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .map_err(classify)?;
        let count = |n: usize| i64::try_from(n).unwrap_or(i64::MAX);
        let (version, parent) = begin_version(&transaction, commit.session).map_err(classify)?;
        let carried = parent_summary(&transaction, parent).map_err(classify)?;
        let summary = Summary {
            nodes: count(atlas.num_vertices()),
            edges: count(atlas.num_edges()),
            keyframes: count(atlas.keyframes.len()),
            local_maps: count(atlas.num_local_maps()),
            mapped_area_m2: atlas.mapped_area_m2(AREA_RESOLUTION_M),
            ..carried
        };
        write_summary(&transaction, version, &summary).map_err(classify)?;
        let counters = encode(&atlas.counters).map_err(classify)?;
        transaction
            .execute(
                "INSERT INTO atlas_state (version, counters, checksum) VALUES (?1, ?2, ?3)",
                params![version, counters, crc(&counters)],
            )
            .map_err(classify)?;
        let graphs = std::iter::once((ACTIVE_SLOT, &atlas.active))
            .chain(atlas.inactive.iter().map(|(m, g)| (i64::from(m.0), g)));
        write_slots(&transaction, "graphs", "slot", version, graphs).map_err(classify)?;
        write_keyframes(&transaction, version, atlas, commit.reference_poses).map_err(classify)?;
        let backups = atlas
            .backups
            .iter()
            .map(|(merge, graph)| (sql_id(merge.0), graph));
        write_immutable(&transaction, "backups", "merge", version, backups).map_err(classify)?;
        let local_maps = atlas
            .local_maps
            .iter()
            .map(|(anchor, map)| (sql_id(anchor.0), map));
        write_slots(&transaction, "local_maps", "anchor", version, local_maps).map_err(classify)?;
        {
            let mut insert = transaction
                .prepare("INSERT INTO events (version, body) VALUES (?1, ?2)")
                .map_err(classify)?;
            for event in commit.events {
                insert.execute(params![version, event]).map_err(classify)?;
            }
        }
        finish_version(transaction, version, keep).map_err(classify)?;
        self.checkpoint()?;
        self.reclaim()?;
        Ok(version)
    }

    /// The atlas of `version` (default: the newest); `None` when the store has no version.
    pub fn load(&self, version: Option<i64>) -> Result<Option<StoredAtlas>, StoreError> {
        let path = &self.path;
        let classify = |e: rusqlite::Error| classify(path, e);
        let Some(version) = self.given_or_newest(version)? else {
            return Ok(None);
        };
        require_retained(&self.connection, path, version)?;
        let corrupt = |reason: String| StoreError::Corrupt {
            path: path.clone(),
            reason: format!("version {version}: {reason}"),
        };
        let Some((_, counters)) = self
            .checked_blobs(
                "SELECT version, counters, checksum FROM atlas_state WHERE version = ?1",
                Some(version),
                "atlas_state",
            )?
            .pop()
        else {
            return Err(StoreError::NoAtlas {
                path: path.clone(),
                version,
            });
        };
        let counters: AtlasCounters =
            postcard::from_bytes(&counters).map_err(|e| corrupt(format!("counters: {e}")))?;
        let mut active = None;
        let mut inactive = BTreeMap::new();
        let graphs = self.checked_blobs(
            &format!("SELECT slot, body, checksum FROM graphs WHERE {VISIBLE}"),
            Some(version),
            "graphs",
        )?;
        for (slot, body) in graphs {
            let graph: PoseGraph2 = postcard::from_bytes(&body)
                .map_err(|e| corrupt(format!("graph in slot {slot}: {e}")))?;
            if slot == ACTIVE_SLOT {
                active = Some(graph);
            } else {
                let map = u32::try_from(slot).map_err(|_| corrupt(format!("graph slot {slot}")))?;
                if inactive.insert(MapId(map), graph).is_some() {
                    return Err(corrupt(format!("two graphs in slot {slot}")));
                }
            }
        }
        let mut keyframes = BTreeMap::new();
        let mut reference_poses = BTreeMap::new();
        let mut statement = self
            .connection
            .prepare(&format!(
                "SELECT node, travel_m, local_x_m, local_y_m, local_yaw_rad, submap,
                        reference_x_m, reference_y_m, reference_yaw_rad, points, checksum
                 FROM keyframes WHERE {VISIBLE}"
            ))
            .map_err(classify)?;
        let rows = statement
            .query_map([version], |row| {
                Ok((
                    row.get::<_, i64>(0)?,
                    row.get::<_, f64>(1)?,
                    [row.get::<_, f64>(2)?, row.get(3)?, row.get(4)?],
                    row.get::<_, Option<i64>>(5)?,
                    [row.get::<_, Option<f64>>(6)?, row.get(7)?, row.get(8)?],
                    row.get::<_, Vec<u8>>(9)?,
                    row.get::<_, i64>(10)?,
                ))
            })
            .map_err(classify)?;
        for row in rows {
            let (node, travel_m, local, submap, reference, points, checksum) =
                row.map_err(classify)?;
            let node = node_id(node).ok_or_else(|| corrupt(format!("keyframe id {node}")))?;
            if crc(&points) != checksum {
                return Err(corrupt(format!("keyframe {node}: checksum mismatch")));
            }
            let points_in_robot = points_from_le_bytes(&points).ok_or_else(|| {
                corrupt(format!("keyframe {node}: {} bytes of points", points.len()))
            })?;
            let submap = match submap {
                Some(s) => Some(node_id(s).ok_or_else(|| corrupt(format!("submap id {s}")))?),
                None => None,
            };
            keyframes.insert(
                node,
                KeyframeRecord {
                    points_in_robot,
                    travel_m,
                    local_from_robot: Se2::new(local[0], local[1], local[2]),
                    submap,
                },
            );
            if let [Some(x), Some(y), Some(yaw)] = reference {
                reference_poses.insert(node, Se2::new(x, y, yaw));
            }
        }
        let backups = self
            .load_blobs::<PoseGraph2>("backups", "merge", version)?
            .into_iter()
            .map(|(id, graph)| {
                Ok((
                    MergeId(id_of(id).ok_or_else(|| corrupt(format!("merge id {id}")))?),
                    graph,
                ))
            })
            .collect::<Result<_, StoreError>>()?;
        let local_maps = self
            .load_blobs::<LocalMapGrid>("local_maps", "anchor", version)?
            .into_iter()
            .map(|(id, map)| {
                Ok((
                    node_id(id).ok_or_else(|| corrupt(format!("anchor id {id}")))?,
                    map,
                ))
            })
            .collect::<Result<_, StoreError>>()?;
        let atlas = AtlasSnapshot {
            counters,
            active: active.unwrap_or_default(),
            inactive,
            keyframes,
            backups,
            local_maps,
        };
        atlas.validate().map_err(corrupt)?;
        Ok(Some(StoredAtlas {
            version,
            atlas,
            reference_poses,
        }))
    }

    /// The event log of the retained versions (JSON documents, oldest first), or of one
    /// version.
    pub fn events(&self, version: Option<i64>) -> Result<Vec<String>, StoreError> {
        let classify = |e: rusqlite::Error| classify(&self.path, e);
        let mut statement = self
            .connection
            .prepare("SELECT body FROM events WHERE ?1 IS NULL OR version = ?1 ORDER BY seq")
            .map_err(classify)?;
        let rows = statement
            .query_map([version], |row| row.get(0))
            .map_err(classify)?;
        rows.collect::<Result<_, _>>().map_err(classify)
    }

    /// The `(key, blob)` pairs `sql` selects as `key, blob, checksum` (with `?1` bound to
    /// `version` when given), each blob checked against its CRC-32; a mismatch is corruption
    /// of `table`.
    pub(crate) fn checked_blobs(
        &self,
        sql: &str,
        version: Option<i64>,
        table: &str,
    ) -> Result<Vec<(i64, Vec<u8>)>, StoreError> {
        let classify = |e: rusqlite::Error| classify(&self.path, e);
        let mut statement = self.connection.prepare(sql).map_err(classify)?;
        let read = |row: &rusqlite::Row<'_>| {
            Ok((
                row.get::<_, i64>(0)?,
                row.get::<_, Vec<u8>>(1)?,
                row.get::<_, i64>(2)?,
            ))
        };
        let rows = match version {
            Some(v) => statement.query_map([v], read),
            None => statement.query_map([], read),
        }
        .map_err(classify)?;
        let mut blobs = Vec::new();
        for row in rows {
            let (id, blob, checksum) = row.map_err(classify)?;
            if crc(&blob) != checksum {
                return Err(StoreError::Corrupt {
                    path: self.path.clone(),
                    reason: format!("{table} row {id}: checksum mismatch"),
                });
            }
            blobs.push((id, blob));
        }
        Ok(blobs)
    }

    /// The blobs of `table` (`backups` by merge, `local_maps` by anchor) valid in `version`,
    /// checksummed and decoded, by key.
    pub(crate) fn load_blobs<T: serde::de::DeserializeOwned>(
        &self,
        table: &str,
        key: &str,
        version: i64,
    ) -> Result<BTreeMap<i64, T>, StoreError> {
        let corrupt = |reason: String| StoreError::Corrupt {
            path: self.path.clone(),
            reason: format!("version {version}: {table} row {reason}"),
        };
        let rows = self.checked_blobs(
            &format!("SELECT {key}, body, checksum FROM {table} WHERE {VISIBLE}"),
            Some(version),
            table,
        )?;
        let mut blobs = BTreeMap::new();
        for (id, body) in rows {
            let value = postcard::from_bytes(&body).map_err(|e| corrupt(format!("{id}: {e}")))?;
            blobs.insert(id, value);
        }
        Ok(blobs)
    }

    /// The rows half of [`Store::check`]: every retained version has counters, every stored
    /// blob decodes, and the newest version loads into a consistent atlas and areas.
    pub(crate) fn check_rows(&self, versions: &[VersionInfo]) -> Result<(), StoreError> {
        let corrupt = |reason: String| StoreError::Corrupt {
            path: self.path.clone(),
            reason,
        };
        let mut with_atlas = BTreeSet::new();
        for (version, counters) in self.checked_blobs(
            "SELECT version, counters, checksum FROM atlas_state",
            None,
            "atlas_state",
        )? {
            postcard::from_bytes::<AtlasCounters>(&counters)
                .map_err(|e| corrupt(format!("version {version}: counters: {e}")))?;
            with_atlas.insert(version);
        }
        // Versions written by schema 1 hold no atlas; every later one does while retained.
        let first_with_atlas = with_atlas.first().copied().unwrap_or(i64::MAX);
        for v in versions {
            let expected = v.retained && v.version >= first_with_atlas;
            if expected != with_atlas.contains(&v.version) {
                return Err(corrupt(format!(
                    "version {} ({}retained) {} an atlas",
                    v.version,
                    if v.retained { "" } else { "not " },
                    if expected { "lacks" } else { "has" }
                )));
            }
        }
        for (table, key) in [
            ("graphs", "id"),
            ("backups", "merge"),
            ("local_maps", "id"),
            ("area_sessions", "session"),
            ("area_maps", "id"),
        ] {
            let sql = format!("SELECT {key}, body, checksum FROM {table}");
            for (id, body) in self.checked_blobs(&sql, None, table)? {
                let decoded = match table {
                    "local_maps" => postcard::from_bytes::<LocalMapGrid>(&body).map(|_| ()),
                    "area_sessions" => postcard::from_bytes::<MappedSession>(&body).map(|_| ()),
                    "area_maps" => postcard::from_bytes::<ManagedMap>(&body).map(|_| ()),
                    _ => postcard::from_bytes::<PoseGraph2>(&body).map(|_| ()),
                };
                decoded.map_err(|e| corrupt(format!("{table} row {id}: {e}")))?;
            }
        }
        let sql = "SELECT node, points, checksum FROM keyframes";
        for (node, points) in self.checked_blobs(sql, None, "keyframes")? {
            if points.len() % 16 != 0 {
                return Err(corrupt(format!(
                    "keyframe {node}: points are not 16-byte pairs"
                )));
            }
        }
        if let Some(newest) = versions.last() {
            if with_atlas.contains(&newest.version) {
                self.load(Some(newest.version))?;
            }
            if newest.retained {
                self.load_areas(Some(newest.version))?;
            }
        }
        Ok(())
    }
}

fn id_of(value: i64) -> Option<u64> {
    u64::try_from(value).ok()
}

fn node_id(value: i64) -> Option<NodeId> {
    id_of(value).map(NodeId)
}

pub(crate) fn sql_id(value: u64) -> i64 {
    i64::try_from(value).unwrap_or(i64::MAX)
}

/// Graphs by slot, local maps by anchor, the managed map in its slot: a slot whose value changed gets a new row and the old
/// one is marked removed; slots that are gone are marked removed.
pub(crate) fn write_slots<'a, T: serde::Serialize + 'a>(
    transaction: &Transaction<'_>,
    table: &str,
    slot_column: &str,
    version: i64,
    items: impl Iterator<Item = (i64, &'a T)>,
) -> rusqlite::Result<()> {
    let mut live: BTreeMap<i64, (i64, Vec<u8>)> = BTreeMap::new();
    {
        let mut statement = transaction.prepare(&format!(
            "SELECT {slot_column}, id, body FROM {table} WHERE removed_version IS NULL"
        ))?;
        let rows = statement.query_map([], |row| Ok((row.get(0)?, row.get(1)?, row.get(2)?)))?;
        for row in rows {
            let (slot, id, body) = row?;
            live.insert(slot, (id, body));
        }
    }
    let mut remove = transaction.prepare(&format!(
        "UPDATE {table} SET removed_version = ?1 WHERE id = ?2"
    ))?;
    let mut insert = transaction.prepare(&format!(
        "INSERT INTO {table} ({slot_column}, added_version, body, checksum) VALUES (?1, ?2, ?3, ?4)"
    ))?;
    let mut kept = BTreeSet::new();
    for (slot, value) in items {
        let body = encode(value)?;
        kept.insert(slot);
        match live.get(&slot) {
            Some((_, old)) if *old == body => continue,
            Some((id, _)) => {
                remove.execute([version, *id])?;
            }
            None => {}
        }
        insert.execute(params![slot, version, body, crc(&body)])?;
    }
    for (slot, (id, _)) in &live {
        if !kept.contains(slot) {
            remove.execute([version, *id])?;
        }
    }
    Ok(())
}

/// Keyframes never change: new ones get a row, those gone are marked removed.
fn write_keyframes(
    transaction: &Transaction<'_>,
    version: i64,
    atlas: &AtlasSnapshot,
    reference_poses: &BTreeMap<NodeId, Se2>,
) -> rusqlite::Result<()> {
    let live = live_ids(transaction, "keyframes", "node")?;
    let mut insert = transaction.prepare(
        "INSERT INTO keyframes (node, added_version, travel_m, local_x_m, local_y_m,
                                local_yaw_rad, submap, reference_x_m, reference_y_m,
                                reference_yaw_rad, points, checksum)
         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12)",
    )?;
    for (node, record) in &atlas.keyframes {
        if live.contains(&sql_id(node.0)) {
            continue;
        }
        let local = record.local_from_robot;
        let reference = reference_poses.get(node);
        let points = points_to_le_bytes(&record.points_in_robot);
        insert.execute(params![
            sql_id(node.0),
            version,
            record.travel_m,
            local.x_m,
            local.y_m,
            local.theta_rad,
            record.submap.map(|s| sql_id(s.0)),
            reference.map(|p| p.x_m),
            reference.map(|p| p.y_m),
            reference.map(|p| p.theta_rad),
            points,
            crc(&points),
        ])?;
    }
    let kept: BTreeSet<i64> = atlas.keyframes.keys().map(|n| sql_id(n.0)).collect();
    mark_removed(
        transaction,
        "keyframes",
        "node",
        version,
        live.difference(&kept),
    )
}

/// Backups and area sessions never change: new ones (by key) get a row, those gone are
/// marked removed. Only new ones are encoded.
pub(crate) fn write_immutable<'a, T: serde::Serialize + 'a>(
    transaction: &Transaction<'_>,
    table: &str,
    key: &str,
    version: i64,
    items: impl Iterator<Item = (i64, &'a T)>,
) -> rusqlite::Result<()> {
    let live = live_ids(transaction, table, key)?;
    let mut kept = BTreeSet::new();
    let mut insert = transaction.prepare(&format!(
        "INSERT INTO {table} ({key}, added_version, body, checksum) VALUES (?1, ?2, ?3, ?4)"
    ))?;
    for (id, value) in items {
        kept.insert(id);
        if !live.contains(&id) {
            let body = encode(value)?;
            insert.execute(params![id, version, body, crc(&body)])?;
        }
    }
    mark_removed(transaction, table, key, version, live.difference(&kept))
}

fn live_ids(
    transaction: &Transaction<'_>,
    table: &str,
    key: &str,
) -> rusqlite::Result<BTreeSet<i64>> {
    let mut statement = transaction.prepare(&format!(
        "SELECT {key} FROM {table} WHERE removed_version IS NULL"
    ))?;
    let rows = statement.query_map([], |row| row.get(0))?;
    rows.collect()
}

fn mark_removed<'a>(
    transaction: &Transaction<'_>,
    table: &str,
    key: &str,
    version: i64,
    ids: impl Iterator<Item = &'a i64>,
) -> rusqlite::Result<()> {
    let mut update = transaction.prepare(&format!(
        "UPDATE {table} SET removed_version = ?1 WHERE {key} = ?2"
    ))?;
    for id in ids {
        update.execute([version, *id])?;
    }
    Ok(())
}

/// A version's summary: its atlas's counts and mapped area, and its areas' counts.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Summary {
    pub(crate) nodes: i64,
    pub(crate) edges: i64,
    pub(crate) keyframes: i64,
    pub(crate) local_maps: i64,
    pub(crate) mapped_area_m2: f64,
    pub(crate) areas: i64,
    pub(crate) link_points: i64,
}

/// Adds the row of a new version continuing the newest (its summary zero until
/// [`write_summary`]); returns it and its parent.
pub(crate) fn begin_version(
    transaction: &Transaction<'_>,
    session: &str,
) -> rusqlite::Result<(i64, Option<i64>)> {
    let created_unix_s = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_secs()).unwrap_or(i64::MAX));
    let parent: Option<i64> = transaction
        .query_row("SELECT max(version) FROM versions", [], |row| row.get(0))
        .optional()?
        .flatten();
    let version = parent.unwrap_or(0) + 1;
    transaction.execute(
        "INSERT INTO versions (version, parent, session, created_unix_s, nodes, edges,
                               keyframes, local_maps, mapped_area_m2, bytes, retained)
         VALUES (?1, ?2, ?3, ?4, 0, 0, 0, 0, 0.0, 0, 1)",
        params![version, parent, session, created_unix_s],
    )?;
    Ok((version, parent))
}

/// The summary of `parent` (zero without one): what a version that changes only the atlas,
/// or only the areas, carries over.
pub(crate) fn parent_summary(
    transaction: &Transaction<'_>,
    parent: Option<i64>,
) -> rusqlite::Result<Summary> {
    let Some(parent) = parent else {
        return Ok(Summary::default());
    };
    transaction.query_row(
        "SELECT nodes, edges, keyframes, local_maps, mapped_area_m2, areas, link_points
         FROM versions WHERE version = ?1",
        [parent],
        |row| {
            Ok(Summary {
                nodes: row.get(0)?,
                edges: row.get(1)?,
                keyframes: row.get(2)?,
                local_maps: row.get(3)?,
                mapped_area_m2: row.get(4)?,
                areas: row.get(5)?,
                link_points: row.get(6)?,
            })
        },
    )
}

pub(crate) fn write_summary(
    transaction: &Transaction<'_>,
    version: i64,
    s: &Summary,
) -> rusqlite::Result<()> {
    transaction.execute(
        "UPDATE versions SET nodes = ?2, edges = ?3, keyframes = ?4, local_maps = ?5,
                             mapped_area_m2 = ?6, areas = ?7, link_points = ?8
         WHERE version = ?1",
        params![
            version,
            s.nodes,
            s.edges,
            s.keyframes,
            s.local_maps,
            s.mapped_area_m2,
            s.areas,
            s.link_points
        ],
    )?;
    Ok(())
}

/// Ends the commit of `version`: versions beyond the newest `keep` forget their rows, the
/// version's size is recorded, and the transaction commits.
pub(crate) fn finish_version(
    transaction: Transaction<'_>,
    version: i64,
    keep: i64,
) -> rusqlite::Result<()> {
    forget_before(&transaction, version - keep + 1)?;
    // The database's size with this version in it (pages × page size).
    let bytes: i64 = transaction.query_row(
        "SELECT page_count * page_size FROM pragma_page_count, pragma_page_size",
        [],
        |row| row.get(0),
    )?;
    transaction.execute(
        "UPDATE versions SET bytes = ?1 WHERE version = ?2",
        [bytes, version],
    )?;
    transaction.commit()
}

/// Versions before `oldest_kept` forget their atlas: rows no version from `oldest_kept` on
/// sees, their counters and their events go; their summary rows stay.
fn forget_before(transaction: &Transaction<'_>, oldest_kept: i64) -> rusqlite::Result<()> {
    if oldest_kept <= 1 {
        return Ok(());
    }
    for table in crate::schema::VERSIONED_TABLES {
        transaction.execute(
            &format!("DELETE FROM {table} WHERE removed_version <= ?1"),
            [oldest_kept],
        )?;
    }
    for table in ["atlas_state", "events"] {
        transaction.execute(
            &format!("DELETE FROM {table} WHERE version < ?1"),
            [oldest_kept],
        )?;
    }
    transaction.execute(
        "UPDATE versions SET retained = 0 WHERE version < ?1",
        [oldest_kept],
    )?;
    Ok(())
}
