//! The detectors by name, with default parameters (what the evaluation harness and the atlas
//! instantiate).

use crate::{
    BetterHypothesisDetector, ChangeDetectionDetector, CombinedDetector, DmDetector,
    EntropyDetector, GridmapDetector, HistogramDetector, InvalidMergeDetector, SmDetector,
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
}
