//! What the filter reports: one serialisable event per change, and per observation an
//! outcome that also hands over an accepted hypothesis with its payloads.

use serde::{Deserialize, Serialize};

use crate::{Hypothesis, HypothesisCounts, HypothesisId, HypothesisState, Target};

/// Why a hypothesis was rejected.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum RejectReason {
    /// An invalid-merge detector found the conditional merge wrong.
    Detector {
        /// The detector's name.
        name: String,
        /// Its invalidity ratio in [0, 1].
        invalidity: f64,
    },
    /// A competitor won: it became conditional with more evidence, or was fully accepted.
    Superseded {
        /// The winner.
        by: HypothesisId,
    },
    /// Any other reason the caller gives.
    Caller {
        /// Free text.
        note: String,
    },
}

/// A live hypothesis of the observation's target and its squared Mahalanobis distance.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GateCandidate {
    /// The hypothesis.
    pub id: HypothesisId,
    /// `d²` of the observation against it (Eq. 6); infinite when it could not be computed.
    pub mahalanobis_sq: f64,
}

/// One change in the filter, serialisable as one JSON object (`"event": "created"`, …).
///
/// Every hypothesis ends in exactly one of `full`, `rejected`, `expired` or `dropped`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum FilterEvent {
    /// A new hypothesis from an observation no live hypothesis of its target gated (Eq. 4).
    Created {
        /// The new hypothesis.
        id: HypothesisId,
        /// Its target.
        target: Target,
        /// The observed view.
        view: u64,
        /// The robot's node.
        robot: u64,
        /// Robot travel (m).
        travel_m: f64,
        /// Every live hypothesis of the same target and its `d²`, none below the gate.
        candidates: Vec<GateCandidate>,
    },
    /// An observation updated a hypothesis (Eq. 6–8).
    Updated {
        /// The hypothesis.
        id: HypothesisId,
        /// Its target.
        target: Target,
        /// The observed view.
        view: u64,
        /// The robot's node.
        robot: u64,
        /// `d²` of the observation (Eq. 6).
        mahalanobis_sq: f64,
        /// Evidence after the update.
        counts: HypothesisCounts,
    },
    /// A merge hypothesis became the conditional merge (Sec. 5.2).
    Conditional {
        /// The hypothesis.
        id: HypothesisId,
        /// Its target.
        target: Target,
        /// Its evidence.
        counts: HypothesisCounts,
        /// The conditional hypothesis it replaced, reported as rejected just before.
        superseded: Option<HypothesisId>,
    },
    /// A hypothesis was accepted for good; the outcome carries it with its payloads.
    Full {
        /// The hypothesis.
        id: HypothesisId,
        /// Its target.
        target: Target,
        /// Its evidence.
        counts: HypothesisCounts,
        /// Its state before (tentative or conditional).
        previous: HypothesisState,
    },
    /// A hypothesis was rejected and removed.
    Rejected {
        /// The hypothesis.
        id: HypothesisId,
        /// Its target.
        target: Target,
        /// Its evidence.
        counts: HypothesisCounts,
        /// Its state before.
        previous: HypothesisState,
        /// Why.
        reason: RejectReason,
    },
    /// A hypothesis went unobserved too long, or was evicted by `max_hypotheses`, and was
    /// removed. A conditional one also counts in [`FilterStats::rejected_conditional`].
    Expired {
        /// The hypothesis.
        id: HypothesisId,
        /// Its target.
        target: Target,
        /// Its evidence.
        counts: HypothesisCounts,
        /// Its state before.
        previous: HypothesisState,
        /// Travel since its last observation (m).
        idle_travel_m: f64,
        /// Time since its last observation (s), when both times are known.
        idle_s: Option<f64>,
        /// True when evicted to respect `max_hypotheses` rather than by age.
        evicted: bool,
    },
    /// A hypothesis was removed because another was fully accepted (a tentative competitor)
    /// or the epoch ended ([`crate::HypothesisFilter::clear`]).
    Dropped {
        /// The hypothesis.
        id: HypothesisId,
        /// Its target.
        target: Target,
        /// Its evidence.
        counts: HypothesisCounts,
        /// Its state before.
        previous: HypothesisState,
    },
}

impl FilterEvent {
    /// The hypothesis the event is about.
    pub fn id(&self) -> HypothesisId {
        self.parts().0
    }

    /// The hypothesis' target.
    pub fn target(&self) -> Target {
        self.parts().1
    }

    /// The hypothesis' evidence after the event (none when it was just created: one
    /// observation).
    pub fn counts(&self) -> Option<&HypothesisCounts> {
        self.parts().2
    }

    /// The fields every variant has: id, target and (except `Created`) counts.
    fn parts(&self) -> (HypothesisId, Target, Option<&HypothesisCounts>) {
        match self {
            Self::Created { id, target, .. } => (*id, *target, None),
            Self::Updated {
                id, target, counts, ..
            }
            | Self::Conditional {
                id, target, counts, ..
            }
            | Self::Full {
                id, target, counts, ..
            }
            | Self::Rejected {
                id, target, counts, ..
            }
            | Self::Expired {
                id, target, counts, ..
            }
            | Self::Dropped {
                id, target, counts, ..
            } => (*id, *target, Some(counts)),
        }
    }
}

/// What one observation did.
#[derive(Clone, Debug, PartialEq)]
pub struct ObserveOutcome<E> {
    /// The hypothesis the observation went into.
    pub hypothesis: HypothesisId,
    /// True when the observation started it.
    pub created: bool,
    /// `d²` against the updated hypothesis; `None` when created.
    pub mahalanobis_sq: Option<f64>,
    /// Every live hypothesis of the observation's target and its `d²`.
    pub candidates: Vec<GateCandidate>,
    /// The hypothesis' state afterwards.
    pub state: HypothesisState,
    /// True when this observation made it the conditional merge: read its edges with
    /// [`crate::HypothesisFilter::conditional`].
    pub conditional_started: bool,
    /// The fully accepted hypothesis with its observations and payloads, no longer live.
    pub accepted: Option<Hypothesis<E>>,
    /// Everything that changed, in order.
    pub events: Vec<FilterEvent>,
}

/// What [`crate::HypothesisFilter::count_again`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct Reconsidered<E> {
    /// Observations that count in full again.
    pub changed: usize,
    /// True when the hypothesis became the conditional merge.
    pub conditional_started: bool,
    /// The fully accepted hypothesis, no longer live.
    pub accepted: Option<Hypothesis<E>>,
    /// Everything that changed, in order.
    pub events: Vec<FilterEvent>,
}

/// Cumulative counts since the filter was made.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct FilterStats {
    /// Hypotheses created.
    pub created: u64,
    /// … of which merge hypotheses.
    pub merge: u64,
    /// … of which recovery hypotheses.
    pub recovery: u64,
    /// Times a hypothesis became conditional.
    pub conditional: u64,
    /// Hypotheses fully accepted.
    pub full: u64,
    /// Conditional merges that ended without full acceptance: rejected (by the caller, a
    /// detector or a competitor), expired, evicted or dropped by `clear`.
    pub rejected_conditional: u64,
    /// Hypotheses expired, evictions included.
    pub expired: u64,
}

impl FilterStats {
    /// The counts `events` add up to: a filter's events since it was made give its
    /// [`crate::HypothesisFilter::stats`], so a caller that logs them needs no counters.
    pub fn of_events<'a>(events: impl IntoIterator<Item = &'a FilterEvent>) -> Self {
        let mut stats = Self::default();
        for event in events {
            let ended_conditional = match event {
                FilterEvent::Created { target, .. } => {
                    stats.created += 1;
                    match target {
                        Target::Merge { .. } => stats.merge += 1,
                        Target::Recovery => stats.recovery += 1,
                    }
                    false
                }
                FilterEvent::Updated { .. } => false,
                FilterEvent::Conditional { .. } => {
                    stats.conditional += 1;
                    false
                }
                FilterEvent::Full { .. } => {
                    stats.full += 1;
                    false
                }
                FilterEvent::Expired { previous, .. } => {
                    stats.expired += 1;
                    *previous == HypothesisState::Conditional
                }
                FilterEvent::Rejected { previous, .. } | FilterEvent::Dropped { previous, .. } => {
                    *previous == HypothesisState::Conditional
                }
            };
            if ended_conditional {
                stats.rejected_conditional += 1;
            }
        }
        stats
    }
}
