//! Parameters of grid matching and of the acceptance rule.

use std::f64::consts::PI;

use mapmerge_grid::ClassThresholds;
use mapmerge_params::{Checker, Real, Validate};
use serde::{Deserialize, Serialize};

use crate::error::GridMatchError;

/// When the best hypothesis is accepted (Birk & Carpin 2006's acceptance index plus a margin
/// over the runner-up, Carpin 2008, Sec. 5).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AcceptanceParams {
    /// Smallest acceptance index ω = agree / (agree + disagree) (default: 0.9). Higher
    /// rejects more wrong matches and more correct ones between maps of different quality.
    pub min_acceptance: f64,
    /// Smallest overlap, as a fraction of the known cells of the smaller map (default: 0.1).
    /// A tiny overlap agrees by chance.
    pub min_overlap_fraction: f64,
    /// Smallest relative lead of the best hypothesis's score over the best distinct runner-up,
    /// `(best − runner_up) / best` (default: 0.15). This is what refuses look-alike places
    /// (a corridor shifted by one door, a symmetric room turned by 180°), whose ω is as high
    /// as the right one's.
    pub min_margin: f64,
    /// Largest DM (cells) of the best hypothesis (default: 4). Right placements of maps of
    /// one place measure 0.2–1.5 cells on the building maps (Andersone, Table 4: up to 2.4
    /// between maps of different sessions); look-alikes whose ω passes measure 6 and more,
    /// because DM sees how far each wall is from the other map's (Andersone, Sec. 3.3).
    pub max_dm_cells: f64,
}

impl Default for AcceptanceParams {
    fn default() -> Self {
        Self {
            min_acceptance: 0.9,
            min_overlap_fraction: 0.1,
            min_margin: 0.15,
            max_dm_cells: 4.0,
        }
    }
}

/// Parameters of [`crate::match_grids`]. Defaults work on building maps of 0.02–0.2 m cells.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GridMatchParams {
    /// Log-odds → free / occupied / unknown (default: 0.65 / 0.35, see `ClassThresholds`).
    pub thresholds: ClassThresholds,
    /// Angle bins of the Hough spectrum over [0, π) (default: 360, i.e. 0.5°). More bins give
    /// finer rotation hypotheses and cost linearly.
    pub hough_angle_bins: usize,
    /// ρ bin of the Hough transform, in cells of the common resolution (default: 2); occupied
    /// cells are pooled to this size first. Larger is faster and blurs the spectrum.
    pub hough_rho_cells: usize,
    /// Peaks of the spectra's cross-correlation kept (default: 4); each gives θ and θ + π, so
    /// 4 peaks keep the 90° and 180° ambiguities of rectilinear buildings.
    pub rotation_peaks: usize,
    /// Peaks of the cross-correlated local-orientation histograms kept (default: 2), each as
    /// θ and θ + π, besides the Hough spectrum's; 0 turns this source off. A wall's
    /// direction is the principal axis of the occupied cells around it; unlike the Hough
    /// spectrum, which long walls dominate, every wall segment votes, so two partial crops of
    /// one building still agree (2 peaks: the 90° turns of rectilinear buildings).
    pub orientation_peaks: usize,
    /// Radius (cells of the common resolution) of the neighbourhood whose principal axis
    /// gives a wall's direction (default: 6). Larger is smoother and blurs corners.
    pub orientation_radius_cells: usize,
    /// A local-orientation peak within this angle (rad) of a Hough peak, modulo π, is the
    /// same hypothesis (default: 1° = 0.0175); keep it below `refine_angle_rad`.
    pub rotation_merge_rad: f64,
    /// Translations kept per rotation hypothesis (default: 2).
    pub translation_peaks: usize,
    /// The coarse correlation raster has at most this many cells along its longest side
    /// (default: 200); the pooling factor follows. Smaller is faster and needs a larger
    /// refinement window.
    pub coarse_max_cells: usize,
    /// Weight of an occupied cell against a free one in the coarse correlation (default: 3):
    /// occupied-occupied counts `w²`, free-free 1, occupied-free `−w`. Walls are few; without
    /// the weight free space decides alone.
    pub occupied_weight: f64,
    /// Ranking score of a cell occupied in both maps, in units of a cell free in both
    /// (default: 10). About the log-likelihood ratio of a wall seen in both under a right
    /// and a random placement (walls cover ~10 % of a building map).
    pub rank_occupied_weight: f64,
    /// Ranking penalty of a cell occupied in one map and free in the other (default: 10).
    /// About `log(0.2 / 0.02) / log(0.98 / 0.8)`: a right placement disagrees on ~2 % of its
    /// cells, a look-alike on ~5–20 %, so a disagreement costs as much as ten agreements; a
    /// smaller weight lets a larger, wrong overlap outrank a smaller right one.
    pub rank_disagree_weight: f64,
    /// Coarse candidates refined at full resolution (default: 10): first the best of each
    /// rotation hypothesis, then the next best overall.
    pub refine_candidates: usize,
    /// Half-width of the refinement's heading window (rad) (default: 1.2° = 0.0209); must
    /// cover half a Hough bin plus the spectrum's error.
    pub refine_angle_rad: f64,
    /// The refinement's translation window is the coarse cell plus this many fine cells on
    /// each side (default: 2).
    pub refine_margin_cells: f64,
    /// At most this many of B's occupied cells (evenly strided) enter the refinement search
    /// (default: 4000). Fewer is faster and less precise.
    pub refine_max_points: usize,
    /// Candidates after the first are searched only for poses scoring at least this fraction
    /// of the first one's refinement score (default: 0.5); the others keep their coarse pose.
    /// Higher prunes hopeless rotations sooner.
    pub refine_min_score_ratio: f64,
    /// The best this many hypotheses get a point-to-line ICP step (default: 1), kept when it
    /// raises their score. Each costs an ICP run and a metric evaluation.
    pub polish_candidates: usize,
    /// Standard deviation of the refinement's likelihood kernel, in cells (default: 1.0).
    pub refine_kernel_sigma_cells: f64,
    /// Two hypotheses closer than this many cells at B's centroid … (default: 3)
    pub distinct_cells: f64,
    /// … and this heading difference (rad) are one hypothesis (default: 1.5° = 0.0262).
    pub distinct_rad: f64,
    /// Largest map accepted, in cells after resampling (default: 25 M; at most 2²⁸).
    pub max_cells: usize,
    /// The acceptance rule.
    pub acceptance: AcceptanceParams,
}

impl Default for GridMatchParams {
    fn default() -> Self {
        Self {
            thresholds: ClassThresholds::default(),
            hough_angle_bins: 360,
            hough_rho_cells: 2,
            rotation_peaks: 4,
            orientation_peaks: 2,
            orientation_radius_cells: 6,
            rotation_merge_rad: 1f64.to_radians(),
            translation_peaks: 2,
            coarse_max_cells: 200,
            occupied_weight: 3.0,
            rank_occupied_weight: 10.0,
            rank_disagree_weight: 10.0,
            refine_candidates: 10,
            refine_angle_rad: 1.2f64.to_radians(),
            refine_margin_cells: 2.0,
            refine_max_points: 4000,
            refine_min_score_ratio: 0.5,
            polish_candidates: 1,
            refine_kernel_sigma_cells: 1.0,
            distinct_cells: 3.0,
            distinct_rad: 1.5f64.to_radians(),
            max_cells: 25_000_000,
            acceptance: AcceptanceParams::default(),
        }
    }
}

impl Validate for AcceptanceParams {
    fn check(&self, check: &mut Checker) {
        check
            .real("min_acceptance", self.min_acceptance, Real::fraction())
            .real(
                "min_overlap_fraction",
                self.min_overlap_fraction,
                Real::fraction(),
            )
            .real("min_margin", self.min_margin, Real::fraction())
            .real("max_dm_cells", self.max_dm_cells, Real::non_negative());
    }
}

/// Largest `max_cells`: 2²⁸ cells after resampling (1 GiB a raster of `f32`).
const MAX_CELLS_LIMIT: u64 = 1 << 28;

impl Validate for GridMatchParams {
    fn check(&self, check: &mut Checker) {
        check
            .nested("thresholds", &self.thresholds)
            .size("hough_angle_bins", self.hough_angle_bins, 4, 10_000)
            .size("hough_rho_cells", self.hough_rho_cells, 1, 256)
            .size("rotation_peaks", self.rotation_peaks, 1, 1_000)
            .size("orientation_peaks", self.orientation_peaks, 0, 1_000)
            .size(
                "orientation_radius_cells",
                self.orientation_radius_cells,
                1,
                64,
            )
            .real(
                "rotation_merge_rad",
                self.rotation_merge_rad,
                Real::within(0.0, PI),
            )
            .size("translation_peaks", self.translation_peaks, 1, 1_000)
            .size("coarse_max_cells", self.coarse_max_cells, 8, 4_096)
            .real("occupied_weight", self.occupied_weight, Real::positive())
            .real(
                "rank_occupied_weight",
                self.rank_occupied_weight,
                Real::positive(),
            )
            .real(
                "rank_disagree_weight",
                self.rank_disagree_weight,
                Real::positive(),
            )
            .size("refine_candidates", self.refine_candidates, 1, 1_000)
            .real(
                "refine_angle_rad",
                self.refine_angle_rad,
                Real::positive_up_to(0.5),
            )
            .rule(
                "rotation_merge_rad",
                self.rotation_merge_rad,
                self.rotation_merge_rad < self.refine_angle_rad,
                "must be below refine_angle_rad",
            )
            .real(
                "refine_margin_cells",
                self.refine_margin_cells,
                Real::within(0.0, 64.0),
            )
            .size("refine_max_points", self.refine_max_points, 1, 1_000_000)
            .real(
                "refine_min_score_ratio",
                self.refine_min_score_ratio,
                Real::fraction(),
            )
            .size("polish_candidates", self.polish_candidates, 0, 100)
            .real(
                "refine_kernel_sigma_cells",
                self.refine_kernel_sigma_cells,
                Real::positive(),
            )
            .real("distinct_cells", self.distinct_cells, Real::non_negative())
            .real("distinct_rad", self.distinct_rad, Real::within(0.0, PI))
            .size("max_cells", self.max_cells, 1, MAX_CELLS_LIMIT)
            .nested("acceptance", &self.acceptance);
    }
}

impl GridMatchParams {
    /// Checks every field's domain ([`Validate`]).
    pub fn validate(&self) -> Result<(), GridMatchError> {
        Ok(Validate::validate(self)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn field(params: &GridMatchParams) -> Result<(), String> {
        Validate::validate(params).map_err(|e| e.field)
    }

    #[test]
    fn the_defaults_pass_and_values_out_of_range_name_their_field() {
        assert_eq!(field(&GridMatchParams::default()), Ok(()));
        assert_eq!(AcceptanceParams::default().validate(), Ok(()));
        let cases: [(GridMatchParams, &str); 7] = [
            (
                GridMatchParams {
                    max_cells: usize::MAX,
                    ..Default::default()
                },
                "max_cells",
            ),
            (
                GridMatchParams {
                    hough_angle_bins: 0,
                    ..Default::default()
                },
                "hough_angle_bins",
            ),
            (
                GridMatchParams {
                    refine_candidates: 1 << 40,
                    ..Default::default()
                },
                "refine_candidates",
            ),
            (
                GridMatchParams {
                    distinct_rad: -0.1,
                    ..Default::default()
                },
                "distinct_rad",
            ),
            (
                GridMatchParams {
                    rotation_merge_rad: 0.1,
                    ..Default::default()
                },
                "rotation_merge_rad",
            ),
            (
                GridMatchParams {
                    thresholds: ClassThresholds {
                        occupied_min: 0.3,
                        free_max: 0.35,
                    },
                    ..Default::default()
                },
                "thresholds.free_max",
            ),
            (
                GridMatchParams {
                    acceptance: AcceptanceParams {
                        min_acceptance: f64::NAN,
                        ..Default::default()
                    },
                    ..Default::default()
                },
                "acceptance.min_acceptance",
            ),
        ];
        for (params, expected) in cases {
            assert_eq!(field(&params), Err(expected.to_owned()));
            assert!(matches!(
                params.validate(),
                Err(GridMatchError::Params(ref e)) if e.field == expected
            ));
        }
    }
}
