//! The map manager's areas in the store (Ehlers et al.; docs/formats.md, "The lifelong
//! store"): each session as mapped, and the managed map built from them. A commit of areas is
//! a version like an atlas session's; the atlas of its parent stays valid in it, as the areas
//! stay valid in a later atlas session's version.

use mapmerge_areas::{ManagedMap, MappedSession};
use rusqlite::{params, TransactionBehavior};

use crate::atlas_rows::{
    begin_version, finish_version, parent_summary, sql_id, write_immutable, write_slots,
    write_summary, Summary,
};
use crate::error::StoreError;
use crate::store::{classify, require_retained, Store};

/// The areas of a site to commit as a new version.
#[derive(Clone, Copy, Debug)]
pub struct AreasCommit<'a> {
    /// The version's name (e.g. the logs it adds).
    pub session: &'a str,
    /// Every session of the site, the stored ones first and in their order: stored ones are
    /// kept, new ones added, and ones no longer given are marked removed.
    pub sessions: &'a [MappedSession],
    /// The managed map built from `sessions`.
    pub map: &'a ManagedMap,
}

/// A version's areas as loaded.
#[derive(Clone, Debug, PartialEq)]
pub struct StoredAreas {
    /// The version.
    pub version: i64,
    /// Its sessions, in order.
    pub sessions: Vec<MappedSession>,
    /// The managed map built from them.
    pub map: ManagedMap,
}

/// The one slot of `area_maps`.
const MAP_SLOT: i64 = 0;

impl Store {
    /// Commits a site's areas as a new version continuing the newest, in one transaction: the
    /// sessions that are new, the managed map, and the version's summary (its atlas counts
    /// are its parent's, whose atlas stays valid in it). Returns the new version's number. A
    /// map that does not fit its sessions is refused before anything is written.
    pub fn commit_areas(&mut self, commit: &AreasCommit<'_>) -> Result<i64, StoreError> {
        let path = self.path.clone();
        let classify = |e: rusqlite::Error| classify(&path, e);
        commit
            .map
            .validate_against(commit.sessions)
            .map_err(|reason| StoreError::BadAreas {
                path: path.clone(),
                reason,
            })?;
        let keep = i64::try_from(self.keep_versions).unwrap_or(i64::MAX);
        let transaction = self
            .connection
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .map_err(classify)?;
        let (version, parent) = begin_version(&transaction, commit.session).map_err(classify)?;
        let count = |n: usize| i64::try_from(n).unwrap_or(i64::MAX);
        let summary = Summary {
            areas: count(commit.map.hybrid.areas.len()),
            link_points: count(commit.map.hybrid.link_points.len()),
            ..parent_summary(&transaction, parent).map_err(classify)?
        };
        write_summary(&transaction, version, &summary).map_err(classify)?;
        if let Some(parent) = parent {
            // The parent's atlas, if it has one, is this version's too.
            transaction
                .execute(
                    "INSERT INTO atlas_state (version, counters, checksum)
                     SELECT ?1, counters, checksum FROM atlas_state WHERE version = ?2",
                    params![version, parent],
                )
                .map_err(classify)?;
        }
        let sessions = commit
            .sessions
            .iter()
            .enumerate()
            .map(|(k, session)| (sql_id(k as u64), session));
        write_immutable(&transaction, "area_sessions", "session", version, sessions)
            .map_err(classify)?;
        write_slots(
            &transaction,
            "area_maps",
            "slot",
            version,
            std::iter::once((MAP_SLOT, commit.map)),
        )
        .map_err(classify)?;
        finish_version(transaction, version, keep).map_err(classify)?;
        self.checkpoint()?;
        Ok(version)
    }

    /// The areas of `version` (default: the newest); `None` when the store has no version or
    /// the version holds no areas.
    pub fn load_areas(&self, version: Option<i64>) -> Result<Option<StoredAreas>, StoreError> {
        let Some(version) = self.given_or_newest(version)? else {
            return Ok(None);
        };
        require_retained(&self.connection, &self.path, version)?;
        let corrupt = |reason: String| StoreError::Corrupt {
            path: self.path.clone(),
            reason: format!("version {version}: {reason}"),
        };
        let mut maps = self.load_blobs::<ManagedMap>("area_maps", "slot", version)?;
        let Some(map) = maps.remove(&MAP_SLOT) else {
            return Ok(None);
        };
        if let Some(slot) = maps.keys().next() {
            return Err(corrupt(format!("area map in slot {slot}")));
        }
        let stored = self.load_blobs::<MappedSession>("area_sessions", "session", version)?;
        // Sessions are numbered 0, 1, … with no gap.
        if let Some((k, _)) = stored.keys().enumerate().find(|(k, s)| **s != *k as i64) {
            return Err(corrupt(format!("no area session {k}")));
        }
        let sessions: Vec<MappedSession> = stored.into_values().collect();
        map.validate_against(&sessions).map_err(corrupt)?;
        Ok(Some(StoredAreas {
            version,
            sessions,
            map,
        }))
    }
}
