//! Every mutation of the atlas is an event with a reason (STYLE: reversibility as a value);
//! the event log is one JSON object per line (`events.jsonl`).

use std::io::{BufRead, Write};

use mapmerge_geometry::Se2;
use mapmerge_posegraph::NodeId;
use serde::{Deserialize, Serialize};

use crate::error::AtlasError;
use crate::ids::{EpochId, MapId, MergeId};

/// Why an epoch ended (Holoch et al., Sec. III: kidnap, restart, tracking failure).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EpochEndReason {
    /// The robot was carried somewhere else.
    Kidnap,
    /// The robot was switched off and on again (a new log or session).
    Restart,
    /// The engine noticed it lost track (its tracking-failure detector: failed matching, a
    /// jump against the odometry, a gap in the stamps), or the caller says so.
    #[serde(alias = "tracking_failure")]
    TrackingLost,
    /// Anything else, in words.
    Other(String),
}

/// Why a merge happened.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum MergeReason {
    /// Place recognition found the active graph in the inactive one (Sec. III-A).
    PlaceRecognition {
        /// Verified loops that agree on the transform.
        loops: usize,
        /// Best verification score among them.
        score: f64,
        /// Best confidence among them (gap to the best rival place).
        confidence: f64,
    },
    /// The caller forced the merge (evaluation cases, the CLI, a human).
    Forced {
        /// Free text: which case, which command.
        note: String,
    },
}

/// Why merges were undone.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum UnmergeReason {
    /// An invalid-merge detector fired (Sec. IV).
    InvalidMerge {
        /// The detector's name.
        detector: String,
        /// Its invalidity ratio in `[0, 1]`.
        invalidity: f64,
    },
    /// The caller asked for it.
    Requested {
        /// Free text.
        note: String,
    },
    /// The epoch's edges to the epochs merged into it disagree with the optimised graph
    /// ([`crate::Atlas::epoch_agreement`]; issue 64, part 4).
    InconsistentEpochs {
        /// Edges the graph satisfies, those it does not, and of those the merges' own.
        agreeing_edges: usize,
        disagreeing_edges: usize,
        disagreeing_merge_edges: usize,
        /// The largest translation residual of a disagreeing edge (m).
        worst_off_m: f64,
    },
}

impl UnmergeReason {
    /// One line for reports.
    pub fn summary(&self) -> String {
        match self {
            Self::InvalidMerge {
                detector,
                invalidity,
            } => format!("{detector} invalidity {invalidity:.2}"),
            Self::Requested { note } => note.clone(),
            Self::InconsistentEpochs {
                agreeing_edges,
                disagreeing_edges,
                disagreeing_merge_edges,
                worst_off_m,
            } => format!(
                "epochs disagree: {disagreeing_merge_edges} merge edges ({disagreeing_edges} of {} \
                 edges) unsatisfied, up to {worst_off_m:.2} m",
                agreeing_edges + disagreeing_edges
            ),
        }
    }
}

/// What one merge did (Sec. III-A).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MergeEvent {
    /// The merge (and its backup's) id.
    pub merge: MergeId,
    /// The current epoch (the active graph's).
    pub active_epoch: EpochId,
    /// The inactive graph merged in.
    pub map: MapId,
    /// Its epochs.
    pub merged_epochs: Vec<EpochId>,
    /// Vertices it brought.
    pub merged_vertices: usize,
    /// Loop edges given with the merge (from recognition or the caller; a synthetic one when
    /// the caller gave a transform only).
    pub loop_edges: usize,
    /// Further loop edges found in the overlap after the merge.
    pub overlap_edges: usize,
    /// `active_from_inactive` applied to the inactive graph, `[x_m, y_m, yaw_rad]`.
    pub active_from_inactive: [f64; 3],
    /// Why.
    pub reason: MergeReason,
    /// Chi2 of the active graph before and after the re-optimisation.
    pub chi2: [f64; 2],
}

/// What one unmerge did (Sec. III-B: *all* merges into the active graph are undone).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct UnmergeEvent {
    /// The current epoch (the active graph's).
    pub active_epoch: EpochId,
    /// The merges undone, oldest first.
    pub merges: Vec<MergeId>,
    /// The inactive graphs restored from their backups.
    pub restored_maps: Vec<MapId>,
    /// The transforms those merges had applied (`active_from_inactive`, `[x_m, y_m,
    /// yaw_rad]`), in the same order.
    #[serde(default)]
    pub undone_transforms: Vec<[f64; 3]>,
    /// Other-epoch vertices removed from the active graph.
    pub removed_vertices: usize,
    /// Edges removed with them.
    pub removed_edges: usize,
    /// Why.
    pub reason: UnmergeReason,
}

/// One mutation of the atlas, as written to `events.jsonl`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum AtlasEvent {
    /// A new epoch (and an empty active graph) started.
    EpochStarted {
        /// The new epoch.
        epoch: EpochId,
    },
    /// The epoch ended: the active graph became inactive map `map` (none when it was empty),
    /// and the merges into it became final (their backups were dropped).
    EpochEnded {
        /// The epoch that ended.
        epoch: EpochId,
        /// Why.
        reason: EpochEndReason,
        /// The inactive graph it became.
        map: Option<MapId>,
        /// Merges that can no longer be undone.
        finalized_merges: Vec<MergeId>,
    },
    /// An inactive graph was merged into the active graph.
    Merged(MergeEvent),
    /// Every merge into the active graph was undone.
    Unmerged(UnmergeEvent),
    /// A fragment (an inactive graph) joined the site map at a session's end.
    Rejoined(crate::rejoin::RejoinEvent),
    /// A vertex was pruned (with its edges and scan).
    Pruned {
        /// The vertex.
        node: NodeId,
        /// Its epoch.
        epoch: EpochId,
        /// The inactive graph it was in, none for the active graph.
        map: Option<MapId>,
    },
}

/// `[x_m, y_m, yaw_rad]` of a pose, the event log's (and the merge cases') transform format.
pub fn pose_array(pose: &Se2) -> [f64; 3] {
    [pose.x_m, pose.y_m, pose.theta_rad]
}

/// Writes events as JSON lines.
pub struct EventLogWriter<W: Write> {
    out: W,
}

impl<W: Write> EventLogWriter<W> {
    /// A writer into `out` (a file, a buffer).
    pub fn new(out: W) -> Self {
        Self { out }
    }

    /// Appends one event as one line and flushes.
    pub fn write(&mut self, event: &AtlasEvent) -> Result<(), AtlasError> {
        serde_json::to_writer(&mut self.out, event)
            .map_err(|source| AtlasError::Event { line: 0, source })?;
        let io = |source| AtlasError::Io {
            path: "events.jsonl".into(),
            source,
        };
        self.out.write_all(b"\n").map_err(io)?;
        self.out.flush().map_err(io)
    }

    /// The underlying writer.
    pub fn into_inner(self) -> W {
        self.out
    }
}

/// Reads an event log (blank lines skipped).
pub fn read_events(input: impl BufRead) -> Result<Vec<AtlasEvent>, AtlasError> {
    let mut events = Vec::new();
    for (index, line) in input.lines().enumerate() {
        let line = line.map_err(|source| AtlasError::Io {
            path: "events.jsonl".into(),
            source,
        })?;
        if line.trim().is_empty() {
            continue;
        }
        events.push(
            serde_json::from_str(&line).map_err(|source| AtlasError::Event {
                line: index + 1,
                source,
            })?,
        );
    }
    Ok(events)
}
