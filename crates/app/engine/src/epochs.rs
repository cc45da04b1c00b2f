//! Why each later epoch did or did not merge, read from the engine's events: how many merge
//! hypotheses it formed, the most evidence one of them collected, and how it ended (the
//! stages of iRobot's Sec. 3.2.1 / 5.2: hypothesis, conditional merge, full merge).

use mapmerge_atlas::{AtlasEvent, EpochEndReason, EpochId};
use mapmerge_hypothesis::{FilterEvent, Target};
use serde::Serialize;

use crate::{EngineEvent, EventKind};

/// How far an epoch's merge hypotheses got.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum EpochEnd {
    /// A merge made in the epoch was still in place at its end.
    Merged,
    /// Merges were made but the last one was undone.
    MergeUndone,
    /// A conditional merge started but never became full.
    ConditionalNeverFull,
    /// Merge hypotheses formed but none became conditional.
    HypothesesNeverConditional,
    /// No merge hypothesis formed: place recognition verified no match.
    NoHypothesis,
}

/// One epoch's merge hypotheses and how it ended.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EpochOutcome {
    /// The epoch.
    pub epoch: EpochId,
    /// How it began: why the epoch before it ended (`kidnap` announced, `tracking_lost`
    /// detected, `restart`); null for the run's first epoch.
    pub started_by: Option<EpochEndReason>,
    /// Robot travel during the epoch (m, tracker estimate).
    pub travel_m: f64,
    /// Merge hypotheses created.
    pub hypotheses: usize,
    /// The most observations one of them collected …
    pub most_observations: usize,
    /// … and the most weighted observations (self-similar views weigh less).
    pub most_weighted_observations: f64,
    /// Conditional merges started.
    pub conditional_merges: usize,
    /// Merges made, and those undone.
    pub merges: usize,
    /// See `merges`.
    pub unmerges: usize,
    /// How far its hypotheses got.
    pub end: EpochEnd,
}

/// Every epoch's outcome, in order, from `events` (as [`crate::Engine::events`] returns
/// them); `travel_now_m` closes the last epoch. Events before the first epoch are ignored.
pub fn epoch_outcomes(events: &[EngineEvent], travel_now_m: f64) -> Vec<EpochOutcome> {
    let mut outcomes: Vec<EpochOutcome> = Vec::new();
    let mut started_at_m = 0.0;
    let mut merge_kept = false;
    let mut ended_by = None;
    for event in events {
        if let Some(AtlasEvent::EpochEnded { reason, .. }) = event.atlas() {
            ended_by = Some(reason.clone());
        }
        if let Some(AtlasEvent::EpochStarted { epoch }) = event.atlas() {
            close(
                outcomes.last_mut(),
                event.travel_m - started_at_m,
                merge_kept,
            );
            started_at_m = event.travel_m;
            merge_kept = false;
            outcomes.push(EpochOutcome {
                epoch: *epoch,
                started_by: ended_by.take(),
                travel_m: 0.0,
                hypotheses: 0,
                most_observations: 0,
                most_weighted_observations: 0.0,
                conditional_merges: 0,
                merges: 0,
                unmerges: 0,
                end: EpochEnd::NoHypothesis,
            });
            continue;
        }
        let Some(outcome) = outcomes.last_mut() else {
            continue;
        };
        match &event.event {
            EventKind::Atlas(AtlasEvent::Merged(_)) => {
                outcome.merges += 1;
                merge_kept = true;
            }
            EventKind::Atlas(AtlasEvent::Unmerged(_)) => {
                outcome.unmerges += 1;
                merge_kept = false;
            }
            EventKind::Hypothesis(filter) if matches!(filter.target(), Target::Merge { .. }) => {
                match filter {
                    FilterEvent::Created { .. } => {
                        outcome.hypotheses += 1;
                        outcome.most_observations = outcome.most_observations.max(1);
                    }
                    FilterEvent::Conditional { .. } => outcome.conditional_merges += 1,
                    _ => {}
                }
                if let Some(counts) = filter.counts() {
                    outcome.most_observations = outcome.most_observations.max(counts.observations);
                    outcome.most_weighted_observations = outcome
                        .most_weighted_observations
                        .max(counts.weighted_observations);
                }
            }
            _ => {}
        }
    }
    close(outcomes.last_mut(), travel_now_m - started_at_m, merge_kept);
    outcomes
}

/// Sets the epoch's travel and how it ended.
fn close(outcome: Option<&mut EpochOutcome>, travel_m: f64, merge_kept: bool) {
    let Some(outcome) = outcome else {
        return;
    };
    outcome.travel_m = travel_m.max(0.0);
    outcome.end = if merge_kept {
        EpochEnd::Merged
    } else if outcome.merges > 0 {
        EpochEnd::MergeUndone
    } else if outcome.conditional_merges > 0 {
        EpochEnd::ConditionalNeverFull
    } else if outcome.hypotheses > 0 {
        EpochEnd::HypothesesNeverConditional
    } else {
        EpochEnd::NoHypothesis
    };
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapmerge_hypothesis::{HypothesisCounts, HypothesisId, HypothesisState};

    fn at(travel_m: f64, event: EventKind) -> EngineEvent {
        EngineEvent {
            scan: 0,
            travel_m,
            event,
        }
    }

    fn started(epoch: u32, travel_m: f64) -> EngineEvent {
        at(
            travel_m,
            EventKind::Atlas(AtlasEvent::EpochStarted {
                epoch: EpochId(epoch),
            }),
        )
    }

    fn counts(observations: usize, weighted: f64) -> HypothesisCounts {
        HypothesisCounts {
            observations,
            weighted_observations: weighted,
            weighted_views: weighted,
            view_spread_m: 0.0,
        }
    }

    fn hypothesis(travel_m: f64, event: FilterEvent) -> EngineEvent {
        at(travel_m, EventKind::Hypothesis(event))
    }

    #[test]
    fn epochs_end_by_how_far_their_merge_hypotheses_got() {
        let merge = Target::Merge { map: 0 };
        let events = vec![
            // Before the first epoch: ignored.
            hypothesis(
                0.0,
                FilterEvent::Dropped {
                    id: HypothesisId(9),
                    target: merge,
                    counts: counts(7, 7.0),
                    previous: HypothesisState::Tentative,
                },
            ),
            started(0, 0.0),
            started(1, 10.0),
            hypothesis(
                12.0,
                FilterEvent::Created {
                    id: HypothesisId(0),
                    target: merge,
                    view: 1,
                    robot: 2,
                    travel_m: 12.0,
                    candidates: Vec::new(),
                },
            ),
            hypothesis(
                13.0,
                FilterEvent::Updated {
                    id: HypothesisId(0),
                    target: merge,
                    view: 3,
                    robot: 4,
                    mahalanobis_sq: 0.5,
                    counts: counts(2, 0.0),
                },
            ),
            // A recovery hypothesis is not a merge hypothesis.
            hypothesis(
                14.0,
                FilterEvent::Created {
                    id: HypothesisId(1),
                    target: Target::Recovery,
                    view: 5,
                    robot: 6,
                    travel_m: 14.0,
                    candidates: Vec::new(),
                },
            ),
            hypothesis(
                15.0,
                FilterEvent::Conditional {
                    id: HypothesisId(0),
                    target: merge,
                    counts: counts(3, 1.0),
                    superseded: None,
                },
            ),
            hypothesis(
                16.0,
                FilterEvent::Expired {
                    id: HypothesisId(0),
                    target: merge,
                    counts: counts(3, 1.0),
                    previous: HypothesisState::Conditional,
                    idle_travel_m: 30.0,
                    idle_s: None,
                    evicted: false,
                },
            ),
            started(2, 40.0),
        ];
        let outcomes = epoch_outcomes(&events, 55.0);
        assert_eq!(outcomes.len(), 3);
        let (first, second, third) = (&outcomes[0], &outcomes[1], &outcomes[2]);
        assert_eq!(
            (first.epoch, first.end),
            (EpochId(0), EpochEnd::NoHypothesis)
        );
        assert_eq!(first.hypotheses, 0);
        assert!((first.travel_m - 10.0).abs() < 1e-12);
        assert_eq!(second.end, EpochEnd::ConditionalNeverFull);
        assert_eq!(
            (
                second.hypotheses,
                second.most_observations,
                second.conditional_merges
            ),
            (1, 3, 1)
        );
        assert!((second.most_weighted_observations - 1.0).abs() < 1e-12);
        assert!((second.travel_m - 30.0).abs() < 1e-12);
        assert_eq!(third.end, EpochEnd::NoHypothesis);
        assert!((third.travel_m - 15.0).abs() < 1e-12);
        assert!(epoch_outcomes(&[], 3.0).is_empty());
    }
}
