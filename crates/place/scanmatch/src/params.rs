//! Parameters of the correlative matcher, of ICP and of the search window.

use mapmerge_params::{Checker, Real, Validate};
use serde::{Deserialize, Serialize};

use crate::error::ScanMatchError;

/// Where to search: a box of half-widths around the guess.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SearchWindow {
    /// Half-width of the translation window in x and in y (m) (default: 0.3). Cost grows with
    /// its square; branch-and-bound keeps large windows (±10 m) affordable.
    pub linear_m: f64,
    /// Half-width of the heading window (rad) (default: 10° = 0.1745). Values ≥ π search the
    /// whole circle (global localisation, verification without a guess).
    pub angular_rad: f64,
}

impl Default for SearchWindow {
    fn default() -> Self {
        Self {
            linear_m: 0.3,
            angular_rad: 10f64.to_radians(),
        }
    }
}

impl SearchWindow {
    /// A window of `linear_m` (m) and `angular_rad` (rad) half-widths.
    pub fn new(linear_m: f64, angular_rad: f64) -> Self {
        Self {
            linear_m,
            angular_rad,
        }
    }

    /// The window for a search without a usable guess: ±`linear_m` and the whole circle.
    pub fn global(linear_m: f64) -> Self {
        Self {
            linear_m,
            angular_rad: std::f64::consts::PI,
        }
    }

    /// The branch-and-bound depth that covers this window at `resolution_m` with one block:
    /// the smallest `h` with `2^h ≥ 2·⌈linear_m / resolution_m⌉ + 1`. Deeper precomputed
    /// levels are never read by a search of this window, so a target built for it alone can
    /// stop there (the same answer, less to build). `None` for a window that is not finite
    /// and positive.
    pub fn branch_and_bound_depth(&self, resolution_m: f64) -> Option<usize> {
        if !(self.linear_m.is_finite() && self.linear_m >= 0.0 && resolution_m > 0.0) {
            return None;
        }
        let cells = (self.linear_m / resolution_m).ceil();
        if cells > f64::from(1u32 << 20) {
            return None;
        }
        let span = 2 * cells as u64 + 1;
        Some(span.next_power_of_two().trailing_zeros() as usize)
    }
}

/// Parameters of the correlative scan matcher (Olson 2009; Hess et al. 2016).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CorrelativeParams {
    /// Cell size of the correlation grid (m) (default: 0.05). Also the translation step of
    /// the search; finer is more precise and slower (cost ∝ 1/resolution³ for a full search).
    pub resolution_m: f64,
    /// Standard deviation of the Gaussian likelihood kernel around each target point, in
    /// cells (default: 1.5). Wider kernels tolerate noise and discretisation but blur the peak.
    pub kernel_sigma_cells: f64,
    /// Number of precomputed coarse grids (Hess et al. 2016, Sec. V-C) (default: 7, i.e.
    /// blocks up to 64 × 64 cells). More levels prune large windows faster and cost memory.
    pub branch_and_bound_depth: usize,
    /// Matches whose score (mean likelihood of the query points, in [0, 1]) is below this are
    /// rejected (default: 0.4). Higher rejects more false matches and more true ones in
    /// changed or cluttered scenes. It also prunes the search, so higher is faster.
    pub min_score: f64,
    /// Query points are voxel-downsampled with this cell (m) before matching (default: 0.05);
    /// 0 keeps every point. Evens out the weight of near and far surfaces and saves time.
    pub query_voxel_m: f64,
    /// Half-width, in grid cells and in angular steps, of the neighbourhood of the optimum
    /// whose scores give the covariance (Olson 2009, Sec. IV) (default: 2).
    pub covariance_half_width: usize,
    /// Refuse targets whose grid would need more cells than this (default: 16 M, e.g.
    /// 200 × 200 m at 5 cm). Memory is about `2 · (depth + 1) · cells` bytes (≈ 256 MB at the
    /// limit with the default depth).
    pub max_grid_cells: u64,
}

impl Default for CorrelativeParams {
    fn default() -> Self {
        Self {
            resolution_m: 0.05,
            kernel_sigma_cells: 1.5,
            branch_and_bound_depth: 7,
            min_score: 0.4,
            query_voxel_m: 0.05,
            covariance_half_width: 2,
            max_grid_cells: 16 << 20,
        }
    }
}

impl CorrelativeParams {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), ScanMatchError> {
        Ok(Validate::validate(self)?)
    }
}

/// Grids of more cells than this are refused whatever `max_grid_cells` says (4 GB of
/// levels at the default depth).
pub const MAX_GRID_CELLS_LIMIT: u64 = 1 << 28;

impl Validate for CorrelativeParams {
    fn check(&self, check: &mut Checker) {
        check
            .real("resolution_m", self.resolution_m, Real::within(1e-3, 10.0))
            .real(
                "kernel_sigma_cells",
                self.kernel_sigma_cells,
                Real::positive_up_to(100.0),
            )
            .size("branch_and_bound_depth", self.branch_and_bound_depth, 0, 16)
            .real("min_score", self.min_score, Real::fraction())
            .real("query_voxel_m", self.query_voxel_m, Real::within(0.0, 10.0))
            .size("covariance_half_width", self.covariance_half_width, 0, 64)
            .count(
                "max_grid_cells",
                self.max_grid_cells,
                1,
                MAX_GRID_CELLS_LIMIT,
            );
    }
}

impl Validate for SearchWindow {
    fn check(&self, check: &mut Checker) {
        check
            .real("linear_m", self.linear_m, Real::within(0.0, 1000.0))
            .real("angular_rad", self.angular_rad, Real::within(0.0, 4.0));
    }
}

/// Parameters of point-to-line ICP (Censi 2008).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct IcpParams {
    /// Correspondences farther than this (m) are rejected (default: 0.3). Must exceed the
    /// initial error; larger lets wrong pairs in.
    pub max_correspondence_m: f64,
    /// Huber threshold on the point-to-line residual (m) (default: 0.03); residuals beyond it
    /// are down-weighted.
    pub huber_m: f64,
    /// Iteration limit (default: 30).
    pub max_iterations: usize,
    /// Converged when a step moves less than this in translation (m) (default: 1e-4) …
    pub translation_tolerance_m: f64,
    /// … and less than this in heading (rad) (default: 1e-4).
    pub rotation_tolerance_rad: f64,
    /// Radius of the neighbourhood that gives target normals (m) (default: 0.15).
    pub normal_radius_m: f64,
    /// Target points whose neighbourhood is less line-like than this (`planarity`, 0..1) get
    /// no normal (default: 0.5).
    pub min_planarity: f64,
    /// Target points are voxel-downsampled with this cell (m) before normals and
    /// correspondences (default: 0.05); 0 keeps every point. A local map of many scans
    /// repeats each wall many times; the centroids stay on the walls.
    pub target_voxel_m: f64,
}

impl Default for IcpParams {
    fn default() -> Self {
        Self {
            max_correspondence_m: 0.3,
            huber_m: 0.03,
            max_iterations: 30,
            translation_tolerance_m: 1e-4,
            rotation_tolerance_rad: 1e-4,
            normal_radius_m: 0.15,
            min_planarity: 0.5,
            target_voxel_m: 0.05,
        }
    }
}

/// Parameters of [`crate::ScanMatcher`]: correlative search, then optional ICP refinement.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScanMatchParams {
    /// The correlative search (defaults: see [`CorrelativeParams`]).
    pub correlative: CorrelativeParams,
    /// ICP refinement; `None` skips it (default: `Some(IcpParams::default())`).
    pub icp: Option<IcpParams>,
    /// ICP results are kept only when at least this fraction of query points found a
    /// correspondence and ICP moved the pose by less than the correlative step
    /// times [`ScanMatchParams::icp_max_shift_cells`] (default: 0.5).
    pub icp_min_inlier_fraction: f64,
    /// See `icp_min_inlier_fraction` (default: 4 cells).
    pub icp_max_shift_cells: f64,
}

impl Default for ScanMatchParams {
    fn default() -> Self {
        Self {
            correlative: CorrelativeParams::default(),
            icp: Some(IcpParams::default()),
            icp_min_inlier_fraction: 0.5,
            icp_max_shift_cells: 4.0,
        }
    }
}

impl Validate for IcpParams {
    fn check(&self, check: &mut Checker) {
        check
            .real(
                "max_correspondence_m",
                self.max_correspondence_m,
                Real::positive_up_to(100.0),
            )
            .real("huber_m", self.huber_m, Real::positive())
            .size("max_iterations", self.max_iterations, 1, 10_000)
            .real(
                "translation_tolerance_m",
                self.translation_tolerance_m,
                Real::non_negative(),
            )
            .real(
                "rotation_tolerance_rad",
                self.rotation_tolerance_rad,
                Real::non_negative(),
            )
            .real(
                "normal_radius_m",
                self.normal_radius_m,
                Real::positive_up_to(100.0),
            )
            .real("min_planarity", self.min_planarity, Real::fraction())
            .real(
                "target_voxel_m",
                self.target_voxel_m,
                Real::within(0.0, 10.0),
            );
    }
}

impl Validate for ScanMatchParams {
    fn check(&self, check: &mut Checker) {
        check
            .nested("correlative", &self.correlative)
            .nested_opt("icp", self.icp.as_ref())
            .real(
                "icp_min_inlier_fraction",
                self.icp_min_inlier_fraction,
                Real::fraction(),
            )
            .real(
                "icp_max_shift_cells",
                self.icp_max_shift_cells,
                Real::non_negative(),
            );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate_and_sizes_are_limited() {
        assert_eq!(Validate::validate(&ScanMatchParams::default()), Ok(()));
        assert_eq!(Validate::validate(&SearchWindow::default()), Ok(()));
        let mut p = ScanMatchParams::default();
        p.correlative.max_grid_cells = u64::MAX;
        let e = Validate::validate(&p).unwrap_err();
        assert_eq!(e.field, "correlative.max_grid_cells");
        let mut p = ScanMatchParams::default();
        if let Some(icp) = p.icp.as_mut() {
            icp.max_iterations = u32::MAX as usize;
        }
        assert_eq!(
            Validate::validate(&p).unwrap_err().field,
            "icp.max_iterations"
        );
    }

    #[test]
    fn a_window_needs_the_levels_whose_block_covers_it() {
        // ±1 m at 5 cm: 41 cells, one 64-cell block (height 6); at 10 cm 21 cells (32, 5).
        assert_eq!(
            SearchWindow::new(1.0, 0.1).branch_and_bound_depth(0.05),
            Some(6)
        );
        assert_eq!(
            SearchWindow::new(1.0, 0.1).branch_and_bound_depth(0.1),
            Some(5)
        );
        assert_eq!(
            SearchWindow::new(0.0, 0.1).branch_and_bound_depth(0.05),
            Some(0)
        );
        assert_eq!(
            SearchWindow::new(f64::NAN, 0.1).branch_and_bound_depth(0.05),
            None
        );
        assert_eq!(
            SearchWindow::new(1e9, 0.1).branch_and_bound_depth(0.05),
            None
        );
    }
}
