//! Andersone's map metrics as invalid-merge detectors (Andersone 2019, Sec. 3.3): a grid of the
//! `n` most recent current-epoch scans against the other epochs' grid in the same area
//! (cropped to the window grid's extent), compared by `mapmerge-gridmatch`'s `map_metrics`
//! over the cells known in both. SM: invalidity `1 − SM`. DM: `DM / (DM + s)` (monotone in DM,
//! so ROC and AUC are DM's). Both 0 below `τ` of overlap.
//!
//! The other epochs' grid is built once per merge (exact ray casting, `mapmerge-grid`) and
//! rebuilt when their poses move.

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{ClassThresholds, GridGeometry, InsertParams, OccupancyGrid};
use mapmerge_gridmatch::{map_metrics, MapMetrics};
use mapmerge_params::{Checker, Real, Validate};
use mapmerge_scan::Point2;
use serde::{Deserialize, Serialize};

use crate::common::{recent, unit, OtherSnapshot};
use crate::{DetectorScan, InvalidMergeDetector, MergedMap, RatioSupport};

/// Parameters of [`SmDetector`] and [`DmDetector`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimilarityParams {
    /// `n`: scans of the window's grid (default: 10; Andersone compares after 10 scans).
    pub recent_scans: usize,
    /// Grid cell (m) (default: 0.05; Andersone used 0.07–0.1).
    pub cell_m: f64,
    /// Classes (default: occupied from p = 0.65, free up to p = 0.45, so one beam through a
    /// cell makes it free).
    pub thresholds: ClassThresholds,
    /// `τ`: below this overlap (m²) the ratio is 0 (default: 2).
    pub min_overlap_m2: f64,
    /// `s` (m) of DM's map into [0, 1] (default: 0.2; Andersone's correct merges stay below
    /// ~0.17 m, wrong ones above ~0.27 m).
    pub dm_scale_m: f64,
    /// Beams longer than this (m) are not used (default: 40).
    pub max_range_m: f64,
    /// Largest other-epoch grid (cells); a larger extent gets coarser cells (default: 2²⁴).
    pub max_cells: usize,
}

impl Default for SimilarityParams {
    fn default() -> Self {
        Self {
            recent_scans: 10,
            cell_m: 0.05,
            thresholds: ClassThresholds {
                occupied_min: 0.65,
                free_max: 0.45,
            },
            min_overlap_m2: 2.0,
            dm_scale_m: 0.2,
            max_range_m: 40.0,
            max_cells: 1 << 24,
        }
    }
}

impl Validate for SimilarityParams {
    fn check(&self, check: &mut Checker) {
        check
            .size("recent_scans", self.recent_scans, 1, 100_000)
            .real("cell_m", self.cell_m, Real::positive())
            .nested("thresholds", &self.thresholds)
            .real("min_overlap_m2", self.min_overlap_m2, Real::non_negative())
            .real("dm_scale_m", self.dm_scale_m, Real::positive())
            .real("max_range_m", self.max_range_m, Real::positive())
            .size("max_cells", self.max_cells, 1, 1 << 28);
    }
}

/// The beams of `scans` in the map frame: (sensor origin, return points), non-finite and
/// over-long ones left out.
pub(crate) fn beams_in_map<'a>(
    scans: impl IntoIterator<Item = &'a DetectorScan>,
    max_range_m: f64,
) -> Vec<(Point2, Vec<Point2>)> {
    scans
        .into_iter()
        .filter(|s| s.map_from_robot.is_finite())
        .map(|s| {
            let pose = &s.map_from_robot;
            let ends = s
                .points_in_robot
                .iter()
                .filter(|p| p.norm() > 0.0 && p.norm() <= max_range_m)
                .map(|p| pose.transform_point(p))
                .collect();
            (pose.translation(), ends)
        })
        .collect()
}

/// A log-odds grid of `beams` (exact ray casting), `None` when empty or too large.
pub(crate) fn grid_of(
    beams: &[(Point2, Vec<Point2>)],
    cell_m: f64,
    max_cells: usize,
) -> Option<OccupancyGrid> {
    let (lo, hi) = beams.iter().fold(
        (
            Point2::repeat(f64::INFINITY),
            Point2::repeat(f64::NEG_INFINITY),
        ),
        |(l, h), (o, ends)| {
            let (l, h) = (l.inf(o), h.sup(o));
            ends.iter().fold((l, h), |(l, h), e| (l.inf(e), h.sup(e)))
        },
    );
    if !(lo.x <= hi.x && lo.y <= hi.y) {
        return None;
    }
    let extent = hi - lo;
    let mut cell_m = if cell_m.is_finite() && cell_m > 0.0 {
        cell_m
    } else {
        0.05
    };
    let max_cells = max_cells.max(1) as f64;
    if (extent.x / cell_m + 2.0) * (extent.y / cell_m + 2.0) > max_cells {
        cell_m = ((extent.x + 1.0) * (extent.y + 1.0) / max_cells).sqrt() * 1.01;
    }
    let mut grid = OccupancyGrid::new(cell_m).ok()?;
    let model = InsertParams::default().model;
    for (origin, ends) in beams {
        let _ = grid.insert_rays(origin, ends, &[], &model);
    }
    (!grid.geometry().is_empty()).then_some(grid)
}

/// `source`'s log-odds on `geometry`'s lattice (same resolution, corners on multiples of it).
fn crop(source: &OccupancyGrid, geometry: &GridGeometry) -> Option<OccupancyGrid> {
    let g = source.geometry();
    let shift = (geometry.origin_m - g.origin_m) / g.resolution_m;
    let (sx, sy) = (shift.x.round() as i64, shift.y.round() as i64);
    let mut values = vec![0.0f32; geometry.len()];
    let log_odds = source.log_odds();
    for y in 0..geometry.height {
        let ys = y as i64 + sy;
        if ys < 0 || ys >= g.height as i64 {
            continue;
        }
        for x in 0..geometry.width {
            let xs = x as i64 + sx;
            if xs < 0 || xs >= g.width as i64 {
                continue;
            }
            if let (Some(v), Some(&l)) = (
                values.get_mut(y * geometry.width + x),
                log_odds.get(ys as usize * g.width + xs as usize),
            ) {
                *v = l;
            }
        }
    }
    OccupancyGrid::from_log_odds(*geometry, values).ok()
}

/// The shared part of SM and DM.
#[derive(Debug, Default)]
struct Similarity {
    params: SimilarityParams,
    snapshot: Option<OtherSnapshot>,
    other: Option<OccupancyGrid>,
    /// Whether the last window overlapped the other epochs by `τ`.
    evidence: RatioSupport,
}

impl Similarity {
    fn prepare(&mut self, other: &[DetectorScan]) {
        self.snapshot = Some(OtherSnapshot::new(other));
        let beams = beams_in_map(other, self.params.max_range_m);
        self.other = grid_of(&beams, self.params.cell_m, self.params.max_cells);
    }

    /// The metrics of the window's grid against the other epochs' there, when the overlap
    /// reaches τ.
    fn metrics(&mut self, map: &MergedMap<'_>) -> Option<MapMetrics> {
        let metrics = self.overlapping_metrics(map);
        self.evidence = if metrics.is_some() {
            RatioSupport::Supported
        } else {
            RatioSupport::Unsupported
        };
        metrics
    }

    fn overlapping_metrics(&mut self, map: &MergedMap<'_>) -> Option<MapMetrics> {
        let tolerance_m = self.params.cell_m.max(0.0);
        if self
            .snapshot
            .as_ref()
            .is_none_or(|s| !s.still_valid(map.other, tolerance_m, 0.01))
        {
            self.prepare(map.other);
        }
        let other = self.other.as_ref()?;
        let beams = beams_in_map(
            recent(map.current, self.params.recent_scans),
            self.params.max_range_m,
        );
        // The window's grid at the other grid's resolution (both lattices on multiples of it).
        let window = grid_of(&beams, other.resolution_m(), usize::MAX)?;
        let other_here = crop(other, window.geometry())?;
        let metrics = map_metrics(
            &window,
            &other_here,
            &Se2::identity(),
            &self.params.thresholds,
        )
        .ok()?;
        let cell_m = metrics.resolution_m;
        ((metrics.overlap_cells as f64) * cell_m * cell_m >= self.params.min_overlap_m2)
            .then_some(metrics)
    }
}

/// Andersone's similarity metric SM as a detector: invalidity `1 − SM`.
#[derive(Debug, Default)]
pub struct SmDetector(Similarity);

impl SmDetector {
    /// A detector with `params`.
    pub fn new(params: SimilarityParams) -> Self {
        Self(Similarity {
            params,
            ..Similarity::default()
        })
    }
}

impl InvalidMergeDetector for SmDetector {
    fn name(&self) -> &'static str {
        "sm"
    }

    fn on_merge(&mut self, map: &MergedMap<'_>) {
        self.0.prepare(map.other);
    }

    fn on_vertex(&mut self, map: &MergedMap<'_>) -> f64 {
        self.0.metrics(map).map_or(0.0, |m| unit(1.0 - m.sm))
    }

    /// Unsupported below `τ` of overlap.
    fn evidence(&self) -> RatioSupport {
        self.0.evidence
    }
}

/// Andersone's distance metric DM as a detector: invalidity `DM / (DM + s)`.
#[derive(Debug, Default)]
pub struct DmDetector(Similarity);

impl DmDetector {
    /// A detector with `params`.
    pub fn new(params: SimilarityParams) -> Self {
        Self(Similarity {
            params,
            ..Similarity::default()
        })
    }
}

impl InvalidMergeDetector for DmDetector {
    fn name(&self) -> &'static str {
        "dm"
    }

    fn on_merge(&mut self, map: &MergedMap<'_>) {
        self.0.prepare(map.other);
    }

    fn on_vertex(&mut self, map: &MergedMap<'_>) -> f64 {
        let scale = self.0.params.dm_scale_m;
        let scale = if scale.is_finite() && scale > 0.0 {
            scale
        } else {
            0.2
        };
        self.0.metrics(map).map_or(0.0, |m| {
            let dm = m.dm_m();
            if dm.is_finite() {
                unit(dm / (dm + scale))
            } else {
                0.0
            }
        })
    }

    /// Unsupported below `τ` of overlap.
    fn evidence(&self) -> RatioSupport {
        self.0.evidence
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testworld::{wrong_turned, Case, World};

    #[test]
    fn wrong_merges_read_higher_than_correct_ones() {
        let (open, closed) = (World::office(false), World::office(true));
        for make in [
            || Box::new(SmDetector::default()) as Box<dyn InvalidMergeDetector>,
            || Box::new(DmDetector::default()) as Box<dyn InvalidMergeDetector>,
        ] {
            let correct = Case::office(&open, &open, &Se2::identity()).max_ratio(make().as_mut());
            let door = Case::office(&open, &closed, &Se2::identity()).max_ratio(make().as_mut());
            let turned = Case::office(&open, &open, &wrong_turned()).max_ratio(make().as_mut());
            assert!(
                turned > correct.max(door),
                "{}: {turned} vs {correct} / {door}",
                make().name()
            );
        }
    }
}
