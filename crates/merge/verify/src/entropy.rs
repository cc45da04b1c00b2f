//! Map entropy (Holoch et al., Sec. IV-C, after Droeschel et al. / Razlaw et al.): the mean
//! differential entropy `h(q) = ½ ln det(2πe Σ(q))` of the points, `Σ(q)` the covariance of
//! the points within `r = 0.3 m`, and `ΔH = H_all − ½ (H_current + H_other)`.
//!
//! Choices where the paper is vague or too costly (it reports ~1 s per vertex):
//! - the paper's `½ (H_current − H_other)` is read as the mean of the two parts' entropies;
//! - the point clouds are those in the area of interest (the bounding box of the `n` most
//!   recent current-epoch scans plus a margin), thinned to one point per `voxel_m`, so the
//!   measure reacts to the merge where the robot is and its cost does not grow with the map;
//! - `Σ + σ² I` with the sensor's noise floor `σ` keeps points on a perfect line finite;
//! - neighbours come from a bucket grid of `r`-sized cells (exact for a fixed radius);
//! - `ΔH` is mapped into [0, 1] by the logistic `1 / (1 + exp(−ΔH / s))` (monotone, so ROC
//!   and AUC are those of `ΔH`); 0 when either part has no point with enough neighbours.

use mapmerge_scan::{voxel_downsample, Point2};
use serde::{Deserialize, Serialize};

use crate::common::{extend_points_in_map, logistic, recent, OtherSnapshot};
use crate::{DetectorScan, InvalidMergeDetector, MergedMap};

/// Parameters of [`EntropyDetector`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EntropyParams {
    /// Neighbourhood radius `r` (m) (default: 0.3, the paper's).
    pub radius_m: f64,
    /// The area of interest is the bounding box of this many recent current-epoch scans
    /// (default: 10) …
    pub recent_scans: usize,
    /// … grown by this margin (m) (default: 1).
    pub margin_m: f64,
    /// Points are thinned to one per cell of this size (m) (default: 0.05): entropy then
    /// measures the spread of surfaces, not scanner density.
    pub voxel_m: f64,
    /// A point needs this many neighbours (itself included) for a covariance (default: 3).
    pub min_neighbours: usize,
    /// Noise floor `σ` (m) added as `σ² I` to every covariance (default: 0.01).
    pub noise_floor_m: f64,
    /// Scale `s` (nats) of the logistic that maps `ΔH` into [0, 1] (default: 0.25).
    pub logistic_scale: f64,
    /// Points farther than this (m) from their sensor are ignored (default: 40).
    pub max_range_m: f64,
}

impl Default for EntropyParams {
    fn default() -> Self {
        Self {
            radius_m: 0.3,
            recent_scans: 10,
            margin_m: 1.0,
            voxel_m: 0.05,
            min_neighbours: 3,
            noise_floor_m: 0.01,
            logistic_scale: 0.25,
            max_range_m: 40.0,
        }
    }
}

/// The mean entropy of `points` (Sec. IV-C), `None` when no point has enough neighbours.
pub(crate) fn mean_entropy(points: &[Point2], params: &EntropyParams) -> Option<f64> {
    let r = if params.radius_m.is_finite() && params.radius_m > 0.0 {
        params.radius_m
    } else {
        0.3
    };
    let points: Vec<Point2> = points
        .iter()
        .filter(|p| p.x.is_finite() && p.y.is_finite())
        .copied()
        .collect();
    let (lo, hi) = points.iter().fold(
        (
            Point2::repeat(f64::INFINITY),
            Point2::repeat(f64::NEG_INFINITY),
        ),
        |(l, h), p| (l.inf(p), h.sup(p)),
    );
    if points.is_empty() {
        return None;
    }
    // Bucket grid of r-sized cells, counting-sorted.
    let extent = (hi - lo) / r;
    if !(extent.x < 1e5 && extent.y < 1e5 && extent.x * extent.y < 1e7) {
        return None;
    }
    let (w, h) = (extent.x as usize + 1, extent.y as usize + 1);
    let cell = |p: &Point2| {
        let c = (p - lo) / r;
        ((c.x as usize).min(w - 1), (c.y as usize).min(h - 1))
    };
    let mut starts = vec![0usize; w * h + 1];
    for p in &points {
        let (x, y) = cell(p);
        starts[y * w + x + 1] += 1;
    }
    for i in 1..starts.len() {
        starts[i] += starts[i - 1];
    }
    let mut fill = starts.clone();
    let mut sorted = vec![Point2::zeros(); points.len()];
    for p in &points {
        let (x, y) = cell(p);
        if let Some(slot) = fill.get_mut(y * w + x) {
            if let Some(s) = sorted.get_mut(*slot) {
                *s = *p;
            }
            *slot += 1;
        }
    }
    let (r2, noise) = (r * r, params.noise_floor_m * params.noise_floor_m);
    let two_pi_e = 2.0 * std::f64::consts::PI * std::f64::consts::E;
    let (mut sum, mut used) = (0.0, 0usize);
    for q in &points {
        let (cx, cy) = cell(q);
        let (mut n, mut s, mut sxx, mut sxy, mut syy) = (0usize, Point2::zeros(), 0.0, 0.0, 0.0);
        for y in cy.saturating_sub(1)..=(cy + 1).min(h - 1) {
            for x in cx.saturating_sub(1)..=(cx + 1).min(w - 1) {
                let (a, b) = (starts[y * w + x], starts[y * w + x + 1]);
                for p in sorted.get(a..b).unwrap_or(&[]) {
                    let d = p - q;
                    if d.norm_squared() <= r2 {
                        n += 1;
                        s += d;
                        sxx += d.x * d.x;
                        sxy += d.x * d.y;
                        syy += d.y * d.y;
                    }
                }
            }
        }
        if n < params.min_neighbours.max(2) {
            continue;
        }
        let nf = n as f64;
        let m = s / nf;
        let (cxx, cxy, cyy) = (
            sxx / nf - m.x * m.x,
            sxy / nf - m.x * m.y,
            syy / nf - m.y * m.y,
        );
        let det = (cxx + noise) * (cyy + noise) - cxy * cxy;
        if det > 0.0 && det.is_finite() {
            // ½ ln det(2πe Σ) in 2D.
            sum += two_pi_e.ln() + 0.5 * det.ln();
            used += 1;
        }
    }
    (used > 0).then(|| sum / used as f64)
}

/// Map entropy (Holoch et al., Sec. IV-C); see the module documentation.
#[derive(Debug, Default)]
pub struct EntropyDetector {
    params: EntropyParams,
    snapshot: Option<OtherSnapshot>,
    other_points: Vec<Point2>,
    /// `ΔH` of the last call (nats), NaN before.
    last_delta_h: Option<f64>,
}

impl EntropyDetector {
    /// A detector with `params`.
    pub fn new(params: EntropyParams) -> Self {
        Self {
            params,
            ..Self::default()
        }
    }

    /// `ΔH` (nats) of the last call, when it could be computed.
    pub fn last_delta_h(&self) -> Option<f64> {
        self.last_delta_h
    }

    fn prepare(&mut self, other: &[DetectorScan]) {
        self.snapshot = Some(OtherSnapshot::new(other));
        self.other_points.clear();
        for scan in other {
            push_in_range(scan, self.params.max_range_m, &mut self.other_points);
        }
    }
}

/// The points of `scan` within `max_range_m` of its sensor, in the map frame.
fn push_in_range(scan: &DetectorScan, max_range_m: f64, out: &mut Vec<Point2>) {
    let start = out.len();
    extend_points_in_map(scan, out);
    let origin = scan.map_from_robot.translation();
    let mut k = start;
    for i in start..out.len() {
        if let Some(&p) = out.get(i) {
            if (p - origin).norm() <= max_range_m {
                if let Some(slot) = out.get_mut(k) {
                    *slot = p;
                }
                k += 1;
            }
        }
    }
    out.truncate(k);
}

impl InvalidMergeDetector for EntropyDetector {
    fn name(&self) -> &'static str {
        "entropy"
    }

    fn on_merge(&mut self, map: &MergedMap<'_>) {
        self.prepare(map.other);
    }

    fn on_vertex(&mut self, map: &MergedMap<'_>) -> f64 {
        self.last_delta_h = None;
        if self
            .snapshot
            .as_ref()
            .is_none_or(|s| !s.still_valid(map.other, 0.05, 0.01))
        {
            self.prepare(map.other);
        }
        // 1. The area of interest.
        let mut window_points = Vec::new();
        for scan in recent(map.current, self.params.recent_scans) {
            push_in_range(scan, self.params.max_range_m, &mut window_points);
        }
        let (mut lo, mut hi) = window_points.iter().fold(
            (
                Point2::repeat(f64::INFINITY),
                Point2::repeat(f64::NEG_INFINITY),
            ),
            |(l, h), p| (l.inf(p), h.sup(p)),
        );
        if !(lo.x <= hi.x && lo.y <= hi.y) {
            return 0.0;
        }
        lo -= Point2::repeat(self.params.margin_m.max(0.0));
        hi += Point2::repeat(self.params.margin_m.max(0.0));
        let inside = |p: &Point2| p.x >= lo.x && p.y >= lo.y && p.x <= hi.x && p.y <= hi.y;
        // 2. The current epoch's and the other epochs' points there, thinned.
        let mut current = Vec::new();
        for scan in map.current {
            push_in_range(scan, self.params.max_range_m, &mut current);
        }
        current.retain(|p| inside(p));
        let other: Vec<Point2> = self
            .other_points
            .iter()
            .filter(|p| inside(p))
            .copied()
            .collect();
        let voxel = self.params.voxel_m;
        let current = voxel_downsample(&current, voxel);
        let other = voxel_downsample(&other, voxel);
        let mut all = current.clone();
        all.extend_from_slice(&other);
        let all = voxel_downsample(&all, voxel);
        // 3. ΔH = H_all − ½ (H_current + H_other), mapped into [0, 1].
        let (Some(h_all), Some(h_current), Some(h_other)) = (
            mean_entropy(&all, &self.params),
            mean_entropy(&current, &self.params),
            mean_entropy(&other, &self.params),
        ) else {
            return 0.0;
        };
        let delta_h = h_all - 0.5 * (h_current + h_other);
        self.last_delta_h = Some(delta_h);
        logistic(delta_h, 0.0, self.params.logistic_scale)
    }
}

#[cfg(test)]
mod tests {
    use mapmerge_geometry::{LieGroup, Se2};

    use super::*;
    use crate::testworld::{wrong_turned, Case, World};

    #[test]
    fn a_wrong_merge_raises_entropy() {
        let open = World::office(false);
        let run = |case: Case| case.max_ratio(&mut EntropyDetector::default());
        let correct = run(Case::office(&open, &open, &Se2::identity()));
        let turned = run(Case::office(&open, &open, &wrong_turned()));
        assert!(turned > correct, "{turned} vs {correct}");
    }

    #[test]
    fn a_line_has_lower_entropy_than_a_blob() {
        let params = EntropyParams::default();
        let line: Vec<Point2> = (0..100)
            .map(|i| Point2::new(i as f64 * 0.02, 0.0))
            .collect();
        let blob: Vec<Point2> = (0..100)
            .map(|i| Point2::new((i % 10) as f64 * 0.03, (i / 10) as f64 * 0.03))
            .collect();
        assert!(mean_entropy(&line, &params).unwrap() < mean_entropy(&blob, &params).unwrap());
        assert!(mean_entropy(&[], &params).is_none());
        assert!(mean_entropy(&[Point2::new(f64::NAN, 0.0)], &params).is_none());
    }

    #[test]
    fn no_other_data_gives_zero() {
        let open = World::office(false);
        let case = Case::office(&open, &open, &Se2::identity());
        let mut d = EntropyDetector::default();
        let map = MergedMap {
            current: &case.current,
            other: &[],
        };
        d.on_merge(&map);
        assert_eq!(d.on_vertex(&map), 0.0);
        let map = MergedMap {
            current: &[],
            other: &case.other,
        };
        assert_eq!(d.on_vertex(&map), 0.0);
    }
}
