//! The combined decision: both kinds of evidence of Holoch et al., Sec. IV — *unexpected
//! appearance* (change detection, Sec. IV-A, and gridmap, Sec. IV-B) and *better hypothesis*.
//!
//! Why this form:
//! - the two appearance ratios live on different scales (fractions of points vs. of cells), so
//!   each is first calibrated to a pseudo-probability by a logistic centred on its own
//!   decision threshold `t` (spread `s · t`), rescaled so that a ratio of 0 stays 0;
//! - change detection and gridmap measure the same kind of evidence with different errors
//!   (points vs. dilated cells), so they are averaged: the mean of two partly independent
//!   estimates is less noisy than either, which is what lifts the AUC above both;
//! - the two kinds fail in opposite situations (the paper: aliasing fools better hypothesis,
//!   change fools appearance; appearance is blind where the merged epochs saw nothing, better
//!   hypothesis where the place is not recognised), so they are joined by a noisy-or,
//!   `1 − (1 − p_appearance)(1 − p_hypothesis)`: either kind alone can flag a merge, and
//!   both together flag it more surely.

use mapmerge_params::{Checker, Real, Validate};
use serde::{Deserialize, Serialize};

use crate::common::{logistic, noisy_or, unit};
use crate::{
    BetterHypothesisDetector, BetterHypothesisParams, ChangeDetectionDetector,
    ChangeDetectionParams, GridmapDetector, GridmapParams, InvalidMergeDetector, MergedMap,
    RatioSupport,
};

/// Parameters of [`CombinedDetector`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CombinedParams {
    /// Change detection's parameters.
    pub change_detection: ChangeDetectionParams,
    /// Gridmap's parameters.
    pub gridmap: GridmapParams,
    /// Better hypothesis' parameters.
    pub better_hypothesis: BetterHypothesisParams,
    /// Change detection's decision threshold `t` (default: 0.4, the threshold that best
    /// separates the tuning logs' valid and invalid forced merges by change detection's peak,
    /// Youden's J, with the two-sided ratio; at 0.15, a value set on the simulator's office
    /// tests, half of the public logs' valid merges read above it).
    pub change_detection_threshold: f64,
    /// Gridmap's decision threshold `t` (default: 0.15; correct merges in the simulated office
    /// with moved furniture and closed doors reach 0.12).
    pub gridmap_threshold: f64,
    /// Spread `s` of the calibration logistics, relative to `t` (default: 0.25).
    pub calibration_spread: f64,
}

impl Default for CombinedParams {
    fn default() -> Self {
        Self {
            change_detection: ChangeDetectionParams::default(),
            gridmap: GridmapParams::default(),
            better_hypothesis: BetterHypothesisParams::default(),
            change_detection_threshold: 0.4,
            gridmap_threshold: 0.15,
            calibration_spread: 0.25,
        }
    }
}

impl Validate for CombinedParams {
    fn check(&self, check: &mut Checker) {
        check
            .nested("change_detection", &self.change_detection)
            .nested("gridmap", &self.gridmap)
            .nested("better_hypothesis", &self.better_hypothesis)
            .real(
                "change_detection_threshold",
                self.change_detection_threshold,
                Real::positive_up_to(1.0),
            )
            .real(
                "gridmap_threshold",
                self.gridmap_threshold,
                Real::positive_up_to(1.0),
            )
            .real(
                "calibration_spread",
                self.calibration_spread,
                Real::positive(),
            );
    }
}

/// A ratio calibrated by the logistic centred on `threshold`, rescaled so that 0 maps to 0.
fn calibrate(ratio: f64, threshold: f64, spread: f64) -> f64 {
    let t = if threshold.is_finite() && threshold > 0.0 {
        threshold
    } else {
        0.1
    };
    let scale = t * if spread.is_finite() && spread > 0.0 {
        spread
    } else {
        0.25
    };
    let at_zero = logistic(0.0, t, scale);
    unit((logistic(ratio, t, scale) - at_zero) / (1.0 - at_zero))
}

/// The last component ratios.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct CombinedInfo {
    /// Change detection's ratio.
    pub change_detection: f64,
    /// Gridmap's ratio.
    pub gridmap: f64,
    /// Better hypothesis' ratio.
    pub better_hypothesis: f64,
    /// The calibrated appearance evidence.
    pub appearance: f64,
}

/// Combined decision; see the module documentation.
#[derive(Debug)]
pub struct CombinedDetector {
    params: CombinedParams,
    change_detection: ChangeDetectionDetector,
    gridmap: GridmapDetector,
    better_hypothesis: BetterHypothesisDetector,
    info: CombinedInfo,
}

impl Default for CombinedDetector {
    fn default() -> Self {
        Self::new(CombinedParams::default())
    }
}

impl CombinedDetector {
    /// A detector with `params`.
    pub fn new(params: CombinedParams) -> Self {
        Self {
            change_detection: ChangeDetectionDetector::new(params.change_detection.clone()),
            gridmap: GridmapDetector::new(params.gridmap.clone()),
            better_hypothesis: BetterHypothesisDetector::new(params.better_hypothesis.clone()),
            params,
            info: CombinedInfo::default(),
        }
    }

    /// The last component ratios.
    pub fn info(&self) -> CombinedInfo {
        self.info
    }

    /// The combination of component ratios (see the module documentation).
    pub fn combine(&self, change_detection: f64, gridmap: f64, better_hypothesis: f64) -> f64 {
        let p = &self.params;
        let appearance = 0.5
            * (calibrate(
                change_detection,
                p.change_detection_threshold,
                p.calibration_spread,
            ) + calibrate(gridmap, p.gridmap_threshold, p.calibration_spread));
        noisy_or(appearance, better_hypothesis)
    }
}

impl InvalidMergeDetector for CombinedDetector {
    fn name(&self) -> &'static str {
        "combined"
    }

    fn on_merge(&mut self, map: &MergedMap<'_>) {
        self.change_detection.on_merge(map);
        self.gridmap.on_merge(map);
        self.better_hypothesis.on_merge(map);
        self.info = CombinedInfo::default();
    }

    fn on_vertex(&mut self, map: &MergedMap<'_>) -> f64 {
        let cd = self.change_detection.on_vertex(map);
        let gm = self.gridmap.on_vertex(map);
        let bh = self.better_hypothesis.on_vertex(map);
        let p = &self.params;
        self.info = CombinedInfo {
            change_detection: cd,
            gridmap: gm,
            better_hypothesis: bh,
            appearance: 0.5
                * (calibrate(cd, p.change_detection_threshold, p.calibration_spread)
                    + calibrate(gm, p.gridmap_threshold, p.calibration_spread)),
        };
        self.combine(cd, gm, bh)
    }

    /// Change detection's (the appearance evidence's finer part).
    fn support(&self) -> Option<u64> {
        self.change_detection.support()
    }

    /// The three components' last ratios, so that a merge's record says which one read high.
    fn component_readings(&self) -> Vec<(&'static str, f64, RatioSupport)> {
        vec![
            (
                self.change_detection.name(),
                self.info.change_detection,
                self.change_detection.evidence(),
            ),
            (
                self.gridmap.name(),
                self.info.gridmap,
                self.gridmap.evidence(),
            ),
            (
                self.better_hypothesis.name(),
                self.info.better_hypothesis,
                self.better_hypothesis.evidence(),
            ),
        ]
    }

    /// Unsupported while no component had anything to compare.
    fn evidence(&self) -> RatioSupport {
        if self.change_detection.evidence() == RatioSupport::Unsupported
            && self.gridmap.evidence() == RatioSupport::Unsupported
            && self.better_hypothesis.evidence() == RatioSupport::Unsupported
        {
            RatioSupport::Unsupported
        } else {
            RatioSupport::Supported
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testworld::Case;

    /// AUC by the Mann–Whitney statistic (ties count half).
    fn auc(valid: &[f64], invalid: &[f64]) -> f64 {
        let mut wins = 0.0;
        for &i in invalid {
            for &v in valid {
                wins += if i > v {
                    1.0
                } else if i == v {
                    0.5
                } else {
                    0.0
                };
            }
        }
        wins / (valid.len() * invalid.len()) as f64
    }

    #[test]
    fn calibration_is_monotone_and_keeps_zero() {
        assert_eq!(calibrate(0.0, 0.15, 0.25), 0.0);
        let mut last = 0.0;
        for i in 1..100 {
            let c = calibrate(i as f64 / 100.0, 0.15, 0.25);
            assert!(c >= last);
            last = c;
        }
        assert!(calibrate(f64::NAN, 0.15, 0.25) == 0.0);
    }

    #[test]
    fn combined_is_at_least_as_good_as_each_single_method() {
        let (valid_cases, invalid_cases) = Case::office_valid_and_invalid();
        let names = [
            "change_detection",
            "gridmap",
            "better_hypothesis",
            "combined",
        ];
        let mut aucs = Vec::new();
        for name in names {
            let score = |cases: &[Case]| -> Vec<f64> {
                cases
                    .iter()
                    .map(|c| c.max_ratio(crate::detector(name).unwrap().as_mut()))
                    .collect()
            };
            let (v, i) = (score(&valid_cases), score(&invalid_cases));
            aucs.push(auc(&v, &i));
            eprintln!(
                "{name}: valid {v:?} invalid {i:?} auc {}",
                aucs.last().unwrap()
            );
        }
        let combined = aucs[3];
        for (name, a) in names.iter().zip(&aucs) {
            assert!(combined >= *a, "combined {combined} < {name} {a}");
        }
        assert!(combined > 0.99);
    }
}
