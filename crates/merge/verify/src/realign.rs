//! Re-registration (not one of Holoch et al.'s detectors): the window of recent current-epoch
//! scans is matched again against the other epochs' points, around where the merged map has it.
//! A right merge leaves the window where it fits best, up to the drift the front-end adds after
//! it; a wrong one leaves a better fit within reach: for a turn, a shift or a careless place
//! recognition near the true place, the true relative pose. Invalidity is the score deficit
//! `1 − s_here / s_best`, where `s_here` is the best correlative score within `tolerance_m` /
//! `tolerance_rad` of the merged pose and `s_best` the best within `reach_m` at any heading
//! (Olson's correlative score, branch-and-bound as Hess et al. 2016). A look-alike room far
//! away is out of reach: that is better hypothesis' job.
//!
//! Only window points that fall where the other epochs' beams reached (at the merged pose)
//! are matched: a window that leaves the merged map into space it never saw would otherwise
//! fit better shifted back onto it.
//!
//! The search costs tens of ms, so it runs again only after the robot moved `every_m` (or
//! turned `every_rad`), or the merged map moved; in between the last ratio stands.

use std::f64::consts::PI;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::OccupancyGrid;
use mapmerge_params::{Checker, Real, Validate};
use mapmerge_scan::Point2;
use mapmerge_scanmatch::{
    match_scan, match_scan_above, CorrelativeParams, MatchTarget, SearchWindow,
};
use serde::{Deserialize, Serialize};

use crate::common::{extend_points_in_map, moved, unit, OtherSnapshot};
use crate::similarity::{beams_in_map, grid_of};
use crate::{DetectorScan, InvalidMergeDetector, MergedMap, RatioSupport};

/// Parameters of [`RealignDetector`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RealignParams {
    /// The window: the newest scans within this path length (m) (default: 8; longer than
    /// the other detectors' 10 scans, so that a corridor's window reaches a junction).
    pub window_travel_m: f64,
    /// … and at most this many scans (default: 40).
    pub max_window_scans: usize,
    /// Window points farther than this (m) from the newest scan are left out (default: 15;
    /// they set the angular step, Hess et al. Eq. 7).
    pub max_range_m: f64,
    /// Half-width (m) of the box around the merged pose whose best score is `s_here`: the
    /// front-end's drift after a right merge (default: 0.5; measured up to 0.45 m on the public
    /// logs' forced merges).
    pub tolerance_m: f64,
    /// … and its heading half-width (rad) (default: 6°; measured drift up to 3.9°).
    pub tolerance_rad: f64,
    /// Half-width (m) of the search for `s_best`, at any heading (default: 3).
    pub reach_m: f64,
    /// The matcher (default: 0.1 m cells, kernel 1.5 cells, query thinned to 0.1 m).
    pub correlative: CorrelativeParams,
    /// Below this best score nothing fits: unsupported (default: 0.15).
    pub min_score: f64,
    /// Cells (m) of the other epochs' coverage, the space their beams crossed or ended in
    /// (default: 0.25).
    pub coverage_cell_m: f64,
    /// Windows with fewer points (after thinning) are unsupported (default: 100).
    pub min_query_points: usize,
    /// Search again after the newest scan moved this far (m) from the last search's
    /// (default: 1) …
    pub every_m: f64,
    /// … or turned this much (rad) (default: 30°).
    pub every_rad: f64,
}

impl Default for RealignParams {
    fn default() -> Self {
        Self {
            window_travel_m: 8.0,
            max_window_scans: 40,
            max_range_m: 15.0,
            tolerance_m: 0.5,
            tolerance_rad: 6f64.to_radians(),
            reach_m: 3.0,
            correlative: CorrelativeParams {
                resolution_m: 0.1,
                query_voxel_m: 0.1,
                min_score: 0.0,
                ..CorrelativeParams::default()
            },
            min_score: 0.15,
            coverage_cell_m: 0.25,
            min_query_points: 100,
            every_m: 1.0,
            every_rad: 30f64.to_radians(),
        }
    }
}

impl Validate for RealignParams {
    fn check(&self, check: &mut Checker) {
        check
            .real(
                "window_travel_m",
                self.window_travel_m,
                Real::non_negative(),
            )
            .size("max_window_scans", self.max_window_scans, 1, 100_000)
            .real("max_range_m", self.max_range_m, Real::positive())
            .real("tolerance_m", self.tolerance_m, Real::non_negative())
            .real("tolerance_rad", self.tolerance_rad, Real::within(0.0, PI))
            .real("reach_m", self.reach_m, Real::positive())
            .nested("correlative", &self.correlative)
            .real("min_score", self.min_score, Real::fraction())
            .real("coverage_cell_m", self.coverage_cell_m, Real::positive())
            .size("min_query_points", self.min_query_points, 0, 1_000_000)
            .real("every_m", self.every_m, Real::non_negative())
            .real("every_rad", self.every_rad, Real::within(0.0, PI));
    }
}

/// Beams longer than this (m) do not count towards the coverage.
const COVERAGE_RANGE_M: f64 = 40.0;
/// Largest coverage grid (cells); a larger extent gets coarser cells.
const COVERAGE_MAX_CELLS: usize = 1 << 22;

/// What the last search found (`eval invalid-merge --trace`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct RealignInfo {
    /// Best score within the tolerance of the merged pose.
    pub score_here: f64,
    /// Best score within reach (≥ `score_here`).
    pub score_best: f64,
    /// How far (m) the best pose lies from the merged one.
    pub best_offset_m: f64,
    /// Its heading difference (rad).
    pub best_offset_rad: f64,
    /// Window points searched (after thinning).
    pub query_points: usize,
}

/// The re-registration detector (see the module docs).
#[derive(Debug, Default)]
pub struct RealignDetector {
    params: RealignParams,
    /// The merged map at the last search.
    snapshot: Option<OtherSnapshot>,
    /// The newest scan's pose at the last search.
    searched_at: Option<Se2>,
    ratio: f64,
    evidence: RatioSupport,
    info: RealignInfo,
    target: Option<MatchTarget>,
    /// Where the other epochs' beams reached, built with the snapshot.
    coverage: Option<OccupancyGrid>,
    other_points: Vec<Point2>,
    query: Vec<Point2>,
}

impl RealignDetector {
    /// A detector with `params`.
    pub fn new(params: RealignParams) -> Self {
        Self {
            params,
            ..Self::default()
        }
    }

    /// What the last search found.
    pub fn info(&self) -> RealignInfo {
        self.info
    }

    /// The window's points in the frame of its newest scan, thinned by the matcher later.
    /// Returns the newest scan's pose.
    fn window(&mut self, current: &[DetectorScan]) -> Option<Se2> {
        let newest = current.last()?;
        let map_from_anchor = newest.map_from_robot;
        if !map_from_anchor.is_finite() {
            return None;
        }
        let anchor_from_map = map_from_anchor.inverse();
        let max_range = self.params.max_range_m;
        let coverage = self.coverage.as_ref();
        self.query.clear();
        let mut travel_m = 0.0;
        let mut previous = map_from_anchor.translation();
        for scan in current
            .iter()
            .rev()
            .take(self.params.max_window_scans.max(1))
        {
            if !scan.map_from_robot.is_finite() {
                continue;
            }
            travel_m += (scan.map_from_robot.translation() - previous).norm();
            previous = scan.map_from_robot.translation();
            if travel_m > self.params.window_travel_m {
                break;
            }
            let anchor_from_robot = anchor_from_map.compose(&scan.map_from_robot);
            let covered = |p: &Point2| {
                coverage.is_some_and(|c| c.log_odds_at(&map_from_anchor.transform_point(p)) != 0.0)
            };
            self.query.extend(
                scan.points_in_robot
                    .iter()
                    .filter(|p| p.x.is_finite() && p.y.is_finite())
                    .map(|p| anchor_from_robot.transform_point(p))
                    .filter(|p| p.norm() <= max_range && covered(p)),
            );
        }
        Some(map_from_anchor)
    }

    /// Searches again: `None` when there is too little to compare.
    fn search(&mut self, map: &MergedMap<'_>) -> Option<(f64, RealignInfo)> {
        let map_from_anchor = self.window(map.current)?;
        let params = &self.params;
        // The other epochs' points that the search can reach.
        let reach = params.max_range_m + params.reach_m + params.correlative.resolution_m;
        let centre = map_from_anchor.translation();
        self.other_points.clear();
        for scan in map.other {
            extend_points_in_map(scan, &mut self.other_points);
        }
        self.other_points
            .retain(|p| (p.x - centre.x).abs() <= reach && (p.y - centre.y).abs() <= reach);
        let wide = SearchWindow::global(params.reach_m);
        let mut correlative = params.correlative;
        correlative.branch_and_bound_depth = wide
            .branch_and_bound_depth(correlative.resolution_m)?
            .min(16);
        let target = match self.target.as_mut() {
            Some(target) => {
                target.rebuild(&self.other_points, &correlative).ok()?;
                target
            }
            None => self
                .target
                .insert(MatchTarget::new(&self.other_points, &correlative).ok()?),
        };
        let thinned = mapmerge_scan::voxel_downsample(&self.query, correlative.query_voxel_m);
        if thinned.len() < params.min_query_points {
            return None;
        }
        let near = SearchWindow::new(params.tolerance_m, params.tolerance_rad);
        let here = match_scan(target, &thinned, &map_from_anchor, &near)?;
        // Only a fit better than the one here matters: the search prunes below it.
        let best = match_scan_above(target, &thinned, &map_from_anchor, &wide, here.score)
            .filter(|best| best.score > here.score)
            .unwrap_or(here);
        if best.score < params.min_score {
            return None;
        }
        let offset = map_from_anchor.between(&best.target_from_query);
        let info = RealignInfo {
            score_here: here.score,
            score_best: best.score,
            best_offset_m: offset.translation().norm(),
            best_offset_rad: offset.theta_rad.abs(),
            query_points: thinned.len(),
        };
        Some((unit(1.0 - here.score / best.score), info))
    }
}

impl InvalidMergeDetector for RealignDetector {
    fn name(&self) -> &'static str {
        "realign"
    }

    fn on_merge(&mut self, map: &MergedMap<'_>) {
        self.snapshot = Some(OtherSnapshot::new(map.other));
        self.searched_at = None;
        self.ratio = 0.0;
        self.evidence = RatioSupport::Unsupported;
        self.info = RealignInfo::default();
        self.coverage = None;
    }

    fn on_vertex(&mut self, map: &MergedMap<'_>) -> f64 {
        let resolution_m = self.params.correlative.resolution_m;
        let map_moved = self
            .snapshot
            .as_ref()
            .is_none_or(|s| !s.still_valid(map.other, resolution_m, 0.01));
        let newest = map.current.last().map(|s| s.map_from_robot);
        let robot_moved = match (&self.searched_at, &newest) {
            (Some(then), Some(now)) => moved(then, now, self.params.every_m, self.params.every_rad),
            _ => true,
        };
        if !(map_moved || robot_moved) {
            return self.ratio;
        }
        if map_moved {
            self.snapshot = Some(OtherSnapshot::new(map.other));
            self.coverage = None;
        }
        if self.coverage.is_none() {
            let beams = beams_in_map(map.other, COVERAGE_RANGE_M);
            self.coverage = grid_of(&beams, self.params.coverage_cell_m, COVERAGE_MAX_CELLS);
        }
        self.searched_at = newest;
        match self.search(map) {
            Some((ratio, info)) => {
                self.ratio = ratio;
                self.info = info;
                self.evidence = RatioSupport::Supported;
            }
            None => {
                self.ratio = 0.0;
                self.info = RealignInfo::default();
                self.evidence = RatioSupport::Unsupported;
            }
        }
        self.ratio
    }

    /// Unsupported when the window or the other epochs near it hold too little to match.
    fn evidence(&self) -> RatioSupport {
        self.evidence
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testworld::{line, scans_along, wrong_turned, Case, World};

    #[test]
    fn a_turned_merge_fits_better_elsewhere_and_a_right_one_does_not() {
        let (open, closed) = (World::office(false), World::office(true));
        let make = || RealignDetector::default();
        let correct = Case::office(&open, &open, &Se2::identity()).max_ratio(&mut make());
        let door = Case::office(&open, &closed, &Se2::identity()).max_ratio(&mut make());
        let turned = Case::office(&open, &open, &wrong_turned()).max_ratio(&mut make());
        assert!(correct < 0.05, "{correct}");
        assert!(door < 0.05, "{door}");
        assert!(turned > 0.2, "{turned}");
    }

    /// A corridor the other epoch saw up to a closed door at x = 12; the robot now drives on
    /// through the open door. Its window leaves the merged map, and the part of it the other
    /// epoch never saw must not pull the window back along the corridor.
    #[test]
    fn a_window_leaving_the_merged_map_is_no_evidence_against_a_right_merge() {
        let corridor = |door_closed: bool| {
            let mut w = World::default();
            w.wall(-10.0, 0.0, 40.0, 0.0);
            w.wall(-10.0, 2.0, 40.0, 2.0);
            // Door niches, so that the corridor is not the same everywhere.
            for x in [2.0, 7.5, 16.0, 23.0] {
                w.rect(x, 2.0, x + 1.0, 2.6);
            }
            if door_closed {
                w.wall(12.0, 0.0, 12.0, 2.0);
            }
            w
        };
        let (then, now) = (corridor(true), corridor(false));
        let tour = line(0.0, 1.0, 10.0, 1.0, 0.0, 20);
        let walk = line(6.0, 1.0, 20.0, 1.0, 0.0, 28);
        let case = |map_from_world: &Se2| Case {
            other: scans_along(&then, &tour, &Se2::identity(), 1, 0),
            current: scans_along(&now, &walk, map_from_world, 2, 1000),
        };
        let right = case(&Se2::identity()).max_ratio(&mut RealignDetector::default());
        let shifted = case(&Se2::new(0.0, 0.0, 0.3)).max_ratio(&mut RealignDetector::default());
        assert!(right < 0.05, "{right}");
        assert!(shifted > 0.2, "{shifted}");
    }
}
