//! The map manager's run over one log (Ehlers et al., Sec. II): door passings split the log
//! into areas, each area is mapped on its own with the configuration its environment calls
//! for, and each passing becomes a link point known in the two maps it joins.
//!
//! The maps overlap at each door: an area's scans run `overlap_m` of travel past the door it
//! leaves by, and start `overlap_m` before the door it enters by, so the crossing's pose is in
//! both maps (Sec. II-A: link points lie "in an area where both maps slightly overlap").

use std::ops::Range;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::LaserScan;
use serde::{Deserialize, Serialize};

use crate::door::{DoorDetector, DoorParams, DoorPassingDetection};
use crate::environment::{Environment, Extents};
use crate::error::AreasError;
use crate::hybrid::{Area, HybridMap, LinkPoint};

/// Parameters of the map manager.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ManagerParams {
    /// Door detection.
    pub doors: DoorParams,
    /// How far adjacent maps overlap on each side of a door (m) (default: 1).
    pub overlap_m: f64,
    /// An area with fewer scans joins the one before it: its door passing is not a map
    /// boundary (default: 20).
    pub min_area_scans: usize,
    /// The first area's environment is judged after this many scans (default: 20).
    pub first_environment_scans: usize,
}

impl Default for ManagerParams {
    fn default() -> Self {
        Self {
            doors: DoorParams::default(),
            overlap_m: 1.0,
            min_area_scans: 20,
            first_environment_scans: 20,
        }
    }
}

/// The scans of one area.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AreaSpan {
    /// Scan indices (into the log), overlap included.
    pub scans: Range<usize>,
    /// Its environment.
    pub environment: Environment,
}

/// A log split at its door passings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Segmentation {
    /// Every passing detected (boundaries or not).
    pub passings: Vec<DoorPassingDetection>,
    /// The areas, in time order.
    pub spans: Vec<AreaSpan>,
    /// For each boundary between span `k` and `k + 1`: the passing (index into `passings`).
    pub boundaries: Vec<usize>,
}

/// Splits a log (`odom_from_robot` and scan of each scan) at its door passings.
pub fn segment<'a>(
    scans: impl IntoIterator<Item = (Se2, &'a LaserScan)>,
    params: &ManagerParams,
) -> Result<Segmentation, AreasError> {
    let mut detector = DoorDetector::new(params.doors.clone())?;
    let mut first_environment = Extents::new(params.doors.environment.clone(), f64::INFINITY);
    let mut environment_of_first = None;
    let mut passings = Vec::new();
    let mut travel = Vec::new();
    let mut previous: Option<Se2> = None;
    for (index, (odom_from_robot, scan)) in scans.into_iter().enumerate() {
        let step = previous.map_or(0.0, |p| {
            (odom_from_robot.translation() - p.translation()).norm()
        });
        travel.push(travel.last().copied().unwrap_or(0.0) + step);
        previous = Some(odom_from_robot);
        if environment_of_first.is_none() {
            first_environment.push(&odom_from_robot, scan, travel[index]);
            if index + 1 >= params.first_environment_scans {
                environment_of_first = Some(first_environment.environment(&odom_from_robot));
            }
        }
        if let Some(found) = detector.push(&odom_from_robot, scan) {
            passings.push(found);
        }
    }
    let n = travel.len();
    let environment_of_first = environment_of_first
        .or_else(|| previous.map(|p| first_environment.environment(&p)))
        .unwrap_or(Environment::Indoor);
    // Boundaries at crossings, each area at least `min_area_scans` long.
    let mut cuts: Vec<(usize, usize)> = Vec::new(); // (crossing scan, passing)
    let mut last_cut = 0usize;
    for (i, passing) in passings.iter().enumerate() {
        let c = passing.crossing_scan;
        if c >= last_cut + params.min_area_scans && c + params.min_area_scans <= n {
            cuts.push((c, i));
            last_cut = c;
        }
    }
    // Scan indices `overlap_m` of travel before and after a crossing.
    let before = |c: usize| {
        let limit = travel[c] - params.overlap_m;
        (0..=c).rev().find(|&k| travel[k] <= limit).unwrap_or(0)
    };
    let after = |c: usize| {
        let limit = travel[c] + params.overlap_m;
        (c..n).find(|&k| travel[k] >= limit).map_or(n, |k| k + 1)
    };
    let mut spans = Vec::with_capacity(cuts.len() + 1);
    let mut start = 0;
    let mut environment = environment_of_first;
    for &(c, i) in &cuts {
        spans.push(AreaSpan {
            scans: start..after(c),
            environment,
        });
        start = before(c);
        environment = passings[i].environment;
    }
    if n > 0 {
        spans.push(AreaSpan {
            scans: start..n,
            environment,
        });
    }
    Ok(Segmentation {
        passings,
        boundaries: cuts.iter().map(|(_, i)| *i).collect(),
        spans,
    })
}

/// The hybrid map of a segmented log, given each span's trajectory (`map_from_robot` of each
/// of its scans, in its own map's frame): one area per span, one link point per boundary at
/// the crossing's pose in both maps, edges, and every area placed in the first one's frame.
pub fn hybrid_map(
    segmentation: &Segmentation,
    trajectories: &[Vec<Se2>],
) -> Result<HybridMap, AreasError> {
    if trajectories.len() != segmentation.spans.len() {
        return Err(AreasError::Mapping(format!(
            "{} trajectories for {} areas",
            trajectories.len(),
            segmentation.spans.len()
        )));
    }
    let mut map = HybridMap {
        areas: segmentation
            .spans
            .iter()
            .enumerate()
            .map(|(id, span)| Area {
                id,
                environment: span.environment,
                first_from_area: Se2::identity(),
            })
            .collect(),
        ..HybridMap::default()
    };
    let pose_at = |area: usize, scan: usize| -> Result<Se2, AreasError> {
        let span = &segmentation.spans[area];
        scan.checked_sub(span.scans.start)
            .and_then(|k| trajectories[area].get(k).copied())
            .ok_or_else(|| AreasError::Mapping(format!("area {area} has no pose for scan {scan}")))
    };
    for (k, passing) in segmentation.boundaries.iter().enumerate() {
        let c = segmentation
            .passings
            .get(*passing)
            .map(|p| p.crossing_scan)
            .ok_or_else(|| AreasError::Mapping(format!("no passing {passing}")))?;
        map.link_points.push(LinkPoint {
            id: k,
            areas: [k, k + 1],
            poses: [pose_at(k, c)?, pose_at(k + 1, c)?],
        });
    }
    map.connect();
    map.chain_frames();
    Ok(map)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use mapmerge_sim::{simulate, SimParams};

    use super::*;

    #[test]
    fn a_simulated_session_splits_at_its_doors_and_chains_back_together() {
        let sim = SimParams::default()
            .with_preset_name("office")
            .unwrap()
            .with_sessions(1)
            .with_duration_secs(120.0);
        let data = simulate(&sim, 1).unwrap();
        let session = &data.sessions[0];
        let scans = session
            .log
            .scans
            .iter()
            .map(|r| (r.odom_from_robot.unwrap(), &r.scan));
        let params = ManagerParams::default();
        let split = segment(scans, &params).unwrap();
        assert!(split.spans.len() >= 3, "{} areas", split.spans.len());
        assert_eq!(split.spans.len(), split.boundaries.len() + 1);
        for pair in split.spans.windows(2) {
            assert!(
                pair[1].scans.start < pair[0].scans.end,
                "adjacent maps overlap"
            );
        }
        assert_eq!(split.spans.first().unwrap().scans.start, 0);
        assert_eq!(
            split.spans.last().unwrap().scans.end,
            session.log.scans.len()
        );
        // Each area mapped by the true poses in a frame of its own (its first pose): the chain
        // through the link points must put every area back where the truth has it.
        let trajectories: Vec<Vec<Se2>> = split
            .spans
            .iter()
            .map(|span| {
                let origin = session.truth[span.scans.start].1;
                span.scans
                    .clone()
                    .map(|k| origin.inverse().compose(&session.truth[k].1))
                    .collect()
            })
            .collect();
        let hybrid = hybrid_map(&split, &trajectories).unwrap();
        let world_from_first = session.truth[0].1;
        for (area, span) in hybrid.areas.iter().zip(&split.spans) {
            let world_from_area = session.truth[span.scans.start].1;
            let error = world_from_first
                .compose(&area.first_from_area)
                .between(&world_from_area);
            assert!(
                error.translation().norm() < 1e-6,
                "area {}: {error:?}",
                area.id
            );
        }
        assert!(hybrid_map(&split, &trajectories[1..]).is_err());
    }
}
