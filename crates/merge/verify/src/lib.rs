//! Invalid-merge detectors (Holoch et al., "Detecting Invalid Map Merges in Lifelong SLAM",
//! Sec. IV): after a merge, every new vertex of the current epoch is checked against the data
//! of the other epochs, and each detector says how likely the merge is wrong as an
//! *invalidity ratio* in [0, 1] (higher = more likely wrong; an unmerge happens above a
//! threshold `t_unmerge`).
//!
//! Entry points: [`MergedMap`] (what a detector sees: the current epoch's scans and the other
//! epochs' scans, each with its pose in the active map frame), the [`InvalidMergeDetector`]
//! trait, and the detectors.

mod map;

pub use map::{DetectorScan, InvalidMergeDetector, MergedMap};
