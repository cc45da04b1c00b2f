//! Parameters of the hypothesis filter (Banerjee et al., Sec. 3.2.1 and 5.2).

use mapmerge_params::{Checker, Real, Validate};
use serde::{Deserialize, Deserializer, Serialize};

use crate::HypothesisError;

/// When a hypothesis holds enough evidence (Sec. 3.2.1: "a threshold on the number of
/// observations contained in the hypothesis, and the number of views that were observed").
///
/// Counts are weighted: a non-ambiguous observation counts 1, an ambiguous one
/// [`HypothesisFilterParams::ambiguous_weight`]; a view counts with the largest weight of its
/// observations. A partial object in a config file keeps the other fields of the criteria it
/// overrides (`full: { min_observations: 8 }` keeps the full criteria's views and spread).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AcceptanceCriteria {
    /// Weighted observations needed.
    pub min_observations: usize,
    /// Weighted distinct views (observed keyframes) needed.
    pub min_distinct_views: usize,
    /// Our addition beyond the paper: observations of two different views must lie at least
    /// this far apart in robot travel (m), so that evidence gathered from one spot does not
    /// count as independent. Travel is the measure, not the distance between robot poses.
    pub min_view_spread_m: f64,
}

impl AcceptanceCriteria {
    /// The permissive criteria of a conditional merge (Sec. 5.2): 2 observations, 2 views,
    /// no spread.
    pub fn conditional() -> Self {
        Self {
            min_observations: 2,
            min_distinct_views: 2,
            min_view_spread_m: 0.0,
        }
    }

    /// The strict criteria of a full merge: 5 observations, 4 views, 2 m.
    pub fn full() -> Self {
        Self {
            min_observations: 5,
            min_distinct_views: 4,
            min_view_spread_m: 2.0,
        }
    }

    /// The criteria of a recovery: 10 observations, 8 views, 5 m. Stricter than a merge's:
    /// a recovery moves the robot's own map against its confident estimate, and a place that
    /// repeats along a corridor keeps agreeing with itself for a while (the paper reports
    /// 1.1 % of runs with an accepted recovery).
    pub fn recovery() -> Self {
        Self {
            min_observations: 10,
            min_distinct_views: 8,
            min_view_spread_m: 5.0,
        }
    }
}

impl Validate for AcceptanceCriteria {
    fn check(&self, check: &mut Checker) {
        check
            .size("min_observations", self.min_observations, 1, 1_000_000)
            .size("min_distinct_views", self.min_distinct_views, 1, 1_000_000)
            .real(
                "min_view_spread_m",
                self.min_view_spread_m,
                Real::non_negative(),
            );
    }
}

/// The default is [`AcceptanceCriteria::conditional`].
impl Default for AcceptanceCriteria {
    fn default() -> Self {
        Self::conditional()
    }
}

/// Fields of [`AcceptanceCriteria`] a config file may leave out.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PartialCriteria {
    min_observations: Option<usize>,
    min_distinct_views: Option<usize>,
    min_view_spread_m: Option<f64>,
}

impl PartialCriteria {
    fn over(self, base: AcceptanceCriteria) -> AcceptanceCriteria {
        AcceptanceCriteria {
            min_observations: self.min_observations.unwrap_or(base.min_observations),
            min_distinct_views: self.min_distinct_views.unwrap_or(base.min_distinct_views),
            min_view_spread_m: self.min_view_spread_m.unwrap_or(base.min_view_spread_m),
        }
    }
}

fn conditional_criteria<'de, D: Deserializer<'de>>(d: D) -> Result<AcceptanceCriteria, D::Error> {
    Ok(PartialCriteria::deserialize(d)?.over(AcceptanceCriteria::conditional()))
}

fn full_criteria<'de, D: Deserializer<'de>>(d: D) -> Result<AcceptanceCriteria, D::Error> {
    Ok(PartialCriteria::deserialize(d)?.over(AcceptanceCriteria::full()))
}

fn recovery_criteria<'de, D: Deserializer<'de>>(d: D) -> Result<AcceptanceCriteria, D::Error> {
    Ok(PartialCriteria::deserialize(d)?.over(AcceptanceCriteria::recovery()))
}

/// Parameters of [`crate::HypothesisFilter`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HypothesisFilterParams {
    /// Criteria of a conditional merge (Sec. 5.2), merge hypotheses only (default:
    /// [`AcceptanceCriteria::conditional`], 2 observations of 2 views). Permissive: the robot
    /// behaves as localised sooner, at the risk of a merge the detectors must undo.
    #[serde(deserialize_with = "conditional_criteria")]
    pub conditional: AcceptanceCriteria,
    /// Criteria of a full merge (default: [`AcceptanceCriteria::full`], 5 observations of
    /// 4 views spread over 2 m). Stricter means fewer wrong merges and a longer wait.
    #[serde(deserialize_with = "full_criteria")]
    pub full: AcceptanceCriteria,
    /// Criteria of a recovery (default: [`AcceptanceCriteria::recovery`], 10 observations of
    /// 8 views spread over 5 m).
    #[serde(deserialize_with = "recovery_criteria")]
    pub recovery: AcceptanceCriteria,
    /// An observation updates the hypothesis of the same target with the smallest squared
    /// Mahalanobis distance (Eq. 6) below this; otherwise it starts a new one (default:
    /// 11.345 = χ²₃(0.99)).
    pub gate_mahalanobis_sq: f64,
    /// A hypothesis without an observation for this much robot travel expires (m)
    /// (default: 10).
    pub expire_after_m: f64,
    /// … or for this long (s), when observations and predictions carry times (default: none).
    pub expire_after_s: Option<f64>,
    /// Weight of an observation of an ambiguous view (Sec. 5.3) in the acceptance counts; it
    /// still updates the EKF (default: 0, ambiguous views do not count).
    pub ambiguous_weight: f64,
    /// At most this many live hypotheses; beyond it the one observed longest ago (in travel)
    /// is dropped and reported as expired (default: 64).
    pub max_hypotheses: usize,
}

impl Default for HypothesisFilterParams {
    fn default() -> Self {
        Self {
            conditional: AcceptanceCriteria::conditional(),
            full: AcceptanceCriteria::full(),
            recovery: AcceptanceCriteria::recovery(),
            gate_mahalanobis_sq: 11.345,
            expire_after_m: 10.0,
            expire_after_s: None,
            ambiguous_weight: 0.0,
            max_hypotheses: 64,
        }
    }
}

impl HypothesisFilterParams {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), HypothesisError> {
        Ok(Validate::validate(self)?)
    }
}

impl Validate for HypothesisFilterParams {
    fn check(&self, check: &mut Checker) {
        check
            .nested("conditional", &self.conditional)
            .nested("full", &self.full)
            .nested("recovery", &self.recovery)
            .real(
                "gate_mahalanobis_sq",
                self.gate_mahalanobis_sq,
                Real::positive(),
            )
            .real("expire_after_m", self.expire_after_m, Real::positive())
            .real_opt("expire_after_s", self.expire_after_s, Real::positive())
            .real("ambiguous_weight", self.ambiguous_weight, Real::fraction())
            .size("max_hypotheses", self.max_hypotheses, 1, 100_000);
    }
}
