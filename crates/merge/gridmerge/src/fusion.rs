//! Fusing map B into map A: binary Bayes (log-odds) updates in A's frame and resolution,
//! weighted by the quality difference of the two maps' regions (Andersone, Sec. 2.2 and 4.1:
//! "depending on the quality differences of both map regions, the Binary Bayes filter update
//! is applied 0–3 times").

use mapmerge_geometry::Se2;
use mapmerge_grid::{Cell, GridError, GridGeometry, OccupancyGrid, Point2, SensorModel, MAX_CELLS};
use serde::{Deserialize, Serialize};

use crate::quality::{QualityMap, QualityParams};
use crate::warp::{check_transform, footprint_in_a, known_bounds, sample_into, samples_per_axis};
use crate::MergeError;

/// Whether the fusion looks at the maps' quality.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FusionWeighting {
    /// Apply B's evidence 0–3 times per cell by the quality difference of the regions.
    Quality,
    /// Apply B's evidence once everywhere (plain binary Bayes).
    Uniform,
}

/// How B is fused into A.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FusionParams {
    /// Quality-weighted or uniform (default `quality`).
    pub weighting: FusionWeighting,
    /// How region quality is estimated (see [`QualityMap`]).
    pub quality: QualityParams,
    /// Quality differences `q_b − q_a` at which B's update is applied 1, 2 and 3 times;
    /// below the first, 0 times (B ignored where A has data). Ascending; default
    /// `[-0.2, 0.1, 0.3]`: comparable regions get one update, as plain Bayes; a clearly
    /// worse B region cannot spoil a good A region; a much better B region overrules A's
    /// evidence.
    pub repeat_thresholds: [f32; 3],
    /// Updates where either region has no quality estimate (default 1).
    pub repeats_without_estimate: u8,
    /// Cells A never observed take B's evidence at least once whatever the quality
    /// difference (default true): the other map's exploration is the point of merging, and
    /// there is no A data to spoil. False leaves them unknown when B's region is worse.
    pub fill_unknown: bool,
    /// Lower clamp of fused cells (log-odds; default the grid's sensor model's, p = 0.12), so
    /// later scans can still change them.
    pub min_log_odds: f32,
    /// Upper clamp of fused cells (log-odds; default p = 0.97).
    pub max_log_odds: f32,
}

impl Default for FusionParams {
    fn default() -> Self {
        let model = SensorModel::default();
        Self {
            weighting: FusionWeighting::Quality,
            quality: QualityParams::default(),
            repeat_thresholds: [-0.2, 0.1, 0.3],
            repeats_without_estimate: 1,
            fill_unknown: true,
            min_log_odds: model.min_log_odds,
            max_log_odds: model.max_log_odds,
        }
    }
}

impl FusionParams {
    /// Validates the parameters (the fusion's only panics would come from bad clamps).
    pub fn validate(&self) -> Result<(), MergeError> {
        self.quality.validate()?;
        let t = self.repeat_thresholds;
        if !(t.iter().all(|v| v.is_finite()) && t[0] <= t[1] && t[1] <= t[2]) {
            return Err(MergeError::BadParams {
                name: "repeat_thresholds",
                reason: format!("must be finite and ascending, got {t:?}"),
            });
        }
        if self.repeats_without_estimate > 3 {
            return Err(MergeError::BadParams {
                name: "repeats_without_estimate",
                reason: format!("must be 0..=3, got {}", self.repeats_without_estimate),
            });
        }
        if !(self.min_log_odds.is_finite()
            && self.max_log_odds.is_finite()
            && self.min_log_odds <= 0.0
            && self.max_log_odds >= 0.0)
        {
            return Err(MergeError::BadParams {
                name: "min_log_odds/max_log_odds",
                reason: format!(
                    "need finite min ≤ 0 ≤ max, got {} and {}",
                    self.min_log_odds, self.max_log_odds
                ),
            });
        }
        Ok(())
    }

    /// How many times B's evidence is applied to a cell whose A region has quality
    /// `a_quality` and B region `b_quality` (Andersone, Sec. 4.1: 0–3 times).
    pub fn repeats(&self, a_quality: Option<f32>, b_quality: Option<f32>) -> u8 {
        match (self.weighting, a_quality, b_quality) {
            (FusionWeighting::Uniform, _, _) => 1,
            (FusionWeighting::Quality, Some(a), Some(b)) => {
                let difference = b - a;
                self.repeat_thresholds
                    .iter()
                    .filter(|&&t| difference >= t)
                    .count() as u8
            }
            _ => self.repeats_without_estimate,
        }
    }
}

/// What a fusion did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FusionInfo {
    /// Cells where B has evidence, by how many times it was applied (index 0–3).
    pub cells_by_repeats: [usize; 4],
    /// Of those, cells A had never observed.
    pub cells_new: usize,
    /// Cells whose value changed.
    pub cells_changed: usize,
    /// A's overall quality ([`QualityMap::overall`]), when weighting by quality.
    pub a_quality: Option<f64>,
    /// B's overall quality.
    pub b_quality: Option<f64>,
    /// Where A's cells went in the merged grid: `merged cell = A cell + shift`.
    pub a_shift_cells: Cell,
    /// Samples of B per merged cell (`k²`, see [`crate::resample_into`]).
    pub samples_per_cell: usize,
}

impl Default for FusionInfo {
    fn default() -> Self {
        Self {
            cells_by_repeats: [0; 4],
            cells_new: 0,
            cells_changed: 0,
            a_quality: None,
            b_quality: None,
            a_shift_cells: Cell::new(0, 0),
            samples_per_cell: 1,
        }
    }
}

/// The result of [`fuse`].
#[derive(Clone, Debug, PartialEq)]
pub struct Fused {
    /// A with B fused in: A's frame and resolution, grown to hold B's observed cells.
    pub merged: OccupancyGrid,
    /// B alone, resampled onto the merged grid's cells (what was fused; the verification
    /// compares later maps with it).
    pub b_in_a: OccupancyGrid,
    /// What happened.
    pub info: FusionInfo,
}

/// Fuses map `b` into map `a`, given B's map frame in A's map frame (`a_from_b`).
///
/// 1. A is copied, grown on its own cell lattice just enough to hold B's observed cells.
/// 2. B is resampled through `a_from_b` onto the merged cells ([`crate::resample_into`]).
/// 3. Where B has evidence `l_b ≠ 0`, the binary Bayes update `l ← clamp(l + l_b)` is applied
///    `n` times, `n` from [`FusionParams::repeats`] of the quality of A's block (estimated on
///    A as given) and B's block (estimated on B as given, at the cell's centre).
///
/// Cells B does not observe are untouched, so fusing an all-unknown B returns A exactly.
pub fn fuse(
    a: &OccupancyGrid,
    b: &OccupancyGrid,
    a_from_b: &Se2,
    params: &FusionParams,
) -> Result<Fused, MergeError> {
    params.validate()?;
    check_transform(a_from_b)?;
    let mut info = FusionInfo::default();
    let Some((lo, hi)) = known_bounds(b) else {
        let b_in_a = OccupancyGrid::with_geometry(*a.geometry())?;
        return Ok(Fused {
            merged: a.clone(),
            b_in_a,
            info,
        });
    };
    // 1. A on its own lattice, grown to hold B's observed box.
    let (lo_a, hi_a) = footprint_in_a(b.geometry(), lo, hi, a_from_b);
    let (mut merged, shift) = grown_copy(a, &lo_a, &hi_a)?;
    info.a_shift_cells = shift;
    // 2. Quality of both maps as received.
    let (a_quality, b_quality) = match params.weighting {
        FusionWeighting::Quality => (
            Some(QualityMap::estimate(a, &params.quality)?),
            Some(QualityMap::estimate(b, &params.quality)?),
        ),
        FusionWeighting::Uniform => (None, None),
    };
    info.a_quality = a_quality.as_ref().and_then(QualityMap::overall);
    info.b_quality = b_quality.as_ref().and_then(QualityMap::overall);
    let geometry = *merged.geometry();
    info.samples_per_cell = samples_per_axis(geometry.resolution_m, b.resolution_m()).pow(2);
    // 3. B sampled on the merged cells; binary Bayes updates, n times each.
    let mut b_in_a = OccupancyGrid::with_geometry(geometry)?;
    let b_cells = b_in_a.log_odds_mut();
    let cells = merged.log_odds_mut();
    let (min, max) = (params.min_log_odds, params.max_log_odds);
    sample_into(
        &geometry,
        b,
        Some((lo, hi)),
        a_from_b,
        b_quality.as_ref(),
        |sample| {
            if let Some(slot) = b_cells.get_mut(sample.index) {
                *slot = sample.value;
            }
            let Some(cell) = cells.get_mut(sample.index) else {
                return;
            };
            let quality_a = a_quality.as_ref().and_then(|q| {
                let s = q.raw_at(
                    (sample.x as i64).saturating_sub(shift.x),
                    (sample.y as i64).saturating_sub(shift.y),
                );
                (s >= 0.0).then_some(s)
            });
            let quality_b = (sample.quality >= 0.0).then_some(sample.quality);
            let mut n = params.repeats(quality_a, quality_b);
            if *cell == 0.0 {
                info.cells_new += 1;
                if params.fill_unknown {
                    n = n.max(1);
                }
            }
            if let Some(count) = info.cells_by_repeats.get_mut(usize::from(n)) {
                *count += 1;
            }
            let before = *cell;
            for _ in 0..n {
                *cell = (*cell + sample.value).clamp(min, max);
            }
            if *cell != before {
                info.cells_changed += 1;
            }
        },
    );
    Ok(Fused {
        merged,
        b_in_a,
        info,
    })
}

/// A copy of `a` grown on its own cell lattice to hold the box `[lo_m, hi_m]` (A's frame),
/// and the shift of A's cells (`copy cell = A cell + shift`). A box edge exactly on a cell
/// boundary does not reach the next cell (no sample of it could fall inside the box).
fn grown_copy(
    a: &OccupancyGrid,
    lo_m: &Point2,
    hi_m: &Point2,
) -> Result<(OccupancyGrid, Cell), MergeError> {
    let g = *a.geometry();
    // Cell coordinates beyond ±1e15 would saturate to i64; no such grid fits in memory.
    let in_range = |p: &Point2| {
        ((p - g.origin_m) / g.resolution_m)
            .iter()
            .all(|c| c.is_finite() && c.abs() < 1e15)
    };
    if !(in_range(lo_m) && in_range(hi_m)) {
        return Err(GridError::TooLarge.into());
    }
    let edge = Point2::repeat(1e-6 * g.resolution_m);
    let (lo, hi) = (g.cell_of(lo_m), g.cell_of(&(hi_m - edge).sup(lo_m)));
    let (w, h) = (g.width as i64, g.height as i64);
    let (new_lo, new_hi) = if g.is_empty() {
        (lo, hi)
    } else {
        (
            Cell::new(lo.x.min(0), lo.y.min(0)),
            Cell::new(hi.x.max(w - 1), hi.y.max(h - 1)),
        )
    };
    if new_lo == Cell::new(0, 0) && new_hi == Cell::new(w - 1, h - 1) {
        return Ok((a.clone(), Cell::new(0, 0)));
    }
    let size = |lo: i64, hi: i64| {
        hi.checked_sub(lo)
            .and_then(|d| d.checked_add(1))
            .and_then(|d| usize::try_from(d).ok())
    };
    let (Some(width), Some(height)) = (size(new_lo.x, new_hi.x), size(new_lo.y, new_hi.y)) else {
        return Err(GridError::TooLarge.into());
    };
    if (width as u128) * (height as u128) > MAX_CELLS as u128 {
        return Err(GridError::TooLarge.into());
    }
    // Same origin formula as the grid's own growth, so cells stay on A's lattice.
    let geometry = GridGeometry {
        resolution_m: g.resolution_m,
        origin_m: g.origin_m + Point2::new(new_lo.x as f64, new_lo.y as f64) * g.resolution_m,
        width,
        height,
    };
    let mut out = OccupancyGrid::with_geometry(geometry)?;
    let (Some(shift_x), Some(shift_y)) = (new_lo.x.checked_neg(), new_lo.y.checked_neg()) else {
        return Err(GridError::TooLarge.into());
    };
    let shift = Cell::new(shift_x, shift_y);
    if g.width > 0 {
        let cells = out.log_odds_mut();
        for (y, row) in a.log_odds().chunks_exact(g.width).enumerate() {
            let start = (y as i64 + shift.y) as usize * width + shift.x as usize;
            if let Some(dst) = cells.get_mut(start..start + g.width) {
                dst.copy_from_slice(row);
            }
        }
    }
    Ok((out, shift))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn filled(resolution_m: f64, width: usize, height: usize, value: f32) -> OccupancyGrid {
        let geometry = GridGeometry {
            resolution_m,
            origin_m: Point2::zeros(),
            width,
            height,
        };
        OccupancyGrid::from_log_odds(geometry, vec![value; width * height]).unwrap()
    }

    #[test]
    fn repeats_follow_the_quality_difference() {
        let p = FusionParams::default();
        assert_eq!(p.repeats(Some(0.9), Some(0.5)), 0);
        assert_eq!(p.repeats(Some(0.7), Some(0.6)), 1);
        assert_eq!(p.repeats(Some(0.6), Some(0.6)), 1);
        assert_eq!(p.repeats(Some(0.5), Some(0.65)), 2);
        assert_eq!(p.repeats(Some(0.2), Some(0.9)), 3);
        assert_eq!(p.repeats(None, Some(0.9)), 1);
        assert_eq!(p.repeats(Some(0.9), None), 1);
        let uniform = FusionParams {
            weighting: FusionWeighting::Uniform,
            ..p
        };
        assert_eq!(uniform.repeats(Some(0.9), Some(0.0)), 1);
    }

    #[test]
    fn equal_quality_is_plain_bayes_and_unknown_cells_take_b() {
        // A: left half free (-0.6), right half unknown; B: all -0.6, same lattice.
        let mut a = filled(0.1, 40, 40, 0.0);
        for y in 0..40 {
            for x in 0..20 {
                a.set(Cell::new(x, y), -0.6).unwrap();
            }
        }
        let b = filled(0.1, 40, 40, -0.6);
        let fused = fuse(&a, &b, &Se2::new(0.0, 0.0, 0.0), &FusionParams::default()).unwrap();
        assert_eq!(
            fused.merged.geometry(),
            a.geometry(),
            "B inside A: no growth"
        );
        assert_eq!(fused.merged.cell_log_odds(Cell::new(5, 5)), -0.6 + -0.6);
        assert_eq!(fused.merged.cell_log_odds(Cell::new(30, 5)), -0.6);
        assert_eq!(fused.info.cells_new, 800);
        assert_eq!(fused.info.cells_changed, 1600);
        assert_eq!(fused.b_in_a, b);
    }

    #[test]
    fn a_much_better_region_is_not_spoiled_and_a_worse_one_is_overruled() {
        // A: block 0 (x < 20) certain free space; block 1 (x ≥ 20) barely observed free
        // space. B: certain occupied everywhere (a solid blob: no free neighbours, low
        // thinness, a poor map).
        let mut a = filled(0.1, 40, 20, -2.0);
        for y in 0..20 {
            for x in 20..40 {
                a.set(Cell::new(x, y), -0.2).unwrap();
            }
        }
        let b = filled(0.1, 40, 20, 2.0);
        let fused = fuse(&a, &b, &Se2::new(0.0, 0.0, 0.0), &FusionParams::default()).unwrap();
        // Quality: A block 0 = 1.0, block 1 = 0.1; B's blocks = 0.5 · (58 / 400 + 1) ≈ 0.57
        // (only the grid's rim is thin): far below A's block 0, far above A's block 1.
        assert_eq!(
            fused.merged.cell_log_odds(Cell::new(5, 5)),
            -2.0,
            "0 updates"
        );
        assert_eq!(
            fused.merged.cell_log_odds(Cell::new(30, 5)),
            SensorModel::default().max_log_odds,
            "3 updates, clamped"
        );
        assert_eq!(fused.info.cells_by_repeats, [400, 0, 0, 400]);
    }

    #[test]
    fn bad_inputs_are_errors() {
        let a = filled(0.1, 4, 4, -1.0);
        let nan = Se2 {
            x_m: f64::NAN,
            y_m: 0.0,
            theta_rad: 0.0,
        };
        assert!(matches!(
            fuse(&a, &a, &nan, &FusionParams::default()),
            Err(MergeError::NotFiniteTransform { .. })
        ));
        let bad = FusionParams {
            min_log_odds: 1.0,
            ..FusionParams::default()
        };
        assert!(matches!(
            fuse(&a, &a, &Se2::new(0.0, 0.0, 0.0), &bad),
            Err(MergeError::BadParams { .. })
        ));
        let far = Se2::new(1e15, 0.0, 0.0);
        assert!(fuse(&a, &a, &far, &FusionParams::default()).is_err());
        // An empty A and a B far away: an error, not a panic or a misplaced grid.
        let empty = OccupancyGrid::new(0.1).unwrap();
        for x_m in [1e300, -1e300, 1e17] {
            let far = Se2::new(x_m, 0.0, 0.0);
            assert!(matches!(
                fuse(&empty, &a, &far, &FusionParams::default()),
                Err(MergeError::Grid(GridError::TooLarge))
            ));
        }
        // An empty A and a near B: B's cells, on A's lattice.
        let fused = fuse(
            &empty,
            &a,
            &Se2::new(10.0, 0.0, 0.0),
            &FusionParams::default(),
        )
        .unwrap();
        assert_eq!(fused.merged.geometry().width, 4);
        assert_eq!(fused.merged.log_odds_at(&Point2::new(10.05, 0.05)), -1.0);
    }
}
