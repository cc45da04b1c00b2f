//! The detectors by name, with default parameters (what the evaluation harness and the atlas
//! instantiate).

use mapmerge_params::{Checker, Validate};
use serde::{Deserialize, Serialize};

use crate::{
    BetterHypothesisDetector, BetterHypothesisParams, ChangeDetectionDetector,
    ChangeDetectionParams, CombinedDetector, CombinedParams, DmDetector, EntropyDetector,
    EntropyParams, GridmapDetector, GridmapParams, HistogramDetector, HistogramParams,
    InvalidMergeDetector, LearnedDetector, RealignDetector, RealignParams, SimilarityParams,
    SmDetector,
};

/// Every detector's [`InvalidMergeDetector::name`], in the order of [`all_detectors`].
pub const DETECTOR_NAMES: &[&str] = &[
    "change_detection",
    "gridmap",
    "entropy",
    "histogram",
    "sm",
    "dm",
    "better_hypothesis",
    "realign",
    "combined",
    "learned",
];

/// The detector called `name` (one of [`DETECTOR_NAMES`]) with default parameters; `None` for
/// an unknown name.
pub fn detector(name: &str) -> Option<Box<dyn InvalidMergeDetector>> {
    let boxed: Box<dyn InvalidMergeDetector> = match name {
        "change_detection" => Box::<ChangeDetectionDetector>::default(),
        "gridmap" => Box::<GridmapDetector>::default(),
        "entropy" => Box::<EntropyDetector>::default(),
        "histogram" => Box::<HistogramDetector>::default(),
        "sm" => Box::<SmDetector>::default(),
        "dm" => Box::<DmDetector>::default(),
        "better_hypothesis" => Box::<BetterHypothesisDetector>::default(),
        "realign" => Box::<RealignDetector>::default(),
        "combined" => Box::<CombinedDetector>::default(),
        "learned" => Box::<LearnedDetector>::default(),
        _ => return None,
    };
    Some(boxed)
}

/// Parameters per detector name, each optional and the defaults where absent (`eval
/// invalid-merge --detector-params`, the engine's `detector_params`). `combined` carries its
/// parts' parameters itself: `change_detection` here sets the detector of that name only.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DetectorParams {
    /// Change detection's.
    pub change_detection: Option<ChangeDetectionParams>,
    /// Gridmap's.
    pub gridmap: Option<GridmapParams>,
    /// Entropy's.
    pub entropy: Option<EntropyParams>,
    /// The histogram detector's.
    pub histogram: Option<HistogramParams>,
    /// SM's.
    pub sm: Option<SimilarityParams>,
    /// DM's.
    pub dm: Option<SimilarityParams>,
    /// Better hypothesis'.
    pub better_hypothesis: Option<BetterHypothesisParams>,
    /// Re-registration's.
    pub realign: Option<RealignParams>,
    /// The combined decision's (its thresholds and its three parts').
    pub combined: Option<CombinedParams>,
}

impl Validate for DetectorParams {
    fn check(&self, check: &mut Checker) {
        check
            .nested_opt("change_detection", self.change_detection.as_ref())
            .nested_opt("gridmap", self.gridmap.as_ref())
            .nested_opt("entropy", self.entropy.as_ref())
            .nested_opt("histogram", self.histogram.as_ref())
            .nested_opt("sm", self.sm.as_ref())
            .nested_opt("dm", self.dm.as_ref())
            .nested_opt("better_hypothesis", self.better_hypothesis.as_ref())
            .nested_opt("realign", self.realign.as_ref())
            .nested_opt("combined", self.combined.as_ref());
    }
}

impl DetectorParams {
    /// The detector called `name` with these parameters where given, the defaults otherwise
    /// ([`detector`]); `None` for an unknown name.
    pub fn detector(&self, name: &str) -> Option<Box<dyn InvalidMergeDetector>> {
        fn with<P: Clone, D: InvalidMergeDetector + 'static>(
            params: &Option<P>,
            make: fn(P) -> D,
        ) -> Option<Box<dyn InvalidMergeDetector>> {
            params
                .clone()
                .map(|p| Box::new(make(p)) as Box<dyn InvalidMergeDetector>)
        }
        let given = match name {
            "change_detection" => with(&self.change_detection, ChangeDetectionDetector::new),
            "gridmap" => with(&self.gridmap, GridmapDetector::new),
            "entropy" => with(&self.entropy, EntropyDetector::new),
            "histogram" => with(&self.histogram, HistogramDetector::new),
            "sm" => with(&self.sm, SmDetector::new),
            "dm" => with(&self.dm, DmDetector::new),
            "better_hypothesis" => with(&self.better_hypothesis, BetterHypothesisDetector::new),
            "realign" => with(&self.realign, RealignDetector::new),
            "combined" => with(&self.combined, CombinedDetector::new),
            _ => None,
        };
        given.or_else(|| detector(name))
    }
}

/// Every detector with default parameters, in the order of [`DETECTOR_NAMES`].
pub fn all_detectors() -> Vec<Box<dyn InvalidMergeDetector>> {
    DETECTOR_NAMES
        .iter()
        .filter_map(|name| detector(name))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_defaults_pass_their_checks_and_values_out_of_range_name_their_path() {
        let every = DetectorParams {
            change_detection: Some(Default::default()),
            gridmap: Some(Default::default()),
            entropy: Some(Default::default()),
            histogram: Some(Default::default()),
            sm: Some(Default::default()),
            dm: Some(Default::default()),
            better_hypothesis: Some(Default::default()),
            realign: Some(Default::default()),
            combined: Some(Default::default()),
        };
        assert_eq!(DetectorParams::default().validate(), Ok(()));
        assert_eq!(every.validate(), Ok(()));
        let field = |params: DetectorParams| params.validate().map_err(|e| e.field);
        let combined = DetectorParams {
            combined: Some(CombinedParams {
                change_detection_threshold: -1.0,
                ..Default::default()
            }),
            ..Default::default()
        };
        assert_eq!(
            field(combined),
            Err("combined.change_detection_threshold".into())
        );
        let parsed = |json: &str| field(serde_json::from_str(json).unwrap());
        for (json, path) in [
            (
                r#"{"sm": {"max_cells": 18446744073709551615}}"#,
                "sm.max_cells",
            ),
            (
                r#"{"dm": {"thresholds": {"occupied_min": 0.65, "free_max": 0.9}}}"#,
                "dm.thresholds.free_max",
            ),
            (r#"{"entropy": {"radius_m": -0.3}}"#, "entropy.radius_m"),
            (
                r#"{"histogram": {"other_support_radius_m": -1}}"#,
                "histogram.other_support_radius_m",
            ),
            (
                r#"{"change_detection": {"max_visibility_cells": 4294967296}}"#,
                "change_detection.max_visibility_cells",
            ),
            (
                r#"{"gridmap": {"recent_scans": 0}}"#,
                "gridmap.recent_scans",
            ),
            (r#"{"realign": {"reach_m": -3}}"#, "realign.reach_m"),
            (
                r#"{"better_hypothesis": {"min_confidence": 1.5}}"#,
                "better_hypothesis.min_confidence",
            ),
            (
                r#"{"combined": {"gridmap": {"cell_m": 0}}}"#,
                "combined.gridmap.cell_m",
            ),
        ] {
            assert_eq!(parsed(json), Err(path.into()), "{json}");
        }
        // The place and scan-matching crates' parameters are checked in place.
        let mut params = every.clone();
        if let Some(realign) = params.realign.as_mut() {
            realign.correlative.resolution_m = -0.1;
        }
        let path = field(params).unwrap_err();
        assert!(path.starts_with("realign.correlative."), "{path}");
    }

    #[test]
    fn every_name_makes_its_detector() {
        for name in DETECTOR_NAMES {
            let d = detector(name).unwrap();
            assert_eq!(d.name(), *name);
        }
        assert!(detector("nope").is_none());
        assert_eq!(all_detectors().len(), DETECTOR_NAMES.len());
    }

    #[test]
    fn parameters_by_name_reach_their_detector_and_only_it() {
        let params: DetectorParams = serde_json::from_str(
            r#"{"combined": {"change_detection_threshold": 0.3}, "gridmap": {}}"#,
        )
        .unwrap();
        for name in DETECTOR_NAMES {
            assert_eq!(params.detector(name).unwrap().name(), *name);
        }
        assert!(params.detector("nope").is_none());
        assert!(serde_json::from_str::<DetectorParams>(r#"{"combined": {"nope": 1}}"#).is_err());
        // The parsed threshold is the combined decision's: a change ratio of 0.2 is below
        // 0.3 and far above 0.15.
        let given = CombinedDetector::new(params.combined.clone().unwrap());
        let lower = CombinedDetector::new(CombinedParams {
            change_detection_threshold: 0.15,
            ..CombinedParams::default()
        });
        let (at_given, at_lower) = (given.combine(0.2, 0.0, 0.0), lower.combine(0.2, 0.0, 0.0));
        assert!(at_lower > at_given + 0.2, "{at_given} vs {at_lower}");
    }

    /// A merged map with nothing in it (before any merge, and after an empty one) reads 0 in
    /// every detector, and no detector claims support for it: nothing to compare is no
    /// evidence either way.
    /// The learned decision is the exception by design: it scores "never supported" where
    /// such merges fell in training (a merge claims overlap), so it reads high here.
    #[test]
    fn an_empty_merged_map_reads_zero_and_unsupported_in_every_detector() {
        use crate::{MergedMap, RatioSupport};
        let empty = MergedMap {
            current: &[],
            other: &[],
        };
        for &name in DETECTOR_NAMES {
            // Before any merge, then after an empty one.
            let mut d = detector(name).unwrap();
            let first = d.on_vertex(&empty);
            d.on_merge(&empty);
            let again = d.on_vertex(&empty);
            assert_eq!(d.evidence(), RatioSupport::Unsupported, "{name}");
            if name == "learned" {
                assert!(first > 0.5 && first == again, "{name}: {first}, {again}");
            } else {
                assert_eq!((first, again), (0.0, 0.0), "{name}");
            }
        }
    }

    /// A merge that puts the current scans where the other epochs saw nothing is unsupported
    /// for every appearance detector (not "valid, 0"); one inside their rooms is supported.
    /// (Better hypothesis, and the combinations holding it, do have evidence far away: they
    /// recognise the rooms where the other epochs put them.)
    #[test]
    fn nothing_to_compare_is_unsupported_and_overlap_is_supported() {
        use crate::testworld::{Case, World};
        use crate::{MergedMap, RatioSupport};
        use mapmerge_geometry::{LieGroup, Se2};
        let open = World::office(false);
        let far = Case::office(&open, &open, &Se2::new(200.0, 0.0, 0.0));
        let right = Case::office(&open, &open, &Se2::identity());
        let last_evidence = |case: &Case, name: &str| {
            let mut d = detector(name).unwrap();
            d.on_merge(&MergedMap {
                current: &case.current[..1],
                other: &case.other,
            });
            let mut ratios = Vec::new();
            for k in 1..=case.current.len() {
                ratios.push(d.on_vertex(&MergedMap {
                    current: &case.current[..k],
                    other: &case.other,
                }));
            }
            (d.evidence(), ratios)
        };
        let place_aware = ["better_hypothesis", "combined", "learned"];
        for &name in DETECTOR_NAMES.iter().filter(|n| !place_aware.contains(n)) {
            let (evidence, ratios) = last_evidence(&far, name);
            assert_eq!(evidence, RatioSupport::Unsupported, "{name} far away");
            assert!(ratios.iter().all(|&r| r == 0.0), "{name}: {ratios:?}");
            let (evidence, _) = last_evidence(&right, name);
            assert_eq!(evidence, RatioSupport::Supported, "{name} in the rooms");
        }
    }
}
