//! What a hypothesis is: a target, an EKF state and the observations that support it.

use std::collections::BTreeMap;

use mapmerge_geometry::Se2;
use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

use crate::AcceptanceCriteria;

/// A hypothesis' id, unique within one [`crate::HypothesisFilter`] and never reused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct HypothesisId(pub u64);

impl core::fmt::Display for HypothesisId {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "h{}", self.0)
    }
}

/// What a hypothesis would join the robot's component to (Sec. 3.2.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Target {
    /// A view of another component: merge with the inactive map `map`.
    Merge {
        /// The inactive map's id.
        map: u32,
    },
    /// A view of the robot's own component that contradicts the current estimate.
    Recovery,
}

/// Where a hypothesis is in its life.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HypothesisState {
    /// Collecting evidence.
    Tentative,
    /// Conditionally merged (Sec. 5.2): the robot acts on it, it can still be rejected.
    Conditional,
    /// Accepted: its edges go into the graph for good.
    Full,
    /// Rejected by a detector, the caller or a stronger competitor.
    Rejected,
    /// No observation for too long (or evicted by `max_hypotheses`).
    Expired,
}

/// One view observation (Eq. 3): the pose of the target's map frame in the robot frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Observation<E> {
    /// What the observation would join.
    pub target: Target,
    /// The observed keyframe's node id.
    pub view: u64,
    /// The robot's keyframe node id when observing.
    pub robot: u64,
    /// The target component's map frame in the current robot frame (`z`).
    pub robot_from_target: Se2,
    /// `Σ_z` in the LEFT tangent of `z` (`z_true = Exp(ε)·z`), order `(v_x, v_y, ω)`.
    pub covariance: Matrix3<f64>,
    /// True when the view is ambiguous (Sec. 5.3): the EKF uses it, the counts weigh it by
    /// `ambiguous_weight`.
    pub ambiguous: bool,
    /// The caller's payload, e.g. the graph edge to add when the hypothesis is accepted.
    pub edge: E,
}

/// An observation as a hypothesis keeps it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObservationRecord<E> {
    /// The observation as given.
    pub observation: Observation<E>,
    /// Robot travel when it was made (m).
    pub travel_m: f64,
    /// Time when it was made (s), if given.
    pub time_s: Option<f64>,
    /// Its squared Mahalanobis distance to the hypothesis (Eq. 6); `None` for the first.
    pub mahalanobis_sq: Option<f64>,
}

/// A hypothesis' evidence, weighted as the acceptance criteria count it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HypothesisCounts {
    /// Observations, unweighted.
    pub observations: usize,
    /// Weighted observations.
    pub weighted_observations: f64,
    /// Weighted distinct views.
    pub weighted_views: f64,
    /// The largest travel between observations of two different counting views (m).
    pub view_spread_m: f64,
}

impl HypothesisCounts {
    /// True when these counts meet `criteria`.
    pub fn meets(&self, criteria: &AcceptanceCriteria) -> bool {
        // Tolerates rounding in sums of fractional weights.
        const SLACK: f64 = 1e-9;
        self.weighted_observations + SLACK >= criteria.min_observations as f64
            && self.weighted_views + SLACK >= criteria.min_distinct_views as f64
            && self.view_spread_m + SLACK >= criteria.min_view_spread_m
    }
}

/// A merge or recovery hypothesis: one EKF on SE(2) (Eq. 4–8) and its observations.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Hypothesis<E> {
    pub(crate) id: HypothesisId,
    pub(crate) target: Target,
    pub(crate) state: HypothesisState,
    pub(crate) robot_from_target: Se2,
    pub(crate) covariance: Matrix3<f64>,
    pub(crate) observations: Vec<ObservationRecord<E>>,
    pub(crate) last_observation_travel_m: f64,
    pub(crate) last_observation_time_s: Option<f64>,
}

impl<E> Hypothesis<E> {
    /// Its id.
    pub fn id(&self) -> HypothesisId {
        self.id
    }
    /// Its target.
    pub fn target(&self) -> Target {
        self.target
    }
    /// Its state.
    pub fn state(&self) -> HypothesisState {
        self.state
    }
    /// The estimate `G`: the target's map frame in the current robot frame.
    pub fn robot_from_target(&self) -> &Se2 {
        &self.robot_from_target
    }
    /// `Σ_G` in the left tangent of `G`.
    pub fn covariance(&self) -> &Matrix3<f64> {
        &self.covariance
    }
    /// Its observations, oldest first.
    pub fn observations(&self) -> &[ObservationRecord<E>] {
        &self.observations
    }
    /// The payloads (edges) of its observations, oldest first.
    pub fn edges(&self) -> impl Iterator<Item = &E> {
        self.observations.iter().map(|r| &r.observation.edge)
    }
    /// Its observations, consumed.
    pub fn into_observations(self) -> Vec<ObservationRecord<E>> {
        self.observations
    }
    /// Robot travel at its last observation (m).
    pub fn last_observation_travel_m(&self) -> f64 {
        self.last_observation_travel_m
    }
    /// Time of its last observation (s), if the observation carried one.
    pub fn last_observation_time_s(&self) -> Option<f64> {
        self.last_observation_time_s
    }

    /// Its evidence with ambiguous observations weighted by `ambiguous_weight`.
    pub fn counts(&self, ambiguous_weight: f64) -> HypothesisCounts {
        let weight = |r: &ObservationRecord<E>| {
            if r.observation.ambiguous {
                ambiguous_weight
            } else {
                1.0
            }
        };
        // Per view: largest weight, first and last travel of its counting observations.
        let mut views: BTreeMap<u64, (f64, f64, f64)> = BTreeMap::new();
        let mut weighted_observations = 0.0;
        for r in &self.observations {
            let w = weight(r);
            weighted_observations += w;
            let entry =
                views
                    .entry(r.observation.view)
                    .or_insert((0.0, f64::INFINITY, f64::NEG_INFINITY));
            entry.0 = entry.0.max(w);
            if w > 0.0 {
                entry.1 = entry.1.min(r.travel_m);
                entry.2 = entry.2.max(r.travel_m);
            }
        }
        let weighted_views = views.values().map(|v| v.0).sum();
        let counting: Vec<(f64, f64)> = views
            .values()
            .filter(|v| v.0 > 0.0)
            .map(|v| (v.1, v.2))
            .collect();
        let mut view_spread_m: f64 = 0.0;
        for (a, (first_a, _)) in counting.iter().enumerate() {
            for (b, (_, last_b)) in counting.iter().enumerate() {
                if a != b {
                    view_spread_m = view_spread_m.max(last_b - first_a);
                }
            }
        }
        HypothesisCounts {
            observations: self.observations.len(),
            weighted_observations,
            weighted_views,
            view_spread_m,
        }
    }
}
