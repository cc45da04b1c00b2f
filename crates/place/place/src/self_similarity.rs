//! How well a keyframe's local map fits *itself* somewhere else: a place whose own map is
//! periodic (rack rows every aisle) or symmetric (a hall that a half turn maps onto itself)
//! is observable from several distinct places, which is what Banerjee et al. call an
//! ambiguous view (Sec. 5.3). Their tracker finds such views from rejected observations while
//! the robot is localised; a view's own map shows it before any merge is made on it.
//!
//! The search: the local map is the match target, and the same points are searched for the
//! best placement away from the identity (a ring of translation windows at small headings,
//! and windows at every other heading), each pruned below a floor relative to the identity's
//! fit; the placements found are scored on the whole-map scale ([`crate::evidence`]), as a
//! match between two places would be.

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_params::{Checker, Real, Validate};
use mapmerge_scan::transform_points;
use mapmerge_scanmatch::{
    match_scan_above, ScanMatchError, ScanMatchParams, ScanMatcher, SearchWindow,
};
use serde::{Deserialize, Serialize};

use crate::evidence::{evidence, Evidence, EvidenceParams};
use crate::Keyframe;

/// Parameters of [`SelfSimilarity`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SelfSimilarityParams {
    /// Other placements are searched within this translation of the identity (m) (default:
    /// 12, beyond a warehouse's aisle pitch and most of a hall).
    pub radius_m: f64,
    /// A placement counts as another place from this translation (m) (default: 1.5) …
    pub min_shift_m: f64,
    /// … or this turn (rad) (default: 30°).
    pub min_turn_rad: f64,
    /// Only placements whose correlative fit reaches this fraction of the identity's are
    /// weighed (default: 0.4); the search prunes everything below. The fit is a mean over
    /// all points, and a placement one aisle over leaves part of the map without a partner:
    /// in the simulator's warehouse such placements fit at 0.46–0.48 of the identity's 0.97.
    pub floor_ratio: f64,
    /// The search's grid cell (m) (default: 0.1; 0.2 took two thirds of the time and merged
    /// 20 instead of 23 of the simulator's 32 tuning epochs).
    pub resolution_m: f64,
    /// The search query is thinned to one point per cell of this size (m) (default: 0.4).
    pub query_voxel_m: f64,
}

impl Default for SelfSimilarityParams {
    fn default() -> Self {
        Self {
            radius_m: 12.0,
            min_shift_m: 1.5,
            min_turn_rad: 30f64.to_radians(),
            floor_ratio: 0.4,
            resolution_m: 0.1,
            query_voxel_m: 0.4,
        }
    }
}

impl Validate for SelfSimilarityParams {
    fn check(&self, check: &mut Checker) {
        check
            .real("min_shift_m", self.min_shift_m, Real::positive())
            .real(
                "radius_m",
                self.radius_m,
                Real::open(self.min_shift_m, 1000.0),
            )
            .real(
                "min_turn_rad",
                self.min_turn_rad,
                Real::open(0.0, std::f64::consts::PI),
            )
            .real("floor_ratio", self.floor_ratio, Real::fraction())
            .real("resolution_m", self.resolution_m, Real::within(0.01, 10.0))
            .real("query_voxel_m", self.query_voxel_m, Real::within(0.0, 10.0));
    }
}

/// The best placement of a keyframe's local map on itself away from the identity.
pub struct SelfSimilarity {
    matcher: ScanMatcher,
    params: SelfSimilarityParams,
    evidence: EvidenceParams,
}

impl SelfSimilarity {
    /// A search with `params`, scoring placements with `evidence` (the merge search's, so a
    /// self-placement is weighed as a match would be); fails on invalid parameters.
    pub fn new(
        params: SelfSimilarityParams,
        evidence: EvidenceParams,
    ) -> Result<Self, ScanMatchError> {
        params.validate()?;
        let mut matcher = ScanMatchParams::default();
        matcher.correlative.resolution_m = params.resolution_m;
        matcher.correlative.query_voxel_m = params.query_voxel_m;
        matcher.icp = None;
        let window = SearchWindow::new(params.radius_m, std::f64::consts::PI);
        if let Some(depth) = window.branch_and_bound_depth(params.resolution_m) {
            matcher.correlative.branch_and_bound_depth = depth.min(16);
        }
        Ok(Self {
            matcher: ScanMatcher::new(matcher)?,
            params,
            evidence,
        })
    }

    /// Its parameters.
    pub fn params(&self) -> &SelfSimilarityParams {
        &self.params
    }

    /// The search windows `(guess, window)` that together cover every placement within
    /// `radius_m` that is `min_shift_m` or `min_turn_rad` away from the identity, and none
    /// that is closer on both.
    fn windows(&self) -> Vec<(Se2, SearchWindow)> {
        let p = &self.params;
        let mut windows = Vec::new();
        // Small headings: the strips x ∈ ±[min_shift, radius] (all y), then y ∈
        // ±[min_shift, radius] (|x| ≤ half ≥ min_shift); none reaches the central square.
        let (centre, half) = (
            0.5 * (p.radius_m + p.min_shift_m),
            0.5 * (p.radius_m - p.min_shift_m),
        );
        let across = (p.radius_m / half).ceil().max(1.0) as usize;
        let step = if across > 1 {
            2.0 * (p.radius_m - half) / (across - 1) as f64
        } else {
            0.0
        };
        for side in [1.0, -1.0] {
            for k in 0..across {
                let along = -p.radius_m + half + step * k as f64;
                windows.push((
                    Se2::new(side * centre, along, 0.0),
                    SearchWindow::new(half, p.min_turn_rad),
                ));
            }
            windows.push((
                Se2::new(0.0, side * centre, 0.0),
                SearchWindow::new(half, p.min_turn_rad),
            ));
        }
        // Every other heading: slices of at most ±min_turn around headings from min_turn on.
        let span = std::f64::consts::TAU - 2.0 * p.min_turn_rad;
        let slices = (span / (2.0 * p.min_turn_rad)).ceil().max(1.0);
        let half_slice = 0.5 * span / slices;
        for k in 0..slices as usize {
            let heading = p.min_turn_rad + half_slice * (2 * k + 1) as f64;
            windows.push((
                Se2::new(0.0, 0.0, heading),
                SearchWindow::new(p.radius_m, half_slice),
            ));
        }
        windows
    }

    /// True when `placement` is another place: `min_shift_m` or `min_turn_rad` from the
    /// identity.
    fn is_other_place(&self, placement: &Se2) -> bool {
        placement.translation().norm() >= self.params.min_shift_m
            || mapmerge_geometry::wrap_angle_rad(placement.theta_rad).abs()
                >= self.params.min_turn_rad
    }

    /// The best placement of `keyframe` on itself that is another place, with its evidence
    /// (scored without a flip penalty); `None` when no placement reaches the floor or the
    /// keyframe has no points.
    pub fn best_other_placement(&self, keyframe: &Keyframe) -> Option<(Se2, Evidence)> {
        self.best_rival_placement(keyframe, keyframe, &Se2::identity())
    }

    /// The best placement of `query` in `target` that is another place than
    /// `target_from_query` (`min_shift_m` or `min_turn_rad` away from it, within
    /// `radius_m`), with its evidence: whether a match could as well have been made
    /// elsewhere in the target's surroundings (a look-alike aisle beside the matched one, a
    /// hall turned half round). The search is [`SelfSimilarity::best_other_placement`]'s
    /// around the match; `None` when no placement reaches the floor (a fraction of the
    /// match's own fit) or either keyframe has no points.
    pub fn best_rival_placement(
        &self,
        target: &Keyframe,
        query: &Keyframe,
        target_from_query: &Se2,
    ) -> Option<(Se2, Evidence)> {
        let target_grid = self.matcher.target(&target.points_in_keyframe).ok()?;
        // The query in the target's frame at the match: rivals are displacements of it.
        let points = transform_points(target_from_query, &query.points_in_keyframe);
        let identity = match_scan_above(
            target_grid.correlative(),
            &points,
            &Se2::identity(),
            &SearchWindow::new(2.0 * self.params.resolution_m, 1f64.to_radians()),
            0.0,
        )?;
        let floor = (self.params.floor_ratio * identity.score)
            .max(self.matcher.params().correlative.min_score);
        let mut best: Option<(Se2, Evidence)> = None;
        for (guess, window) in self.windows() {
            let Some(found) =
                match_scan_above(target_grid.correlative(), &points, &guess, &window, floor)
            else {
                continue;
            };
            if !self.is_other_place(&found.target_from_query) {
                continue;
            }
            let placement = found.target_from_query.compose(target_from_query);
            let proof = evidence(query, target, &placement, 0.0, &self.evidence);
            if best.as_ref().is_none_or(|(_, b)| proof.score > b.score) {
                best = Some((placement, proof));
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use mapmerge_geometry::LieGroup;
    use mapmerge_scan::Point2;

    /// Points every 3 cm along the segment from `a` to `b`.
    fn wall(a: Point2, b: Point2) -> Vec<Point2> {
        let n = ((b - a).norm() / 0.03).ceil() as usize;
        (0..=n)
            .map(|j| a + (b - a) * (j as f64 / n as f64))
            .collect()
    }

    /// A keyframe seen from the origin: the points, and free space along rays to them.
    fn keyframe(points: Vec<Point2>) -> Keyframe {
        let rays: Vec<(Point2, Point2)> = points.iter().map(|p| (Point2::zeros(), *p)).collect();
        Keyframe::new(0, points).with_rays(0.1, rays)
    }

    /// Rows of racks 1 m deep every 5 m along y (the first at `y0`, while ≤ `y1`), 18 m long,
    /// with uprights every 2.7 m standing out of both faces.
    fn rack_rows(y0: f64, y1: f64) -> Vec<Point2> {
        let mut rows = Vec::new();
        let mut y = y0;
        while y <= y1 {
            rows.extend(wall(Point2::new(-9.0, y), Point2::new(9.0, y)));
            rows.extend(wall(Point2::new(-9.0, y + 1.0), Point2::new(9.0, y + 1.0)));
            for j in -3..=3 {
                let x = 2.7 * j as f64;
                rows.extend(wall(Point2::new(x, y - 0.2), Point2::new(x, y)));
                rows.extend(wall(Point2::new(x, y + 1.0), Point2::new(x, y + 1.2)));
            }
            y += 5.0;
        }
        rows
    }

    /// An L-shaped room with a niche, seen from the origin.
    fn l_room() -> Keyframe {
        let corners = [
            Point2::new(-3.0, -2.5),
            Point2::new(5.0, -2.5),
            Point2::new(5.0, 0.5),
            Point2::new(1.0, 0.5),
            Point2::new(1.0, 4.0),
            Point2::new(-1.0, 4.0),
            Point2::new(-1.0, 3.0),
            Point2::new(-3.0, 3.0),
        ];
        let mut room = Vec::new();
        for (i, a) in corners.iter().enumerate() {
            room.extend(wall(*a, corners[(i + 1) % corners.len()]));
        }
        keyframe(room)
    }

    /// Rows of racks every 5 m along y with uprights every 2.7 m, seen from an aisle: the map fits itself one row
    /// over. An irregular room does not fit itself anywhere else.
    #[test]
    fn periodic_rows_fit_themselves_one_row_over_and_a_room_does_not() {
        let rows = rack_rows(-7.5, 12.5);
        let search =
            SelfSimilarity::new(SelfSimilarityParams::default(), EvidenceParams::default())
                .unwrap();
        let (placement, proof) = search.best_other_placement(&keyframe(rows)).unwrap();
        assert!(proof.score > 0.95, "{proof:?}");
        assert!(placement.translation().norm() > 1.5, "{placement:?}");

        // Its best other placement (half turned, where the long walls cross) agrees over part
        // of a small overlap only: below the 0.9 from which the engine calls a view ambiguous.
        let other = search.best_other_placement(&l_room());
        assert!(
            other.as_ref().is_none_or(|(_, proof)| proof.score < 0.85),
            "{other:?}"
        );
        // No window reaches the identity's neighbourhood (heading and translation both
        // within the limits).
        let p = search.params;
        for (guess, window) in search.windows() {
            let turned =
                mapmerge_geometry::wrap_angle_rad(guess.theta_rad).abs() - window.angular_rad;
            let shifted =
                (guess.x_m.abs() - window.linear_m).max(guess.y_m.abs() - window.linear_m);
            assert!(
                turned >= p.min_turn_rad - 1e-9 || shifted >= p.min_shift_m - 1e-9,
                "{guess:?} {window:?}"
            );
        }
        assert!(!search.is_other_place(&Se2::identity()));
    }

    /// A query matched in rack rows fits one row over as well (a rival), and the identity
    /// itself is never reported; matched in a room that fits only one way, it has none.
    #[test]
    fn a_match_in_periodic_rows_has_a_rival_one_row_over() {
        let search =
            SelfSimilarity::new(SelfSimilarityParams::default(), EvidenceParams::default())
                .unwrap();
        // The target: five rows; the query: two of them, seen from 1 m beside the match.
        let target = keyframe(rack_rows(-7.5, 12.5));
        let target_from_query = Se2::new(0.5, 1.0, 0.1);
        let query_points: Vec<Point2> = rack_rows(-2.5, 2.5)
            .iter()
            .map(|p| target_from_query.inverse().transform_point(p))
            .collect();
        let query = keyframe(query_points);
        let (rival, proof) = search
            .best_rival_placement(&target, &query, &target_from_query)
            .unwrap();
        assert!(proof.score > 0.9, "{proof:?}");
        let shift = rival.translation() - target_from_query.translation();
        assert!(shift.norm() > 1.5, "{rival:?}");

        // An L-shaped room: the query is the room itself, matched at the identity.
        let room = l_room();
        let other = search.best_rival_placement(&room, &room, &Se2::identity());
        assert!(
            other.as_ref().is_none_or(|(_, proof)| proof.score < 0.85),
            "{other:?}"
        );
    }
}
