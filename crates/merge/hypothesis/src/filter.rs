//! The hypothesis filter (Banerjee et al., Sec. 3.2.1, Fig. 3) with conditional merges
//! (Sec. 5.2): gating, one EKF per hypothesis, two levels of acceptance, expiry.

use std::collections::{BTreeMap, BTreeSet};

use mapmerge_geometry::{LieGroup, Se2};
use nalgebra::Matrix3;

use crate::ekf::{self, Innovation};
use crate::{
    FilterEvent, FilterStats, GateCandidate, Hypothesis, HypothesisCounts, HypothesisError,
    HypothesisFilterParams, HypothesisId, HypothesisState, Observation, ObservationRecord,
    ObserveOutcome, Reconsidered, RejectReason, Target,
};

/// Merge and recovery hypotheses, each an EKF on SE(2) over `robot_from_target`.
///
/// Per robot motion call [`HypothesisFilter::predict`] (Eq. 5, then expiry); per view
/// observation that the back-end does not take directly call [`HypothesisFilter::observe`]
/// (gating by Eq. 6, then Eq. 4 or Eq. 7–8, then acceptance). At most one merge hypothesis is
/// conditional at a time; a full acceptance removes every other hypothesis.
///
/// Rejected, expired and dropped hypotheses leave the filter at once: a later observation of
/// the same alignment starts a new hypothesis (refusing a transform an unmerge took back is
/// the caller's rule).
#[derive(Clone, Debug)]
pub struct HypothesisFilter<E> {
    params: HypothesisFilterParams,
    live: BTreeMap<HypothesisId, Hypothesis<E>>,
    next_id: u64,
    stats: FilterStats,
}

/// Idle travel (m) and idle time (s) of a hypothesis due to expire.
type Due = (HypothesisId, f64, Option<f64>);

fn check_travel_time(travel_m: f64, time_s: Option<f64>) -> Result<(), HypothesisError> {
    if !travel_m.is_finite() {
        return Err(HypothesisError::NonFinite { what: "travel_m" });
    }
    if time_s.is_some_and(|t| !t.is_finite()) {
        return Err(HypothesisError::NonFinite { what: "time_s" });
    }
    Ok(())
}

/// Sec. 5.2, "a competing hypothesis wins over": strictly more weighted views, or as many
/// and strictly more weighted observations.
fn wins(challenger: &HypothesisCounts, holder: &HypothesisCounts) -> bool {
    const SLACK: f64 = 1e-9;
    challenger.weighted_views > holder.weighted_views + SLACK
        || ((challenger.weighted_views - holder.weighted_views).abs() <= SLACK
            && challenger.weighted_observations > holder.weighted_observations + SLACK)
}

impl<E> Default for HypothesisFilter<E> {
    fn default() -> Self {
        Self {
            params: HypothesisFilterParams::default(),
            live: BTreeMap::new(),
            next_id: 0,
            stats: FilterStats::default(),
        }
    }
}

impl<E> HypothesisFilter<E> {
    /// An empty filter; refuses parameters out of range.
    pub fn new(params: HypothesisFilterParams) -> Result<Self, HypothesisError> {
        params.validate()?;
        Ok(Self {
            params,
            ..Self::default()
        })
    }

    /// Its parameters.
    pub fn params(&self) -> &HypothesisFilterParams {
        &self.params
    }

    /// Cumulative counts.
    pub fn stats(&self) -> FilterStats {
        self.stats
    }

    /// The live (tentative or conditional) hypotheses, by id.
    pub fn hypotheses(&self) -> impl Iterator<Item = &Hypothesis<E>> {
        self.live.values()
    }

    /// A live hypothesis.
    pub fn hypothesis(&self, id: HypothesisId) -> Option<&Hypothesis<E>> {
        self.live.get(&id)
    }

    /// The conditional merge hypothesis, if any (Sec. 5.2): its edges join the graph copy.
    pub fn conditional(&self) -> Option<&Hypothesis<E>> {
        self.live
            .values()
            .find(|h| h.state == HypothesisState::Conditional)
    }

    /// Number of live hypotheses.
    pub fn len(&self) -> usize {
        self.live.len()
    }

    /// True when no hypothesis is live.
    pub fn is_empty(&self) -> bool {
        self.live.is_empty()
    }

    /// Eq. 5 on every live hypothesis, then expiry.
    ///
    /// `previous_robot_from_robot` is the odometry increment (the new robot pose in the
    /// previous robot frame), `increment_covariance` its covariance in the increment's RIGHT
    /// tangent (as a scan matcher or odometry gives it), `travel_m` the robot's total travel
    /// so far. Bad input changes nothing and returns an error.
    pub fn predict(
        &mut self,
        previous_robot_from_robot: &Se2,
        increment_covariance: &Matrix3<f64>,
        travel_m: f64,
        time_s: Option<f64>,
    ) -> Result<Vec<FilterEvent>, HypothesisError> {
        check_travel_time(travel_m, time_s)?;
        if !previous_robot_from_robot.is_finite() {
            return Err(HypothesisError::NonFinite {
                what: "previous_robot_from_robot",
            });
        }
        let increment_covariance = ekf::checked_psd(increment_covariance, "increment_covariance")?;
        let predicted: Vec<(HypothesisId, Se2, Matrix3<f64>)> = self
            .live
            .values()
            .map(|h| {
                let (pose, covariance) = ekf::predict(
                    &h.robot_from_target,
                    &h.covariance,
                    previous_robot_from_robot,
                    &increment_covariance,
                );
                (h.id, pose, covariance)
            })
            .collect();
        if predicted
            .iter()
            .any(|(_, pose, cov)| !pose.is_finite() || cov.iter().any(|v| !v.is_finite()))
        {
            return Err(HypothesisError::Numerical {
                what: "motion update",
            });
        }
        for (id, pose, covariance) in predicted {
            if let Some(h) = self.live.get_mut(&id) {
                h.robot_from_target = pose;
                h.covariance = covariance;
            }
        }
        Ok(self.expire(travel_m, time_s))
    }

    /// Removes the hypotheses without an observation for `expire_after_m` of travel (or
    /// `expire_after_s` when both times are known). [`HypothesisFilter::predict`] and
    /// [`HypothesisFilter::observe`] call it; a conditional one that expires is reported as
    /// expired and also counts in [`FilterStats::rejected_conditional`]. A non-finite travel
    /// or time expires nothing.
    pub fn expire(&mut self, travel_m: f64, time_s: Option<f64>) -> Vec<FilterEvent> {
        let mut events = Vec::new();
        if check_travel_time(travel_m, time_s).is_err() {
            return events;
        }
        for (id, idle_travel_m, idle_s) in self.due(travel_m, time_s) {
            self.remove_expired(id, idle_travel_m, idle_s, false, &mut events);
        }
        events
    }

    /// Gates the observation (Eq. 6) against the live hypotheses of its target, then updates
    /// the nearest one below the gate (Eq. 7–8) or starts a new one (Eq. 4), then applies the
    /// acceptance rules. Expired hypotheses are removed first. Bad input changes nothing and
    /// returns an error.
    pub fn observe(
        &mut self,
        observation: Observation<E>,
        travel_m: f64,
        time_s: Option<f64>,
    ) -> Result<ObserveOutcome<E>, HypothesisError> {
        check_travel_time(travel_m, time_s)?;
        if !observation.robot_from_target.is_finite() {
            return Err(HypothesisError::NonFinite {
                what: "observation robot_from_target",
            });
        }
        let z_covariance = ekf::checked_pd(&observation.covariance, "observation covariance")?;
        let due = self.due(travel_m, time_s);

        // Eq. 6 against every live hypothesis of the same target.
        let mut candidates = Vec::new();
        let mut best: Option<(HypothesisId, Innovation)> = None;
        for h in self
            .live
            .values()
            .filter(|h| h.target == observation.target && !due.iter().any(|(id, _, _)| *id == h.id))
        {
            let innovation = ekf::innovation(
                &h.robot_from_target,
                &h.covariance,
                &observation.robot_from_target,
                &z_covariance,
            );
            let mahalanobis_sq = innovation.map_or(f64::INFINITY, |i| i.mahalanobis_sq);
            candidates.push(GateCandidate {
                id: h.id,
                mahalanobis_sq,
            });
            if let Some(innovation) = innovation {
                if mahalanobis_sq < self.params.gate_mahalanobis_sq
                    && best
                        .as_ref()
                        .is_none_or(|(_, b)| mahalanobis_sq < b.mahalanobis_sq)
                {
                    best = Some((h.id, innovation));
                }
            }
        }
        // Eq. 7–8, computed before anything changes so that an error leaves the filter intact.
        let updated = match &best {
            Some((id, innovation)) => match self.live.get(id) {
                Some(h) => Some(ekf::update(
                    &h.robot_from_target,
                    &h.covariance,
                    &innovation.log_residual,
                    &z_covariance,
                )?),
                None => None,
            },
            None => None,
        };

        let mut events = Vec::new();
        for (id, idle_travel_m, idle_s) in due {
            self.remove_expired(id, idle_travel_m, idle_s, false, &mut events);
        }
        let (target, view, robot) = (observation.target, observation.view, observation.robot);
        let mahalanobis_sq = best.as_ref().map(|(_, i)| i.mahalanobis_sq);
        let record = ObservationRecord {
            observation,
            travel_m,
            time_s,
            mahalanobis_sq,
        };
        let ambiguous_weight = self.params.ambiguous_weight;
        let existing = match (best, updated) {
            (Some((id, innovation)), Some((pose, covariance))) => self
                .live
                .get_mut(&id)
                .map(|h| (h, innovation, pose, covariance)),
            _ => None,
        };
        let (id, created) = if let Some((h, innovation, pose, covariance)) = existing {
            h.robot_from_target = pose;
            h.covariance = covariance;
            h.observations.push(record);
            h.last_observation_travel_m = travel_m;
            h.last_observation_time_s = time_s;
            events.push(FilterEvent::Updated {
                id: h.id,
                target,
                view,
                robot,
                mahalanobis_sq: innovation.mahalanobis_sq,
                counts: h.counts(ambiguous_weight),
            });
            (h.id, false)
        } else {
            // Eq. 4: G = z₀, Σ_G = Σ_z₀.
            let id = HypothesisId(self.next_id);
            self.next_id += 1;
            self.stats.created += 1;
            match target {
                Target::Merge { .. } => self.stats.merge += 1,
                Target::Recovery => self.stats.recovery += 1,
            }
            events.push(FilterEvent::Created {
                id,
                target,
                view,
                robot,
                travel_m,
                candidates: candidates.clone(),
            });
            let hypothesis = Hypothesis {
                id,
                target,
                state: HypothesisState::Tentative,
                robot_from_target: record.observation.robot_from_target,
                covariance: z_covariance,
                observations: vec![record],
                last_observation_travel_m: travel_m,
                last_observation_time_s: time_s,
            };
            self.live.insert(id, hypothesis);
            self.evict(id, travel_m, time_s, &mut events);
            (id, true)
        };

        let (conditional_started, accepted) = self.promote(id, &mut events);
        let state = match (&accepted, self.live.get(&id)) {
            (Some(h), _) | (None, Some(h)) => h.state,
            (None, None) => HypothesisState::Expired,
        };
        Ok(ObserveOutcome {
            hypothesis: id,
            created,
            mahalanobis_sq,
            candidates,
            state,
            conditional_started,
            accepted,
            events,
        })
    }

    /// Rejects a live hypothesis (e.g. the conditional one an invalid-merge detector refuted);
    /// `None` when `id` is not live. A tentative hypothesis that already meets the conditional
    /// criteria becomes conditional at its next observation.
    pub fn reject(&mut self, id: HypothesisId, reason: RejectReason) -> Option<FilterEvent> {
        let mut events = Vec::new();
        self.remove_rejected(id, reason, &mut events);
        events.pop()
    }

    /// Drops every live hypothesis (the epoch ended), reporting each.
    pub fn clear(&mut self) -> Vec<FilterEvent> {
        let mut events = Vec::new();
        let ids: Vec<HypothesisId> = self.live.keys().copied().collect();
        for id in ids {
            self.remove_dropped(id, &mut events);
        }
        events
    }

    /// Marks the live hypotheses' observations of `views` as ambiguous (Sec. 5.3: views found
    /// ambiguous later are discounted too). Returns how many observations changed. States do
    /// not go back: a conditional hypothesis stays conditional.
    pub fn discount_views(&mut self, views: &BTreeSet<u64>) -> usize {
        let mut changed = 0;
        for record in self
            .live
            .values_mut()
            .flat_map(|h| h.observations.iter_mut())
        {
            if !record.observation.ambiguous && views.contains(&record.observation.view) {
                record.observation.ambiguous = true;
                changed += 1;
            }
        }
        changed
    }

    /// Counts the ambiguous observations of hypothesis `id` that `counts_again` picks in
    /// full again (e.g. of views ambiguous one by one whose joint map is not: what they saw
    /// together fits nowhere else), then re-evaluates its acceptance as after an
    /// observation. `None` when `id` is not live.
    pub fn count_again(
        &mut self,
        id: HypothesisId,
        counts_again: impl Fn(&Observation<E>) -> bool,
    ) -> Option<Reconsidered<E>> {
        let h = self.live.get_mut(&id)?;
        let mut changed = 0;
        for record in &mut h.observations {
            if record.observation.ambiguous && counts_again(&record.observation) {
                record.observation.ambiguous = false;
                changed += 1;
            }
        }
        let mut events = Vec::new();
        let (conditional_started, accepted) = if changed > 0 {
            self.promote(id, &mut events)
        } else {
            (false, None)
        };
        Some(Reconsidered {
            changed,
            conditional_started,
            accepted,
            events,
        })
    }

    fn due(&self, travel_m: f64, time_s: Option<f64>) -> Vec<Due> {
        self.live
            .values()
            .filter_map(|h| {
                let idle_travel_m = travel_m - h.last_observation_travel_m;
                let idle_s = time_s.zip(h.last_observation_time_s).map(|(t, l)| t - l);
                let by_travel = idle_travel_m > self.params.expire_after_m;
                let by_time = self
                    .params
                    .expire_after_s
                    .zip(idle_s)
                    .is_some_and(|(limit, idle)| idle > limit);
                (by_travel || by_time).then_some((h.id, idle_travel_m, idle_s))
            })
            .collect()
    }

    /// Keeps `max_hypotheses` by evicting the ones observed longest ago, never `keep`.
    fn evict(
        &mut self,
        keep: HypothesisId,
        travel_m: f64,
        time_s: Option<f64>,
        events: &mut Vec<FilterEvent>,
    ) {
        while self.live.len() > self.params.max_hypotheses {
            let stalest = self
                .live
                .values()
                .filter(|h| h.id != keep)
                .min_by(|a, b| {
                    a.last_observation_travel_m
                        .total_cmp(&b.last_observation_travel_m)
                        .then(a.id.cmp(&b.id))
                })
                .map(|h| {
                    (
                        h.id,
                        travel_m - h.last_observation_travel_m,
                        time_s.zip(h.last_observation_time_s).map(|(t, l)| t - l),
                    )
                });
            match stalest {
                Some((id, idle_travel_m, idle_s)) => {
                    self.remove_expired(id, idle_travel_m, idle_s, true, events);
                }
                None => break,
            }
        }
    }

    /// Acceptance of the hypothesis `id` after its observation (Sec. 3.2.1, 5.2). Returns
    /// whether it became conditional and, if fully accepted, the hypothesis.
    fn promote(
        &mut self,
        id: HypothesisId,
        events: &mut Vec<FilterEvent>,
    ) -> (bool, Option<Hypothesis<E>>) {
        let weight = self.params.ambiguous_weight;
        let Some(h) = self.live.get(&id) else {
            return (false, None);
        };
        let counts = h.counts(weight);
        let is_recovery = h.target == Target::Recovery;
        let strict = if is_recovery {
            &self.params.recovery
        } else {
            &self.params.full
        };
        if counts.meets(strict) {
            let Some(mut accepted) = self.live.remove(&id) else {
                return (false, None);
            };
            let previous = accepted.state;
            accepted.state = HypothesisState::Full;
            self.stats.full += 1;
            events.push(FilterEvent::Full {
                id,
                target: accepted.target,
                counts,
                previous,
            });
            // "When we accept a hypothesis, we delete all the other competing hypotheses": a
            // merge competes with every hypothesis, a recovery with the other recoveries.
            let others: Vec<HypothesisId> = self
                .live
                .values()
                .filter(|h| !is_recovery || h.target == Target::Recovery)
                .map(|h| h.id)
                .collect();
            for other in others {
                if self.live.get(&other).map(|h| h.state) == Some(HypothesisState::Conditional) {
                    self.remove_rejected(other, RejectReason::Superseded { by: id }, events);
                } else {
                    self.remove_dropped(other, events);
                }
            }
            return (false, Some(accepted));
        }
        // Recovery hypotheses never go conditional (Sec. 5.2 is about merges).
        let eligible = matches!(h.target, Target::Merge { .. })
            && h.state == HypothesisState::Tentative
            && counts.meets(&self.params.conditional);
        if !eligible {
            return (false, None);
        }
        let holder = self.conditional().map(|c| (c.id, c.counts(weight)));
        let superseded = match holder {
            None => None,
            Some((holder, holder_counts)) if wins(&counts, &holder_counts) => {
                self.remove_rejected(holder, RejectReason::Superseded { by: id }, events);
                Some(holder)
            }
            Some(_) => return (false, None),
        };
        let Some(h) = self.live.get_mut(&id) else {
            return (false, None);
        };
        h.state = HypothesisState::Conditional;
        self.stats.conditional += 1;
        events.push(FilterEvent::Conditional {
            id,
            target: h.target,
            counts,
            superseded,
        });
        (true, None)
    }

    fn take(&mut self, id: HypothesisId) -> Option<(Hypothesis<E>, HypothesisCounts)> {
        let h = self.live.remove(&id)?;
        if h.state == HypothesisState::Conditional {
            self.stats.rejected_conditional += 1;
        }
        let counts = h.counts(self.params.ambiguous_weight);
        Some((h, counts))
    }

    fn remove_expired(
        &mut self,
        id: HypothesisId,
        idle_travel_m: f64,
        idle_s: Option<f64>,
        evicted: bool,
        events: &mut Vec<FilterEvent>,
    ) {
        if let Some((h, counts)) = self.take(id) {
            self.stats.expired += 1;
            events.push(FilterEvent::Expired {
                id,
                target: h.target,
                counts,
                previous: h.state,
                idle_travel_m,
                idle_s,
                evicted,
            });
        }
    }

    fn remove_rejected(
        &mut self,
        id: HypothesisId,
        reason: RejectReason,
        events: &mut Vec<FilterEvent>,
    ) {
        if let Some((h, counts)) = self.take(id) {
            events.push(FilterEvent::Rejected {
                id,
                target: h.target,
                counts,
                previous: h.state,
                reason,
            });
        }
    }

    fn remove_dropped(&mut self, id: HypothesisId, events: &mut Vec<FilterEvent>) {
        if let Some((h, counts)) = self.take(id) {
            events.push(FilterEvent::Dropped {
                id,
                target: h.target,
                counts,
                previous: h.state,
            });
        }
    }
}
