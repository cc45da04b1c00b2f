//! The detectors by name, with default parameters (what the evaluation harness and the atlas
//! instantiate).

use crate::{
    BetterHypothesisDetector, ChangeDetectionDetector, CombinedDetector, DmDetector,
    EntropyDetector, GridmapDetector, HistogramDetector, InvalidMergeDetector, LearnedDetector,
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
        "combined" => Box::<CombinedDetector>::default(),
        "learned" => Box::<LearnedDetector>::default(),
        _ => return None,
    };
    Some(boxed)
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
    fn every_name_makes_its_detector() {
        for name in DETECTOR_NAMES {
            let d = detector(name).unwrap();
            assert_eq!(d.name(), *name);
        }
        assert!(detector("nope").is_none());
        assert_eq!(all_detectors().len(), DETECTOR_NAMES.len());
    }

    /// Issue 15, part 3: a merge that puts the current scans where the other epochs saw
    /// nothing is unsupported for every appearance detector (not "valid, 0"); one inside
    /// their rooms is supported. (Better hypothesis, and the combinations holding it, do have
    /// evidence far away: they recognise the rooms where the other epochs put them.)
    #[test]
    fn nothing_to_compare_is_unsupported_and_overlap_is_supported() {
        use crate::testworld::{Case, World};
        use crate::{Evidence, MergedMap};
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
            assert_eq!(evidence, Evidence::Unsupported, "{name} far away");
            assert!(ratios.iter().all(|&r| r == 0.0), "{name}: {ratios:?}");
            let (evidence, _) = last_evidence(&right, name);
            assert_eq!(evidence, Evidence::Supported, "{name} in the rooms");
        }
    }
}
