//! Point histograms (Holoch et al., Sec. IV-D, after Corso): unnormalised counts of points in
//! 0.5 m cells for the `n` most recent current-epoch scans (`h₁`) and for all other epochs
//! (`h₂`), compared by the intersection kernel `c = Σ min(h₁, h₂) / Σ h₁`; invalidity `1 − c`.
//!
//! Our addition (real logs are not static, and a robot explores): only cells of `h₁` within
//! `other_support_radius_m` of a cell the other epochs have points in are counted, so a robot
//! exploring beyond the merged map does not read as an invalid merge; `None` is the paper's
//! rule. Below `min_points` supported points the ratio is 0.

use std::collections::HashMap;

use mapmerge_params::{Checker, Real, Validate};
use mapmerge_scan::Point2;
use serde::{Deserialize, Serialize};

use crate::common::{extend_points_in_map, recent, unit, OtherSnapshot};
use crate::{DetectorScan, InvalidMergeDetector, MergedMap, RatioSupport};

/// Parameters of [`HistogramDetector`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HistogramParams {
    /// Histogram cell side (m) (default: 0.5, the paper's).
    pub cell_m: f64,
    /// `n` (default: 10).
    pub recent_scans: usize,
    /// Only cells of `h₁` this close (m, square neighbourhood) to a cell with other-epoch
    /// points count (default: 1); `None`: every cell (the paper).
    pub other_support_radius_m: Option<f64>,
    /// Below this many counted points of `h₁` the ratio is 0 (default: 100).
    pub min_points: usize,
}

impl Default for HistogramParams {
    fn default() -> Self {
        Self {
            cell_m: 0.5,
            recent_scans: 10,
            other_support_radius_m: Some(1.0),
            min_points: 100,
        }
    }
}

impl Validate for HistogramParams {
    fn check(&self, check: &mut Checker) {
        check
            .real("cell_m", self.cell_m, Real::positive())
            .size("recent_scans", self.recent_scans, 1, 100_000)
            .real_opt(
                "other_support_radius_m",
                self.other_support_radius_m,
                Real::non_negative(),
            )
            .size("min_points", self.min_points, 0, 100_000_000);
    }
}

type Key = (i64, i64);

/// Point histograms (Holoch et al., Sec. IV-D); see the module documentation.
#[derive(Debug, Default)]
pub struct HistogramDetector {
    params: HistogramParams,
    snapshot: Option<OtherSnapshot>,
    other: HashMap<Key, u32>,
    current: HashMap<Key, u32>,
    points: Vec<Point2>,
    evidence: RatioSupport,
}

impl HistogramDetector {
    /// A detector with `params`.
    pub fn new(params: HistogramParams) -> Self {
        Self {
            params,
            ..Self::default()
        }
    }

    fn cell_m(&self) -> f64 {
        if self.params.cell_m.is_finite() && self.params.cell_m > 0.0 {
            self.params.cell_m
        } else {
            0.5
        }
    }

    fn key(&self, p: &Point2) -> Option<Key> {
        let c = p / self.cell_m();
        (c.x.abs() < 1e15 && c.y.abs() < 1e15).then(|| (c.x.floor() as i64, c.y.floor() as i64))
    }

    fn prepare(&mut self, other: &[DetectorScan]) {
        self.snapshot = Some(OtherSnapshot::new(other));
        self.other.clear();
        let mut points = Vec::new();
        for scan in other {
            extend_points_in_map(scan, &mut points);
        }
        for p in &points {
            if let Some(k) = self.key(p) {
                *self.other.entry(k).or_insert(0) += 1;
            }
        }
    }
}

impl InvalidMergeDetector for HistogramDetector {
    fn name(&self) -> &'static str {
        "histogram"
    }

    fn on_merge(&mut self, map: &MergedMap<'_>) {
        self.prepare(map.other);
    }

    fn on_vertex(&mut self, map: &MergedMap<'_>) -> f64 {
        let tolerance_m = self.cell_m() * 0.2;
        if self
            .snapshot
            .as_ref()
            .is_none_or(|s| !s.still_valid(map.other, tolerance_m, 0.01))
        {
            self.prepare(map.other);
        }
        // h₁ of the window (buffers reused across calls).
        let mut points = std::mem::take(&mut self.points);
        points.clear();
        for scan in recent(map.current, self.params.recent_scans) {
            extend_points_in_map(scan, &mut points);
        }
        let mut current = std::mem::take(&mut self.current);
        current.clear();
        for p in &points {
            if let Some(k) = self.key(p) {
                *current.entry(k).or_insert(0) += 1;
            }
        }
        self.points = points;
        // c = Σ min(h₁, h₂) / Σ h₁ over the supported cells (Sec. IV-D).
        let support = self
            .params
            .other_support_radius_m
            .map(|r| (r.max(0.0) / self.cell_m()).ceil().min(50.0) as i64);
        let (mut intersection, mut total) = (0u64, 0u64);
        for (&(x, y), &h1) in &current {
            let h2 = self.other.get(&(x, y)).copied().unwrap_or(0);
            let supported = match support {
                None => true,
                Some(r) => {
                    h2 > 0
                        || (-r..=r)
                            .any(|dy| (-r..=r).any(|dx| self.other.contains_key(&(x + dx, y + dy))))
                }
            };
            if supported {
                intersection += u64::from(h1.min(h2));
                total += u64::from(h1);
            }
        }
        self.current = current;
        self.evidence = if total == 0 || total < self.params.min_points as u64 {
            RatioSupport::Unsupported
        } else {
            RatioSupport::Supported
        };
        if self.evidence == RatioSupport::Unsupported {
            return 0.0;
        }
        unit(1.0 - intersection as f64 / total as f64)
    }

    /// Unsupported below `min_points` window points near other-epoch data.
    fn evidence(&self) -> RatioSupport {
        self.evidence
    }
}

#[cfg(test)]
mod tests {
    use mapmerge_geometry::{LieGroup, Se2};

    use super::*;
    use crate::testworld::{wrong_turned, Case, World};

    #[test]
    fn a_wrong_merge_reads_higher_and_empty_input_zero() {
        let open = World::office(false);
        let run = |case: Case| case.max_ratio(&mut HistogramDetector::default());
        let correct = run(Case::office(&open, &open, &Se2::identity()));
        let turned = run(Case::office(&open, &open, &wrong_turned()));
        assert!(turned > correct, "{turned} vs {correct}");
        let mut d = HistogramDetector::default();
        let empty = MergedMap {
            current: &[],
            other: &[],
        };
        assert_eq!(d.on_vertex(&empty), 0.0);
    }

    #[test]
    fn exploring_beyond_the_merged_map_is_not_invalid() {
        let open = World::office(false);
        let case = Case::office(&open, &open, &Se2::identity());
        // The current epoch far away from everything the other epochs saw.
        let far: Vec<DetectorScan> = case
            .current
            .iter()
            .map(|s| DetectorScan {
                map_from_robot: Se2::new(100.0, 0.0, 0.0).compose(&s.map_from_robot),
                ..s.clone()
            })
            .collect();
        let mut d = HistogramDetector::default();
        let map = MergedMap {
            current: &far,
            other: &case.other,
        };
        d.on_merge(&map);
        assert_eq!(d.on_vertex(&map), 0.0);
    }
}
