//! The hypothesis filter's behaviour through its public API.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use approx::assert_relative_eq;

use std::collections::BTreeSet;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_hypothesis::{
    AcceptanceCriteria, FilterEvent, FilterStats, HypothesisError, HypothesisFilter,
    HypothesisFilterParams, HypothesisId, HypothesisState, Observation, RejectReason, Target,
};
use nalgebra::{Matrix3, Vector3};

const MAP_1: Target = Target::Merge { map: 1 };
const MAP_2: Target = Target::Merge { map: 2 };

fn covariance() -> Matrix3<f64> {
    // σ = 0.1 m, 0.05 rad.
    Matrix3::from_diagonal(&Vector3::new(0.01, 0.01, 0.0025))
}

fn seen(target: Target, view: u64, robot_from_target: Se2) -> Observation<u64> {
    Observation {
        target,
        view,
        robot: 1000 + view,
        robot_from_target,
        covariance: covariance(),
        ambiguous: false,
        edge: view,
    }
}

/// [`seen`] of a view that fits elsewhere in its own map too (ambiguous).
fn seen_ambiguous(target: Target, view: u64, robot_from_target: Se2) -> Observation<u64> {
    Observation {
        ambiguous: true,
        ..seen(target, view, robot_from_target)
    }
}

fn filter() -> HypothesisFilter<u64> {
    HypothesisFilter::new(HypothesisFilterParams::default()).unwrap()
}

fn at() -> Se2 {
    Se2::new(4.0, -1.0, 0.7)
}

/// Observes `views` of `target` at pose `pose`, one per travel step `step_m` from `start_m`.
fn observe_views(
    f: &mut HypothesisFilter<u64>,
    target: Target,
    pose: Se2,
    views: &[u64],
    start_m: f64,
    step_m: f64,
) -> Vec<mapmerge_hypothesis::ObserveOutcome<u64>> {
    views
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            f.observe(seen(target, v, pose), start_m + step_m * i as f64, None)
                .unwrap()
        })
        .collect()
}

#[test]
fn consistent_observation_updates_and_a_distant_one_starts_another() {
    let mut f = filter();
    let first = f.observe(seen(MAP_1, 10, at()), 0.0, None).unwrap();
    assert!(first.created);
    assert_eq!(first.mahalanobis_sq, None);
    let h = first.hypothesis;
    let before = *f.hypothesis(h).unwrap().covariance();

    let nearby = Se2::exp(&Vector3::new(0.05, -0.03, 0.02)).compose(&at());
    let second = f.observe(seen(MAP_1, 11, nearby), 0.0, None).unwrap();
    assert!(!second.created);
    assert_eq!(second.hypothesis, h);
    let d2 = second.mahalanobis_sq.unwrap();
    assert!(d2 > 0.0 && d2 < 11.345, "{d2}");
    // Equal covariances: the estimate lands halfway, the covariance halves.
    let hypothesis = f.hypothesis(h).unwrap();
    let halfway = Se2::exp(&Vector3::new(0.025, -0.015, 0.01)).compose(&at());
    assert!(
        hypothesis
            .robot_from_target()
            .between(&halfway)
            .log()
            .norm()
            < 1e-3
    );
    assert_relative_eq!(*hypothesis.covariance(), before * 0.5, epsilon = 1e-12);

    // 2 m and 30° away from the estimate.
    let far = Se2::exp(&Vector3::new(2.0, 0.0, 30f64.to_radians())).compose(&at());
    let third = f.observe(seen(MAP_1, 12, far), 0.0, None).unwrap();
    assert!(third.created);
    assert_ne!(third.hypothesis, h);
    assert_eq!(third.candidates.len(), 1);
    assert_eq!(third.candidates[0].id, h);
    assert!(third.candidates[0].mahalanobis_sq > 100.0);
    match &third.events[..] {
        [FilterEvent::Created { candidates, .. }] => assert_eq!(candidates, &third.candidates),
        other => panic!("{other:?}"),
    }
    assert_eq!(f.len(), 2);
}

#[test]
fn different_targets_never_share_a_hypothesis() {
    let mut f = filter();
    let ids: Vec<HypothesisId> = [MAP_1, MAP_2, Target::Recovery]
        .into_iter()
        .map(|t| {
            let outcome = f.observe(seen(t, 10, at()), 0.0, None).unwrap();
            assert!(outcome.created);
            assert!(outcome.candidates.is_empty(), "{:?}", outcome.candidates);
            outcome.hypothesis
        })
        .collect();
    assert_eq!(ids.iter().collect::<BTreeSet<_>>().len(), 3);
    let stats = f.stats();
    assert_eq!((stats.created, stats.merge, stats.recovery), (3, 2, 1));
}

#[test]
fn gating_updates_the_nearest_hypothesis_below_the_gate() {
    let mut f = filter();
    let near = f
        .observe(seen(MAP_1, 1, Se2::new(1.0, 0.0, 0.0)), 0.0, None)
        .unwrap()
        .hypothesis;
    let far = f
        .observe(seen(MAP_1, 2, Se2::new(0.0, 0.0, 0.0)), 0.0, None)
        .unwrap();
    assert!(far.created, "1 m apart with σ = 0.1 m must not gate");
    // A vague observation both gate; the nearer one takes it.
    let mut vague = seen(MAP_1, 3, Se2::new(0.7, 0.0, 0.0));
    vague.covariance = Matrix3::from_diagonal(&Vector3::new(0.25, 0.25, 0.01));
    let outcome = f.observe(vague, 0.0, None).unwrap();
    assert_eq!(outcome.candidates.len(), 2);
    assert!(outcome.candidates.iter().all(|c| c.mahalanobis_sq < 11.345));
    assert_eq!(outcome.hypothesis, near);
}

#[test]
fn prediction_moves_every_hypothesis_with_the_robot() {
    let mut f = filter();
    let h = f
        .observe(seen(MAP_1, 1, at()), 0.0, None)
        .unwrap()
        .hypothesis;
    let step = Se2::new(0.8, 0.1, 0.3);
    let step_covariance = Matrix3::from_diagonal(&Vector3::new(1e-3, 1e-3, 1e-4));
    let events = f.predict(&step, &step_covariance, 0.8, None).unwrap();
    assert!(events.is_empty());
    let moved = f.hypothesis(h).unwrap();
    let expected = step.inverse().compose(&at());
    assert!(moved.robot_from_target().between(&expected).log().norm() < 1e-12);
    let ad = step.inverse().adjoint();
    let expected_cov = ad * covariance() * ad.transpose() + step_covariance;
    assert_relative_eq!(*moved.covariance(), expected_cov, epsilon = 1e-12);
    // The map seen from the new robot pose gates into the moved hypothesis.
    let outcome = f.observe(seen(MAP_1, 2, expected), 0.8, None).unwrap();
    assert_eq!(outcome.hypothesis, h);
}

#[test]
fn conditional_after_two_views_then_full_after_the_strict_criteria() {
    let mut f = filter();
    let outcomes = observe_views(&mut f, MAP_1, at(), &[10, 10], 0.0, 0.5);
    assert!(outcomes
        .iter()
        .all(|o| o.state == HypothesisState::Tentative));
    let third = f.observe(seen(MAP_1, 11, at()), 1.0, None).unwrap();
    assert!(third.conditional_started);
    assert_eq!(third.state, HypothesisState::Conditional);
    assert!(matches!(
        third.events.last(),
        Some(FilterEvent::Conditional {
            superseded: None,
            ..
        })
    ));
    assert_eq!(f.conditional().unwrap().id(), third.hypothesis);

    // 4 views and 5 observations, but spread over 1.5 m only: still conditional.
    let more = observe_views(&mut f, MAP_1, at(), &[12, 13], 1.2, 0.3);
    assert!(more
        .iter()
        .all(|o| o.state == HypothesisState::Conditional && !o.conditional_started));
    assert_eq!(
        f.hypothesis(third.hypothesis)
            .unwrap()
            .counts(0.0)
            .view_spread_m,
        1.5
    );
    // Another view 2.5 m after the first: full.
    let last = f.observe(seen(MAP_1, 14, at()), 2.5, None).unwrap();
    assert_eq!(last.state, HypothesisState::Full);
    let accepted = last.accepted.unwrap();
    assert_eq!(accepted.state(), HypothesisState::Full);
    assert_eq!(
        accepted.edges().copied().collect::<Vec<_>>(),
        vec![10, 10, 11, 12, 13, 14]
    );
    assert!(matches!(
        last.events.last(),
        Some(FilterEvent::Full {
            previous: HypothesisState::Conditional,
            ..
        })
    ));
    assert!(f.is_empty() && f.conditional().is_none());
    let stats = f.stats();
    assert_eq!(
        (stats.conditional, stats.full, stats.rejected_conditional),
        (1, 1, 0)
    );
}

#[test]
fn ambiguous_observations_update_but_do_not_count() {
    let mut f = filter();
    for (i, view) in [10, 11, 12, 13, 14, 15].into_iter().enumerate() {
        let outcome = f
            .observe(seen_ambiguous(MAP_1, view, at()), i as f64, None)
            .unwrap();
        assert_eq!(outcome.state, HypothesisState::Tentative);
        assert_eq!(outcome.created, i == 0);
    }
    let h = f.hypotheses().next().unwrap();
    let counts = h.counts(0.0);
    assert_eq!(
        (
            counts.observations,
            counts.weighted_observations,
            counts.weighted_views
        ),
        (6, 0.0, 0.0)
    );
    // The EKF still used them.
    assert!(h.covariance()[(0, 0)] < 0.01 / 5.0);
    // One non-ambiguous observation counts one, not more.
    let outcome = f.observe(seen(MAP_1, 16, at()), 6.0, None).unwrap();
    assert_eq!(outcome.state, HypothesisState::Tentative);

    // With weight 1 the same sequence is accepted at the fifth observation.
    let mut f = HypothesisFilter::<u64>::new(HypothesisFilterParams {
        ambiguous_weight: 1.0,
        ..HypothesisFilterParams::default()
    })
    .unwrap();
    let states: Vec<HypothesisState> = (0..5)
        .map(|i| {
            f.observe(seen_ambiguous(MAP_1, 10 + i, at()), i as f64, None)
                .unwrap()
                .state
        })
        .collect();
    assert_eq!(states[4], HypothesisState::Full);
}

#[test]
fn views_found_ambiguous_later_are_discounted() {
    let mut f = filter();
    observe_views(&mut f, MAP_1, at(), &[10], 0.0, 1.0);
    let ambiguous: BTreeSet<u64> = [10].into();
    assert_eq!(f.discount_views(&ambiguous), 1);
    // Another view: one counting view, not two.
    let outcome = f.observe(seen(MAP_1, 11, at()), 1.0, None).unwrap();
    assert_eq!(outcome.state, HypothesisState::Tentative);
}

#[test]
fn views_counted_again_make_a_hypothesis_conditional_and_then_full() {
    let mut f = filter();
    // Two ambiguous views, then a third: nothing counts yet.
    let ids: Vec<HypothesisId> = (0..3)
        .map(|i| {
            f.observe(seen_ambiguous(MAP_1, 10 + i, at()), i as f64, None)
                .unwrap()
                .hypothesis
        })
        .collect();
    let h = ids[0];
    assert!(ids.iter().all(|id| *id == h));
    assert_eq!(f.hypothesis(h).unwrap().state(), HypothesisState::Tentative);
    // Views 10 and 11 count again: 2 views, 2 observations, conditional.
    let again = f.count_again(h, |o| [10, 11].contains(&o.view)).unwrap();
    assert_eq!(again.changed, 2);
    assert!(again.conditional_started);
    assert!(again.accepted.is_none());
    assert!(matches!(
        again.events[..],
        [FilterEvent::Conditional { id, .. }] if id == h
    ));
    // Counting them again changes nothing.
    let same = f.count_again(h, |o| [10, 11].contains(&o.view)).unwrap();
    assert_eq!((same.changed, same.conditional_started), (0, false));
    assert!(same.events.is_empty());
    // Two more counting views and view 12 again: 5 observations of 5 views over 4 m, full.
    observe_views(&mut f, MAP_1, at(), &[13, 14], 3.0, 1.0);
    let full = f.count_again(h, |o| [12].contains(&o.view)).unwrap();
    assert_eq!(
        full.accepted.map(|a| a.state()),
        Some(HypothesisState::Full)
    );
    // Not live any more.
    assert!(f.count_again(h, |o| [10].contains(&o.view)).is_none());
}

#[test]
fn only_one_conditional_and_a_stronger_competitor_supersedes_it() {
    let mut f = filter();
    let a = observe_views(&mut f, MAP_1, at(), &[10, 11], 0.0, 0.1)[1].hypothesis;
    assert_eq!(f.conditional().unwrap().id(), a);
    // B ties A (2 views, 2 observations): A stays.
    let other = Se2::new(-3.0, 2.0, -1.0);
    let b = observe_views(&mut f, MAP_2, other, &[20, 21], 0.2, 0.1);
    assert!(!b[1].conditional_started);
    assert_eq!(b[1].state, HypothesisState::Tentative);
    assert_eq!(f.conditional().unwrap().id(), a);
    // A third view for B: more views, B wins over.
    let b3 = f.observe(seen(MAP_2, 22, other), 0.4, None).unwrap();
    assert!(b3.conditional_started);
    match &b3.events[..] {
        [FilterEvent::Updated { .. }, FilterEvent::Rejected {
            id,
            previous,
            reason,
            ..
        }, FilterEvent::Conditional { superseded, .. }] => {
            assert_eq!(*id, a);
            assert_eq!(*previous, HypothesisState::Conditional);
            assert_eq!(*reason, RejectReason::Superseded { by: b3.hypothesis });
            assert_eq!(*superseded, Some(a));
        }
        other => panic!("{other:?}"),
    }
    assert!(f.hypothesis(a).is_none());
    assert_eq!(f.conditional().unwrap().id(), b3.hypothesis);
    assert_eq!(
        f.hypotheses()
            .filter(|h| h.state() == HypothesisState::Conditional)
            .count(),
        1
    );
    assert_eq!(f.stats().rejected_conditional, 1);
    assert_eq!(f.stats().conditional, 2);
}

#[test]
fn equal_views_and_more_observations_supersede() {
    let mut f = filter();
    let a = observe_views(&mut f, MAP_1, at(), &[10, 11], 0.0, 0.1)[1].hypothesis;
    let other = Se2::new(-3.0, 2.0, -1.0);
    let b = observe_views(&mut f, MAP_2, other, &[20, 20, 21], 0.2, 0.1);
    assert!(b[2].conditional_started);
    assert!(f.hypothesis(a).is_none());
}

#[test]
fn recovery_hypotheses_skip_the_conditional_state() {
    let mut f = filter();
    // The recovery criteria (10 observations of 8 views over 5 m), stricter than a merge's.
    let views: Vec<u64> = (1..=10).collect();
    let outcomes = observe_views(&mut f, Target::Recovery, at(), &views, 0.0, 0.6);
    let states: Vec<_> = outcomes.iter().map(|o| o.state).collect();
    assert_eq!(&states[..9], &[HypothesisState::Tentative; 9]);
    assert_eq!(states[9], HypothesisState::Full);
    assert!(outcomes.iter().all(|o| !o.conditional_started));
    assert_eq!(f.stats().conditional, 0);
}

#[test]
fn full_acceptance_removes_every_competitor() {
    let mut f = filter();
    let conditional = observe_views(&mut f, MAP_1, at(), &[10, 11], 0.0, 0.1)[1].hypothesis;
    let recovery = f
        .observe(seen(Target::Recovery, 5, Se2::identity()), 0.3, None)
        .unwrap()
        .hypothesis;
    let other = Se2::new(-3.0, 2.0, -1.0);
    let winner = observe_views(&mut f, MAP_2, other, &[20, 21, 22, 23, 24], 1.0, 0.6);
    let last = winner.last().unwrap();
    assert_eq!(last.state, HypothesisState::Full);
    // It went conditional at its third view on the way.
    assert!(winner[2].conditional_started);
    assert!(f.is_empty());
    let all_events: Vec<&FilterEvent> = winner.iter().flat_map(|o| &o.events).collect();
    assert!(all_events.iter().any(|e| matches!(e,
        FilterEvent::Rejected { id, reason: RejectReason::Superseded { .. }, .. } if *id == conditional)));
    assert!(last.events.iter().any(|e| matches!(e,
        FilterEvent::Dropped { id, previous: HypothesisState::Tentative, .. } if *id == recovery)));
}

#[test]
fn full_acceptance_rejects_the_conditional_competitor_as_superseded() {
    // A strict full criterion reached in one go by a hypothesis that never was conditional.
    let params = HypothesisFilterParams {
        conditional: AcceptanceCriteria {
            min_observations: 2,
            min_distinct_views: 2,
            min_view_spread_m: 0.0,
        },
        full: AcceptanceCriteria {
            min_observations: 2,
            min_distinct_views: 2,
            min_view_spread_m: 1.0,
        },
        ..HypothesisFilterParams::default()
    };
    let mut f = HypothesisFilter::<u64>::new(params).unwrap();
    let a = observe_views(&mut f, MAP_1, at(), &[10, 11], 0.0, 0.1)[1].hypothesis;
    assert_eq!(f.conditional().unwrap().id(), a);
    let other = Se2::new(-3.0, 2.0, -1.0);
    let b = observe_views(&mut f, MAP_2, other, &[20, 21], 0.2, 1.0);
    assert_eq!(b[1].state, HypothesisState::Full);
    match &b[1].events[..] {
        [FilterEvent::Updated { .. }, FilterEvent::Full {
            previous: HypothesisState::Tentative,
            ..
        }, FilterEvent::Rejected { id, reason, .. }] => {
            assert_eq!(*id, a);
            assert_eq!(
                *reason,
                RejectReason::Superseded {
                    by: b[1].hypothesis
                }
            );
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(f.stats().rejected_conditional, 1);
}

#[test]
fn the_caller_rejects_the_conditional_merge() {
    let mut f = filter();
    let a = observe_views(&mut f, MAP_1, at(), &[10, 11], 0.0, 0.1)[1].hypothesis;
    let other = Se2::new(-3.0, 2.0, -1.0);
    let b = observe_views(&mut f, MAP_2, other, &[20, 21], 0.2, 0.1)[1].hypothesis;
    let reason = RejectReason::Detector {
        name: "combined".into(),
        invalidity: 0.8,
    };
    let event = f.reject(a, reason.clone()).unwrap();
    assert_eq!(
        event,
        FilterEvent::Rejected {
            id: a,
            target: MAP_1,
            counts: event_counts(&event),
            previous: HypothesisState::Conditional,
            reason,
        }
    );
    assert!(f.conditional().is_none());
    assert!(f
        .reject(
            a,
            RejectReason::Caller {
                note: "again".into()
            }
        )
        .is_none());
    assert_eq!(f.stats().rejected_conditional, 1);
    // The tentative competitor that already qualifies takes over at its next observation.
    let next = f.observe(seen(MAP_2, 20, other), 0.5, None).unwrap();
    assert_eq!(next.hypothesis, b);
    assert!(next.conditional_started);
}

fn event_counts(event: &FilterEvent) -> mapmerge_hypothesis::HypothesisCounts {
    match event {
        FilterEvent::Rejected { counts, .. } => *counts,
        other => panic!("{other:?}"),
    }
}

#[test]
fn hypotheses_expire_after_travel_without_observations() {
    let mut f = filter();
    let h = observe_views(&mut f, MAP_1, at(), &[10, 11], 0.0, 1.0)[1].hypothesis;
    assert_eq!(f.conditional().unwrap().id(), h);
    let small = Matrix3::from_diagonal_element(1e-6);
    let stay = Se2::identity();
    assert!(f.predict(&stay, &small, 10.9, None).unwrap().is_empty());
    let events = f.predict(&stay, &small, 11.1, None).unwrap();
    match &events[..] {
        [FilterEvent::Expired {
            id,
            previous,
            idle_travel_m,
            evicted,
            ..
        }] => {
            assert_eq!(*id, h);
            assert_eq!(*previous, HypothesisState::Conditional);
            assert!((idle_travel_m - 10.1).abs() < 1e-9);
            assert!(!evicted);
        }
        other => panic!("{other:?}"),
    }
    assert!(f.is_empty());
    let stats = f.stats();
    assert_eq!((stats.expired, stats.rejected_conditional), (1, 1));
}

#[test]
fn a_stale_hypothesis_expires_before_it_could_take_an_observation() {
    let mut f = filter();
    let old = f
        .observe(seen(MAP_1, 10, at()), 0.0, None)
        .unwrap()
        .hypothesis;
    let outcome = f.observe(seen(MAP_1, 11, at()), 20.0, None).unwrap();
    assert!(outcome.created);
    assert_ne!(outcome.hypothesis, old);
    assert!(matches!(
        &outcome.events[..],
        [FilterEvent::Expired { .. }, FilterEvent::Created { .. }]
    ));
}

#[test]
fn hypotheses_expire_after_time_when_times_are_given() {
    let mut f = HypothesisFilter::<u64>::new(HypothesisFilterParams {
        expire_after_s: Some(30.0),
        ..HypothesisFilterParams::default()
    })
    .unwrap();
    f.observe(seen(MAP_1, 10, at()), 0.0, Some(100.0)).unwrap();
    let small = Matrix3::from_diagonal_element(1e-6);
    let stay = Se2::identity();
    assert!(f
        .predict(&stay, &small, 0.1, Some(129.0))
        .unwrap()
        .is_empty());
    assert!(
        f.predict(&stay, &small, 0.1, None).unwrap().is_empty(),
        "no time, no time expiry"
    );
    let events = f.predict(&stay, &small, 0.2, Some(131.0)).unwrap();
    match &events[..] {
        [FilterEvent::Expired {
            idle_s: Some(idle), ..
        }] => assert!((idle - 31.0).abs() < 1e-9),
        other => panic!("{other:?}"),
    }
    // Without `expire_after_s` time alone never expires.
    let mut f = filter();
    f.observe(seen(MAP_1, 10, at()), 0.0, Some(0.0)).unwrap();
    assert!(f.predict(&stay, &small, 0.1, Some(1e6)).unwrap().is_empty());
}

#[test]
fn the_stalest_hypothesis_is_evicted_beyond_max_hypotheses() {
    let mut f = HypothesisFilter::<u64>::new(HypothesisFilterParams {
        max_hypotheses: 3,
        ..HypothesisFilterParams::default()
    })
    .unwrap();
    let pose = |k: u64| Se2::new(k as f64 * 3.0, 0.0, 0.0);
    let ids: Vec<HypothesisId> = (0..3)
        .map(|k| {
            f.observe(seen(MAP_1, k, pose(k)), k as f64, None)
                .unwrap()
                .hypothesis
        })
        .collect();
    let fourth = f.observe(seen(MAP_1, 3, pose(3)), 3.0, None).unwrap();
    match &fourth.events[..] {
        [FilterEvent::Created { .. }, FilterEvent::Expired {
            id,
            evicted: true,
            idle_travel_m,
            ..
        }] => {
            assert_eq!(*id, ids[0]);
            assert_eq!(*idle_travel_m, 3.0);
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(f.len(), 3);
    // Refresh the oldest survivor; the next eviction takes the one after it.
    f.observe(seen(MAP_1, 11, pose(1)), 4.0, None).unwrap();
    let fifth = f.observe(seen(MAP_1, 4, pose(4)), 5.0, None).unwrap();
    assert!(fifth.events.iter().any(|e| matches!(e,
        FilterEvent::Expired { id, evicted: true, .. } if *id == ids[2])));
    assert_eq!(f.stats().expired, 2);
}

#[test]
fn clear_drops_everything_and_reports_it() {
    let mut f = filter();
    observe_views(&mut f, MAP_1, at(), &[10, 11], 0.0, 0.1);
    f.observe(seen(Target::Recovery, 3, at()), 0.3, None)
        .unwrap();
    let events = f.clear();
    assert_eq!(events.len(), 2);
    assert!(events
        .iter()
        .all(|e| matches!(e, FilterEvent::Dropped { .. })));
    assert!(f.is_empty());
    assert_eq!(f.stats().rejected_conditional, 1);
}

#[test]
fn bad_input_is_refused_and_changes_nothing() {
    let mut f = filter();
    observe_views(&mut f, MAP_1, at(), &[10], 0.0, 0.1);
    let before = (f.len(), f.stats(), f.hypotheses().next().cloned());

    let mut nan = seen(MAP_1, 11, at());
    nan.robot_from_target.x_m = f64::NAN;
    assert!(matches!(
        f.observe(nan, 0.1, None),
        Err(HypothesisError::NonFinite { .. })
    ));
    let mut singular = seen(MAP_1, 11, at());
    singular.covariance = Matrix3::from_diagonal(&Vector3::new(0.01, 0.0, 0.01));
    assert!(matches!(
        f.observe(singular, 0.1, None),
        Err(HypothesisError::NotPositiveDefinite { .. })
    ));
    assert!(f
        .observe(seen(MAP_1, 11, at()), f64::INFINITY, None)
        .is_err());
    assert!(f
        .observe(seen(MAP_1, 11, at()), 0.1, Some(f64::NAN))
        .is_err());
    let negative = Matrix3::from_diagonal(&Vector3::new(1e-3, -1e-3, 1e-3));
    assert!(matches!(
        f.predict(&Se2::new(0.1, 0.0, 0.0), &negative, 0.1, None),
        Err(HypothesisError::NotPositiveSemidefinite { .. })
    ));
    assert!(f
        .predict(&Se2::new(f64::NAN, 0.0, 0.0), &Matrix3::zeros(), 0.1, None)
        .is_err());
    assert_eq!(before, (f.len(), f.stats(), f.hypotheses().next().cloned()));

    let bad = HypothesisFilterParams {
        gate_mahalanobis_sq: f64::NAN,
        ..HypothesisFilterParams::default()
    };
    assert!(HypothesisFilter::<u64>::new(bad).is_err());
    let bad = HypothesisFilterParams {
        max_hypotheses: 0,
        ..HypothesisFilterParams::default()
    };
    assert!(HypothesisFilter::<u64>::new(bad).is_err());
}

#[test]
fn events_and_stats_serialise_as_json() {
    let mut f = filter();
    let outcomes = observe_views(&mut f, MAP_1, at(), &[10, 11], 0.0, 0.1);
    let mut events: Vec<FilterEvent> = outcomes.into_iter().flat_map(|o| o.events).collect();
    events.extend(f.reject(
        HypothesisId(0),
        RejectReason::Detector {
            name: "gridmap".into(),
            invalidity: 0.7,
        },
    ));
    let lines: Vec<String> = events
        .iter()
        .map(|e| serde_json::to_string(e).unwrap())
        .collect();
    assert!(
        lines[0].starts_with(r#"{"event":"created","id":0,"target":{"kind":"merge","map":1}"#),
        "{}",
        lines[0]
    );
    assert!(lines.iter().any(|l| l.contains(r#""event":"conditional""#)));
    assert!(lines
        .last()
        .unwrap()
        .contains(r#""reason":{"kind":"detector","name":"gridmap","invalidity":0.7}"#));
    for (line, event) in lines.iter().zip(&events) {
        assert_eq!(&serde_json::from_str::<FilterEvent>(line).unwrap(), event);
    }
    let stats = serde_json::to_value(f.stats()).unwrap();
    assert_eq!(stats["conditional"], 1);
    assert_eq!(stats["rejected_conditional"], 1);
    let recovery = serde_json::to_string(&Target::Recovery).unwrap();
    assert_eq!(recovery, r#"{"kind":"recovery"}"#);
}

#[test]
fn the_events_add_up_to_the_stats() {
    let mut f = filter();
    let mut events: Vec<FilterEvent> = Vec::new();
    let outcomes = |o: Vec<mapmerge_hypothesis::ObserveOutcome<u64>>| {
        o.into_iter().flat_map(|o| o.events).collect::<Vec<_>>()
    };
    // A conditional, superseded by a stronger competitor; a recovery.
    events.extend(outcomes(observe_views(
        &mut f,
        MAP_1,
        at(),
        &[10, 11],
        0.0,
        0.1,
    )));
    let other = Se2::new(-3.0, 2.0, -1.0);
    events.extend(outcomes(observe_views(
        &mut f,
        MAP_2,
        other,
        &[20, 21, 22],
        0.2,
        0.1,
    )));
    events.extend(
        f.observe(seen(Target::Recovery, 3, at()), 0.6, None)
            .unwrap()
            .events,
    );
    // Both expire, the conditional one among them.
    let small = Matrix3::from_diagonal_element(1e-6);
    events.extend(f.predict(&Se2::identity(), &small, 20.0, None).unwrap());
    // One made full, then one conditional when everything is dropped.
    events.extend(outcomes(observe_views(
        &mut f,
        MAP_1,
        at(),
        &[30, 31, 32, 33, 34],
        21.0,
        1.0,
    )));
    events.extend(outcomes(observe_views(
        &mut f,
        MAP_2,
        other,
        &[40, 41],
        30.0,
        0.1,
    )));
    events.extend(f.clear());
    let stats = f.stats();
    assert_eq!(
        (
            stats.created,
            stats.conditional,
            stats.full,
            stats.expired,
            stats.rejected_conditional
        ),
        (5, 4, 1, 2, 3),
        "{events:?}"
    );
    assert_eq!(FilterStats::of_events(&events), stats);
    assert_eq!(FilterStats::of_events(&[]), FilterStats::default());
}

#[test]
fn params_have_documented_defaults_and_partial_criteria_keep_their_own() {
    let p = HypothesisFilterParams::default();
    assert_eq!(
        p.conditional,
        AcceptanceCriteria {
            min_observations: 2,
            min_distinct_views: 2,
            min_view_spread_m: 0.0
        }
    );
    assert_eq!(
        p.full,
        AcceptanceCriteria {
            min_observations: 5,
            min_distinct_views: 4,
            min_view_spread_m: 2.0
        }
    );
    assert_eq!(
        (p.gate_mahalanobis_sq, p.expire_after_m, p.expire_after_s),
        (11.345, 10.0, None)
    );
    assert_eq!((p.ambiguous_weight, p.max_hypotheses), (0.0, 64));

    let parsed: HypothesisFilterParams = serde_json::from_str(
        r#"{"full": {"min_observations": 8}, "conditional": {"min_view_spread_m": 0.5}}"#,
    )
    .unwrap();
    assert_eq!(
        parsed.full,
        AcceptanceCriteria {
            min_observations: 8,
            ..AcceptanceCriteria::full()
        }
    );
    assert_eq!(
        parsed.conditional,
        AcceptanceCriteria {
            min_view_spread_m: 0.5,
            ..AcceptanceCriteria::conditional()
        }
    );
    assert_eq!(
        serde_json::from_str::<HypothesisFilterParams>("{}").unwrap(),
        p
    );
    let round: HypothesisFilterParams =
        serde_json::from_str(&serde_json::to_string(&p).unwrap()).unwrap();
    assert_eq!(round, p);
    assert!(serde_json::from_str::<HypothesisFilterParams>(r#"{"gate": 3}"#).is_err());
    assert!(serde_json::from_str::<HypothesisFilterParams>(r#"{"full": {"views": 3}}"#).is_err());
}
