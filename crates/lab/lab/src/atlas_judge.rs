//! `mapmerge atlas` against the truth: simulated sessions with their ground truth, every
//! merge judged by its edges, the trajectory error of every committed session, and how far
//! each later epoch travelled where an earlier one had been (Holoch et al.'s targets: every
//! wrong merge undone within 10 m, no correct one undone).

use std::collections::{BTreeMap, BTreeSet};
use std::io::Write;
use std::path::Path;

use anyhow::Context;
use mapmerge_atlas::AtlasEvent;
use mapmerge_engine::MergeState;
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_jobs::{AtlasRun, AtlasSession, MergeReport};
use mapmerge_posegraph::NodeId;
use nalgebra::Vector2;
use serde::Serialize;

use crate::invalid_merge_eval::{Label, MergeResult};

/// Merge edges are judged true within this (m, rad).
pub const TRUE_WITHIN: (f64, f64) = (0.5, 0.1745);
/// A wrong merge must be undone within this much travel (m) (issue target).
pub const UNDO_WITHIN_M: f64 = 10.0;
/// An epoch revisits where its true path passes within this of an earlier epoch's (m): a
/// 360° scan there sees the same place …
pub const REVISIT_RADIUS_M: f64 = 1.5;
/// … and counts as revisiting with at least this much such travel (m): the full merge
/// criteria need 5 observations over views 2 m apart, about 5 m of travel.
pub const REVISIT_MIN_M: f64 = 5.0;

/// The sessions of a simulated world (`preset`), with the simulator's truth as reference
/// and its kidnaps: [`crate::sim::simulated_sessions`].
pub fn simulated_sessions(
    preset: &str,
    sessions: usize,
    duration_secs: f64,
    seed: u64,
    session_index: Option<usize>,
) -> anyhow::Result<Vec<AtlasSession>> {
    let simulated =
        crate::sim::simulated_sessions(preset, sessions, duration_secs, seed, session_index, true)?;
    Ok(simulated
        .into_iter()
        .map(|s| AtlasSession {
            name: format!("{preset} session {}", s.index),
            kidnaps: s.kidnaps.iter().map(|k| k.scan_index).collect(),
            reference: Some(s.truth.iter().map(|(_, pose)| *pose).collect()),
            log: s.log,
        })
        .collect())
}

/// One epoch after the first, against the ground truth.
#[derive(Clone, Debug, Serialize)]
pub struct EpochRevisit {
    pub epoch: usize,
    /// Its true path's length (m) …
    pub travel_m: f64,
    /// … and the part of it within [`REVISIT_RADIUS_M`] of an earlier epoch's true path (m).
    pub revisit_travel_m: f64,
    /// Whether it ends with a kept correct merge.
    pub merged_correctly: bool,
}

/// The run's merges against the truth (none of it without a reference).
#[derive(Clone, Debug, Default, Serialize)]
pub struct AtlasJudgement {
    /// Wrong merges (any state), those rejected or undone within [`UNDO_WITHIN_M`] of
    /// travel, correct ones, those undone (full) and those rejected (conditional), epochs
    /// after the first that end with a kept correct merge.
    pub wrong_merges: Option<usize>,
    pub wrong_undone_within_10m: Option<usize>,
    pub correct_merges: Option<usize>,
    pub correct_undone: Option<usize>,
    pub correct_rejected: Option<usize>,
    pub epochs_merged_correctly: Option<usize>,
    /// Fragments that rejoined the site map at a session's end, correctly and wrongly (by
    /// the merges' rule).
    pub correct_rejoins: Option<usize>,
    pub wrong_rejoins: Option<usize>,
    /// Fresh runs: epochs after the first whose true path ran at least [`REVISIT_MIN_M`]
    /// within [`REVISIT_RADIUS_M`] of an earlier epoch's (the others had little or no chance
    /// to merge), those of them that end with a kept correct merge, and every epoch's
    /// figures.
    pub epochs_revisiting: Option<usize>,
    pub epochs_revisiting_merged_correctly: Option<usize>,
    pub epoch_revisits: Option<Vec<EpochRevisit>>,
}

/// Judges `run` against its reference poses: fills every merge's verdict and every committed
/// session's ATE in the report, and returns the counts.
pub fn judge_atlas(run: &mut AtlasRun, sessions: &[AtlasSession]) -> AtlasJudgement {
    let references = &run.reference_of_node;
    for (report, record) in run.report.merges.iter_mut().zip(run.engine.merge_log()) {
        if let Some((correct, error)) = judge_edges(references, &record.edges) {
            report.correct = Some(correct);
            report.error_m_deg = Some(error);
        }
    }
    for rejoin in &mut run.report.rejoins {
        if let Some((correct, error)) = judge_edges(references, &rejoin.edges) {
            rejoin.correct = Some(correct);
            rejoin.error_m_deg = Some(error);
        }
    }
    if let Some(store) = run.report.store.as_mut() {
        for committed in &mut store.committed {
            let session: Vec<(NodeId, Se2)> = committed
                .mapped_poses
                .iter()
                .filter(|(n, _)| *n >= committed.first_node)
                .copied()
                .collect();
            committed.session_ate_m = ate_of(&session, references);
            committed.map_ate_m = ate_of(&committed.mapped_poses, references);
        }
    }
    if references.is_empty() {
        return AtlasJudgement::default();
    }
    let merges = &run.report.merges;
    let wrong: Vec<&MergeReport> = merges.iter().filter(|m| m.correct == Some(false)).collect();
    let correct: Vec<&MergeReport> = merges.iter().filter(|m| m.correct == Some(true)).collect();
    let kept_correct: BTreeSet<u32> = correct
        .iter()
        .filter(|m| m.state == MergeState::Full)
        .map(|m| m.epoch)
        .collect();
    let correct_in = |state| correct.iter().filter(|m| m.state == state).count();
    let rejoined = |correct: bool| {
        run.report
            .rejoins
            .iter()
            .filter(|r| r.correct == Some(correct))
            .count()
    };
    let epoch_revisits = epoch_revisits(run, sessions, &kept_correct);
    let revisiting = |e: &&EpochRevisit| e.revisit_travel_m >= REVISIT_MIN_M;
    AtlasJudgement {
        wrong_merges: Some(wrong.len()),
        wrong_undone_within_10m: Some(
            wrong
                .iter()
                .filter(|m| m.undone_after_m.is_some_and(|d| d <= UNDO_WITHIN_M))
                .count(),
        ),
        correct_merges: Some(correct.len()),
        correct_undone: Some(correct_in(MergeState::Undone)),
        correct_rejected: Some(correct_in(MergeState::Rejected)),
        epochs_merged_correctly: Some(kept_correct.len()),
        correct_rejoins: Some(rejoined(true)),
        wrong_rejoins: Some(rejoined(false)),
        epochs_revisiting: epoch_revisits
            .as_ref()
            .map(|r| r.iter().filter(revisiting).count()),
        epochs_revisiting_merged_correctly: epoch_revisits.as_ref().map(|r| {
            r.iter()
                .filter(revisiting)
                .filter(|e| e.merged_correctly)
                .count()
        }),
        epoch_revisits,
    }
}

/// Epochs after the first: how far each travelled where an earlier epoch had been. Only for
/// a fresh run whose every session has a reference (a resumed atlas's earlier paths are not
/// known).
fn epoch_revisits(
    run: &AtlasRun,
    sessions: &[AtlasSession],
    kept_correct: &BTreeSet<u32>,
) -> Option<Vec<EpochRevisit>> {
    let resumed = run
        .report
        .store
        .as_ref()
        .is_some_and(|s| s.resumed_from.is_some());
    if resumed {
        return None;
    }
    let positions: Vec<Vector2<f64>> = sessions
        .iter()
        .map(|s| s.reference.as_ref().map(|r| r.iter().map(Se2::translation)))
        .collect::<Option<Vec<_>>>()?
        .into_iter()
        .flatten()
        .collect();
    if positions.len() != run.engine.scans() {
        return None;
    }
    // An epoch's scans: from the scan count at its start to the next one's.
    let mut starts: Vec<usize> = run
        .engine
        .events()
        .iter()
        .filter(|e| matches!(e.atlas(), Some(AtlasEvent::EpochStarted { .. })))
        .map(|e| e.scan.min(positions.len()))
        .collect();
    if starts.len() != run.report.epochs {
        return None;
    }
    starts.push(positions.len());
    let paths: Vec<Vec<Vector2<f64>>> = starts
        .windows(2)
        .map(|w| positions.get(w[0]..w[1]).unwrap_or_default().to_vec())
        .collect();
    let revisit_m = mapmerge_eval::revisit_travel_m(&paths, REVISIT_RADIUS_M);
    Some(
        (1..paths.len())
            .map(|e| EpochRevisit {
                epoch: e,
                travel_m: paths[e].windows(2).map(|w| (w[1] - w[0]).norm()).sum(),
                revisit_travel_m: revisit_m[e],
                merged_correctly: u32::try_from(e).is_ok_and(|e| kept_correct.contains(&e)),
            })
            .collect(),
    )
}

/// ATE (m, RMS after rigid alignment) of the `poses` that have a reference pose; none with
/// fewer than three.
fn ate_of(poses: &[(NodeId, Se2)], references: &BTreeMap<NodeId, Se2>) -> Option<f64> {
    let (reference, estimate): (Vec<Se2>, Vec<Se2>) = poses
        .iter()
        .filter_map(|(n, pose)| Some((*references.get(n)?, *pose)))
        .unzip();
    if reference.len() < 3 {
        return None;
    }
    mapmerge_eval::absolute_trajectory_error(&reference, &estimate, true)
        .ok()
        .map(|e| e.rms_m)
}

/// A merge is correct when most of its merge edges (recorded by the engine when it decided,
/// since an undo removes them) are within [`TRUE_WITHIN`] of the reference; `None` without
/// one. Also returns the median edge's error against it `[m, deg]` (the edge with the
/// median translation error).
fn judge_edges(
    references: &BTreeMap<NodeId, Se2>,
    edges: &[(NodeId, NodeId, Se2)],
) -> Option<(bool, [f64; 2])> {
    let reference = |node: NodeId| references.get(&node).copied();
    let mut errors: Vec<(f64, f64)> = edges
        .iter()
        .filter_map(|(from, to, measurement)| {
            let (a, b) = (reference(*from)?, reference(*to)?);
            let error = a.between(&b).between(measurement);
            Some((error.translation().norm(), error.theta_rad.abs()))
        })
        .collect();
    if errors.is_empty() {
        return None;
    }
    let good = errors
        .iter()
        .filter(|(m, rad)| *m <= TRUE_WITHIN.0 && *rad <= TRUE_WITHIN.1)
        .count();
    errors.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (median_m, median_rad) = errors[errors.len() / 2];
    Some((2 * good > errors.len(), [median_m, median_rad.to_degrees()]))
}

/// `atlas --merge-results`: one `eval invalid-merge` result per judged merge and detector
/// reading, labelled by the truth, so that `eval calibrate --results` can fit the decision on
/// the engine's own merges. Ids are `group/run/mergeK`.
pub fn write_merge_results(
    merges: &[MergeReport],
    group: &str,
    run: &str,
    path: &Path,
) -> anyhow::Result<()> {
    let mut out = std::io::BufWriter::new(
        std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?,
    );
    for (k, merge) in merges.iter().enumerate() {
        let Some(correct) = merge.correct else {
            continue;
        };
        for reading in &merge.readings {
            let result = MergeResult {
                id: format!("{group}/{run}/merge{k}"),
                method: reading.method.clone(),
                max_invalidity: reading.peak_ratio,
                ms_per_vertex: None,
                vertices: reading.vertices,
                label: Some(if correct {
                    Label::Valid
                } else {
                    Label::Invalid
                }),
                kind: "engine".into(),
                log: group.to_owned(),
                supported_vertices: Some(reading.supported_vertices),
            };
            serde_json::to_writer(&mut out, &result)?;
            writeln!(out)?;
        }
    }
    out.flush()
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}
