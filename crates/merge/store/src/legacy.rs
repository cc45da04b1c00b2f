//! Types of older schemas, frozen as they were written, and the migration steps that
//! re-encode them (postcard is not self-describing: a type that grows needs its old form to
//! read old blobs).

use std::collections::BTreeMap;

use mapmerge_atlas::{AppliedMerge, AtlasCounters, EpochId};
use mapmerge_geometry::Se2;
use mapmerge_posegraph::NodeId;
use rusqlite::{params, Transaction};
use serde::Deserialize;

/// `AtlasCounters` as schema 2 wrote them.
#[derive(Deserialize)]
struct CountersV2 {
    epoch: EpochId,
    next_node: u64,
    next_epoch: u32,
    next_map: u32,
    next_merge: u64,
    robot: Option<NodeId>,
    merges: Vec<AppliedMerge>,
    map_from_local: Se2,
}

/// Schema 2 → 3: every version's counters gain the maintenance sessions (0: none ran) and
/// the views' use (none recorded).
pub(crate) fn counters_2_to_3(transaction: &Transaction<'_>) -> rusqlite::Result<()> {
    let rows: Vec<(i64, Vec<u8>)> = {
        let mut statement = transaction.prepare("SELECT version, counters FROM atlas_state")?;
        let rows = statement.query_map([], |row| Ok((row.get(0)?, row.get(1)?)))?;
        rows.collect::<Result<_, _>>()?
    };
    let mut update = transaction
        .prepare("UPDATE atlas_state SET counters = ?1, checksum = ?2 WHERE version = ?3")?;
    for (version, bytes) in rows {
        let old: CountersV2 = postcard::from_bytes(&bytes).map_err(|e| {
            rusqlite::Error::FromSqlConversionFailure(1, rusqlite::types::Type::Blob, Box::new(e))
        })?;
        let new = AtlasCounters {
            epoch: old.epoch,
            next_node: old.next_node,
            next_epoch: old.next_epoch,
            next_map: old.next_map,
            next_merge: old.next_merge,
            robot: old.robot,
            merges: old.merges,
            map_from_local: old.map_from_local,
            sessions: 0,
            views: BTreeMap::new(),
            session_first_nodes: Vec::new(),
        };
        let body = crate::atlas_rows::encode(&new)?;
        update.execute(params![body, crate::atlas_rows::crc(&body), version])?;
    }
    Ok(())
}
