//! Reports read from the engine's events ([`crate::Engine::events`], the lines of
//! `events.jsonl`), so that the engine keeps no counters for them and a saved event log
//! gives the same report: the hypotheses' counters, the views marked ambiguous and the views
//! searched for self-similarity. Each is what the engine's state holds, since the engine logs
//! every change of it.

use std::collections::{BTreeMap, BTreeSet};

use mapmerge_hypothesis::FilterStats;
use mapmerge_posegraph::NodeId;

use crate::{Decision, EngineEvent, EventKind, HypothesisSummary};

/// Counters of the merge and recovery hypotheses in `events`.
pub fn hypothesis_summary(events: &[EngineEvent]) -> HypothesisSummary {
    FilterStats::of_events(events.iter().filter_map(|e| match &e.event {
        EventKind::Hypothesis(event) => Some(event),
        _ => None,
    }))
}

/// The keyframes `events` marked ambiguous (Sec. 5.3), by node: by the ambiguity tracker, and
/// views whose own local map fits itself elsewhere (`decisions.self_similarity`).
pub fn ambiguous_views(events: &[EngineEvent]) -> BTreeSet<NodeId> {
    events
        .iter()
        .filter_map(|e| match &e.event {
            EventKind::Decision(Decision::AmbiguousViews { views }) => Some(views),
            _ => None,
        })
        .flatten()
        .map(|view| NodeId(*view))
        .collect()
}

/// The views of inactive graphs `events` searched for another placement of their own local
/// map (`decisions.self_similarity`; each view once), by node, with that placement's score;
/// those from `decisions.self_similar_from_score` on are ambiguous.
pub fn view_self_similarity(events: &[EngineEvent]) -> BTreeMap<NodeId, f64> {
    events
        .iter()
        .filter_map(|e| match &e.event {
            EventKind::Decision(Decision::SelfSimilarity { node, score, .. }) => {
                Some((NodeId(*node), *score))
            }
            _ => None,
        })
        .collect()
}
