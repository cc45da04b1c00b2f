//! Whole-epoch agreement (our addition beyond Holoch et al. and iRobot). A merge claims that
//! the *whole* current epoch lies in the other map where the merge puts it, not only the places
//! that were recognised. Place recognition and the window detectors look at a few metres; an
//! epoch that came from a part of the building the look-alike does not share carries the
//! contradiction in its older scans. The epoch's scans, joined in the map frame with the free
//! space their beams crossed, are compared with the other epochs' scans near them by the
//! whole-map agreement of `mapmerge_place::evidence` (Birk & Carpin 2006's `agr / (agr + dis)`
//! over points: a point agrees near a return of the other map and disagrees in its free space).
//!
//! It is a check, not a detector of the registry: it reads an agreement, not a ratio, and is
//! meant to be asked rarely (a conditional merge, a full acceptance), since it joins the
//! whole epoch each time.

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_place::{evidence, EvidenceParams, Keyframe};
use mapmerge_scan::Point2;
use serde::{Deserialize, Serialize};

use crate::similarity::beams_in_map;
use crate::{DetectorScan, MergedMap};

/// Parameters of [`epoch_agreement`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EpochAgreementParams {
    /// A merge is contradicted below this agreement (default: 0.95, from a first reading of
    /// wrong and correct merges on the simulator's tuning seeds 11–20 of the warehouse and the
    /// symmetric hall and on the three tuning logs).
    pub min_agreement: f64,
    /// … over at least this many points where both maps know the space; fewer give no
    /// reading (default: 500).
    pub min_overlap_points: usize,
    /// The other epochs' scans whose vertex lies within this distance (m) of one of the
    /// current epoch's take part (default: 6, the keyframes' local-map travel).
    pub other_within_m: f64,
    /// At most this many scans of each side, evenly spread over it (default: 400).
    pub max_scans: usize,
    /// Returns farther than this (m) are left out (default: 20).
    pub max_range_m: f64,
    /// Cell (m) of the free space the beams crossed (default: 0.1, the keyframes').
    pub free_space_m: f64,
    /// The comparison (default: `EvidenceParams::default()`: points thinned to 0.1 m).
    pub evidence: EvidenceParams,
}

impl Default for EpochAgreementParams {
    fn default() -> Self {
        Self {
            min_agreement: 0.95,
            min_overlap_points: 500,
            other_within_m: 6.0,
            max_scans: 400,
            max_range_m: 20.0,
            free_space_m: 0.1,
            evidence: EvidenceParams::default(),
        }
    }
}

/// What [`epoch_agreement`] read.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpochAgreement {
    /// Of the points of either side where the other knows the space, the share near one of
    /// its returns.
    pub agreement: f64,
    /// How many such points.
    pub overlap_points: usize,
}

impl EpochAgreement {
    /// Whether this reading contradicts the merge: enough overlap, too little agreement.
    pub fn contradicts(&self, params: &EpochAgreementParams) -> bool {
        self.overlap_points >= params.min_overlap_points && self.agreement < params.min_agreement
    }
}

/// The whole current epoch of `map` against the other epochs' scans near it, both in the
/// map frame. `None` when either side is empty or has no free space to compare.
pub fn epoch_agreement(
    map: &MergedMap<'_>,
    params: &EpochAgreementParams,
) -> Option<EpochAgreement> {
    let within_sq = params.other_within_m * params.other_within_m;
    let current: Vec<&DetectorScan> = spread(map.current.iter(), params.max_scans);
    let near = map.other.iter().filter(|o| {
        let at = o.map_from_robot.translation();
        current
            .iter()
            .any(|c| (c.map_from_robot.translation() - at).norm_squared() <= within_sq)
    });
    let other = spread(near, params.max_scans);
    let (query, candidate) = (joined(&current, params), joined(&other, params));
    let found = evidence(
        &query?,
        &candidate?,
        &Se2::identity(),
        0.0,
        &params.evidence,
    );
    found.whole_map.then_some(EpochAgreement {
        agreement: found.agreement,
        overlap_points: found.overlap_points,
    })
}

/// At most `max` of `scans`, evenly spread, in order.
fn spread<'a>(scans: impl Iterator<Item = &'a DetectorScan>, max: usize) -> Vec<&'a DetectorScan> {
    let all: Vec<&DetectorScan> = scans.collect();
    let stride = all.len().div_ceil(max.max(1)).max(1);
    all.into_iter().step_by(stride).collect()
}

/// `scans` as one keyframe in the map frame, with the free space their beams crossed;
/// `None` without returns.
fn joined(scans: &[&DetectorScan], params: &EpochAgreementParams) -> Option<Keyframe> {
    let beams = beams_in_map(scans.iter().copied(), params.max_range_m);
    let rays: Vec<(Point2, Point2)> = beams
        .iter()
        .flat_map(|(origin, ends)| ends.iter().map(move |end| (*origin, *end)))
        .collect();
    let points: Vec<Point2> = rays.iter().map(|(_, end)| *end).collect();
    (!points.is_empty()).then(|| Keyframe::new(0, points).with_rays(params.free_space_m, rays))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;
    use crate::testworld::{wrong_shifted, wrong_turned, Case, World};

    fn agreement_of(case: &Case) -> Option<EpochAgreement> {
        epoch_agreement(
            &MergedMap {
                current: &case.current,
                other: &case.other,
            },
            &EpochAgreementParams::default(),
        )
    }

    #[test]
    fn a_right_merge_agrees_and_wrong_ones_contradict() {
        let world = World::office(false);
        let params = EpochAgreementParams::default();
        let right = agreement_of(&Case::office(&world, &world, &Se2::identity())).expect("overlap");
        assert!(right.agreement > 0.97, "{right:?}");
        assert!(
            right.overlap_points >= params.min_overlap_points,
            "{right:?}"
        );
        assert!(!right.contradicts(&params));
        for wrong in [wrong_turned(), wrong_shifted()] {
            let read = agreement_of(&Case::office(&world, &world, &wrong)).expect("overlap");
            assert!(read.contradicts(&params), "{wrong:?}: {read:?}");
        }
    }

    #[test]
    fn too_little_overlap_contradicts_nothing() {
        let read = EpochAgreement {
            agreement: 0.5,
            overlap_points: 499,
        };
        assert!(!read.contradicts(&EpochAgreementParams::default()));
    }

    #[test]
    fn nothing_to_compare_gives_no_reading() {
        let world = World::office(false);
        let right = Case::office(&world, &world, &Se2::identity());
        let alone = MergedMap {
            current: &right.current,
            other: &[],
        };
        let params = EpochAgreementParams::default();
        assert_eq!(epoch_agreement(&alone, &params), None);
        // Far away: no other scan is near enough to take part.
        let far = Case::office(&world, &world, &Se2::new(500.0, 0.0, 0.0));
        assert_eq!(agreement_of(&far), None);
    }

    #[test]
    fn spreading_keeps_order_and_bounds() {
        let scans: Vec<DetectorScan> = (0..10)
            .map(|i| DetectorScan {
                node: mapmerge_posegraph::NodeId(i),
                epoch: 0,
                map_from_robot: Se2::identity(),
                points_in_robot: Vec::new().into(),
            })
            .collect();
        let ids = |max: usize| -> Vec<u64> {
            spread(scans.iter(), max).iter().map(|s| s.node.0).collect()
        };
        assert_eq!(ids(4), [0, 3, 6, 9]);
        assert_eq!(ids(0), [0], "at least one");
        assert_eq!(ids(20).len(), 10);
    }
}
