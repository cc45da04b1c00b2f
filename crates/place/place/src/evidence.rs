//! How much an alignment of two keyframes proves that they show the same place.
//!
//! A scan matcher's score says how well the query's points fit the candidate's; in corridors,
//! at corners and in look-alike rooms a wrong place fits as well. Without a pose prior a loop
//! must be refused unless the fit is also
//! - *complete*: most query points have a candidate point nearby (`inlier_fraction`),
//! - *free-space consistent*: few candidate points lie where the query saw through, i.e. in
//!   front of its returns (`violation_fraction`; the negative evidence the likelihood score
//!   ignores),
//! - *constrained*: the matched line-like structure pins the translation in every direction
//!   (`constraint_m`, the smallest eigenvalue of `Σ n nᵀ` over matched points thinned to
//!   `voxel_m`, in metres of wall; a corridor's two walls leave the axis along it free), and
//! - *unique in heading*: the query turned by 180° does not fit nearly as well (`flip_ratio`,
//!   from a second search; symmetric corridors and rooms fit both ways).
//!
//! [`Evidence::score`] folds these into one number in `[0, 1]`, so that rivals in
//! [`crate::verify_candidates`] are compared on the same scale.
//!
//! The free space is the query keyframe's own: the nearest return per 1° bearing from its
//! origin. For a single scan that is exact; for a local map (points seen from several poses
//! along the path) it is an approximation that holds where the path passed in the open.
//!
//! **Whole maps**. When both keyframes carry the free space their beams crossed
//! ([`Keyframe::with_free_space`]), the two local maps are compared over their whole overlap
//! instead: each map's points are checked against the other map, agreeing near one of its
//! returns and disagreeing in its free space, and points where the other map knows nothing
//! count for neither (Birk & Carpin 2006's agreement `agr / (agr + dis)`, over points). The
//! score is then that agreement, reduced for a small overlap, a good 180° fit and a weak
//! constraint: a query that saw further than the candidate is no longer held against it, while
//! a wall where the other map saw through still is.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::FreeSpace;
use mapmerge_params::{Checker, Real, Validate};
use mapmerge_scan::{estimate_normals, transform_points, voxel_downsample, Point2};
use nalgebra::Matrix2;
use serde::{Deserialize, Serialize};

use crate::Keyframe;

/// Bearing bins of the free-space profile (1° each).
const BEARING_BINS: usize = 360;

/// Parameters of the evidence check.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvidenceParams {
    /// Both point sets are thinned to one point per cell of this size (m) (default: 0.1), so
    /// counts measure length of structure, not scanner density.
    pub voxel_m: f64,
    /// A query point with a candidate point within this distance is an inlier (m)
    /// (default: 0.15).
    pub inlier_m: f64,
    /// A candidate point violates the query's free space when it lies this far (m) in front
    /// of the query's returns on its bearing and its neighbours' (default: 0.3) …
    pub free_space_margin_m: f64,
    /// … and farther than this (m) from every query point (default: 0.3).
    pub violation_clearance_m: f64,
    /// Weight of `violation_fraction` in the score (default: 3: 5 % of the candidate's
    /// structure in the query's free space costs 0.15). Higher refuses more look-alikes and
    /// more true places whose doors or furniture moved.
    pub violation_weight: f64,
    /// Weight of the part of `flip_ratio` above `flip_tolerance` in the score (default: 2).
    pub flip_weight: f64,
    /// See `flip_weight` (default: 0.5: a turned query that fits half as well is normal).
    pub flip_tolerance: f64,
    /// With both keyframes' free space, measure the flip on the whole-map scale instead of
    /// the scan matcher's: `flip_ratio` becomes the best placement's disagreement over the
    /// turned placement's, `(1 − agreement) / (1 − turned agreement)` (1 when the turned
    /// placement agrees as well; [`disagreement_ratio`]) (default: false). In a corridor
    /// the turned local map fits the matcher almost as well (ratio 0.8–0.95, so the true
    /// place scores 0.3–0.45) while disagreeing several times as much over the whole
    /// overlap.
    pub flip_by_agreement: bool,
    /// Matched structure (m of line-like wall in the weakest direction) from which the score is
    /// not reduced; below it the score shrinks in proportion (default: 3). Higher refuses
    /// more corridor-like places.
    pub full_constraint_m: f64,
    /// With both keyframes' free space: a placement that puts less than this fraction of the
    /// query's points where the candidate knows the space is scored down in proportion
    /// (default: 0.5); the agreement of a small overlap proves little.
    pub min_overlap_fraction: f64,
    /// With both keyframes' free space, the agreement enters the score as the lower end of
    /// its Wilson score interval at this many standard deviations over `overlap_points`
    /// (0: the agreement itself) (default: 0). An agreement measured over many points is
    /// firmer evidence than the same fraction over few.
    pub agreement_z: f64,
    /// With both keyframes' free space: a placement whose distance metric
    /// ([`Evidence::distance_m`]) exceeds this (m) scores 0 (default: none, no limit).
    pub max_distance_m: Option<f64>,
    /// Distances that enter [`Evidence::distance_m`] are capped at this (m) (default: 1), so
    /// a few points far from everything do not outweigh the rest.
    pub distance_cap_m: f64,
    /// With both keyframes' free space, a map's points that its own beams later saw through
    /// (the point's cell and the eight around it crossed: a person who walked on, a door
    /// that opened; [`FreeSpace::is_free_around`]) count for neither agreement nor
    /// disagreement (default: false). The other map cannot be held to them.
    pub skip_transient: bool,
    /// Radius of the neighbourhood that gives a point's normal (m) (default: 0.2).
    pub normal_radius_m: f64,
    /// Points whose neighbourhood is less line-like than this count as no structure
    /// (`planarity`, 0..1) (default: 0.5).
    pub min_planarity: f64,
}

impl Default for EvidenceParams {
    fn default() -> Self {
        Self {
            voxel_m: 0.1,
            inlier_m: 0.15,
            free_space_margin_m: 0.3,
            violation_clearance_m: 0.3,
            violation_weight: 3.0,
            flip_weight: 2.0,
            flip_tolerance: 0.5,
            flip_by_agreement: false,
            full_constraint_m: 3.0,
            min_overlap_fraction: 0.5,
            agreement_z: 0.0,
            max_distance_m: None,
            distance_cap_m: 1.0,
            skip_transient: false,
            normal_radius_m: 0.2,
            min_planarity: 0.5,
        }
    }
}

/// What an alignment proves (see the module documentation).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Evidence {
    /// Thinned query points.
    pub query_points: usize,
    /// Fraction of them with a candidate point within `inlier_m`.
    pub inlier_fraction: f64,
    /// Thinned candidate points on bearings the query observed.
    pub candidate_points_in_view: usize,
    /// Fraction of those in the query's free space.
    pub violation_fraction: f64,
    /// Matched line-like structure in the weakest direction (m of wall).
    pub constraint_m: f64,
    /// Scan-matcher score with the query turned by 180° over the score of the alignment
    /// (0 when that search found nothing); with `EvidenceParams::flip_by_agreement` on whole
    /// maps, the alignment's whole-map disagreement over the turned placement's.
    pub flip_ratio: f64,
    /// Whether both keyframes carried their free space: the score is then the whole-map
    /// agreement's.
    pub whole_map: bool,
    /// With both keyframes' free space: the points of either map that fall where the other
    /// map knows the space (near one of its returns, or in its free space), both directions
    /// together …
    pub overlap_points: usize,
    /// … the fraction of them near a return of the other map (Birk & Carpin 2006's
    /// agreement, `agr / (agr + dis)`, over points instead of cells; 0 without free space) …
    pub agreement: f64,
    /// … the fraction of the query's points that fall where the candidate knows the space …
    pub overlap_fraction: f64,
    /// … and the modified distance metric DM of Andersone (2019, Sec. 3.3) over those points
    /// instead of cells (m): per map, the mean distance from its overlapping points to the
    /// other map's nearest return (each capped at `distance_cap_m`), summed over the two
    /// maps. 0 for identical maps; it grows with misalignment, while the agreement (SM)
    /// only counts points beyond a tolerance. 0 without free space.
    #[serde(default)]
    pub distance_m: f64,
    /// The evidence in `[0, 1]`: `support · min(1, constraint_m / full_constraint_m)` (0 when
    /// `distance_m` exceeds `EvidenceParams::max_distance_m`), where
    /// with both keyframes' free space `support = max(0, agreement − flip) · min(1,
    /// overlap_fraction / min_overlap_fraction)` (the two maps agree wherever both know the
    /// space; the agreement taken at the lower end of its Wilson interval over
    /// `overlap_points` when `EvidenceParams::agreement_z` > 0), and without `support = inlier_fraction − violation_weight ·
    /// violation_fraction − flip` (points the candidate never saw count against it);
    /// `flip = flip_weight · max(0, flip_ratio − flip_tolerance)`.
    pub score: f64,
}

impl Evidence {
    /// The score of these parts under `params` (see [`Evidence::score`]).
    pub fn score_with(&self, params: &EvidenceParams) -> f64 {
        let flip_penalty = params.flip_weight * (self.flip_ratio - params.flip_tolerance).max(0.0);
        let support = if self.whole_map {
            // The two maps agree wherever both know the space.
            let overlapping = if params.min_overlap_fraction > 0.0 {
                (self.overlap_fraction / params.min_overlap_fraction).min(1.0)
            } else {
                1.0
            };
            let agreement =
                wilson_lower_bound(self.agreement, self.overlap_points, params.agreement_z);
            if params
                .max_distance_m
                .is_some_and(|max| self.distance_m > max)
            {
                return 0.0;
            }
            (agreement - flip_penalty).max(0.0) * overlapping
        } else {
            // Completeness less the candidate's points in the query's free space.
            self.inlier_fraction - params.violation_weight * self.violation_fraction - flip_penalty
        };
        let constrained = if params.full_constraint_m > 0.0 {
            (self.constraint_m / params.full_constraint_m).min(1.0)
        } else {
            1.0
        };
        (support * constrained).clamp(0.0, 1.0)
    }
}

/// How nearly a turned placement agrees as well as the best one, in `[0, 1]`: the best
/// placement's disagreement over the turned one's, `(1 − best) / (1 − turned)` for whole-map
/// agreements `best` and `turned`; 1 when the turned placement agrees at least as well.
pub fn disagreement_ratio(best_agreement: f64, turned_agreement: f64) -> f64 {
    let (best, turned) = (1.0 - best_agreement, 1.0 - turned_agreement);
    if turned <= best {
        1.0
    } else {
        (best / turned).clamp(0.0, 1.0)
    }
}

/// The lower end of the Wilson score interval of a fraction `p` observed over `n` trials, at
/// `z` standard deviations (Wilson 1927); `p` itself when `z` is not a positive finite
/// number, 0 without trials.
pub fn wilson_lower_bound(p: f64, n: usize, z: f64) -> f64 {
    if z.is_nan() || z.is_infinite() || z <= 0.0 {
        return p;
    }
    if n == 0 {
        return 0.0;
    }
    let (n, z2) = (n as f64, z * z);
    let centre = p + z2 / (2.0 * n);
    let spread = z * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).max(0.0).sqrt();
    ((centre - spread) / (1.0 + z2 / n)).clamp(0.0, 1.0)
}

/// A 2D k-d tree and nearest-neighbour distances (m).
struct Nearest(Option<ImmutableKdTree<f64, 2>>);

impl Nearest {
    fn new(points: &[Point2]) -> Self {
        let coords: Vec<[f64; 2]> = points.iter().map(|p| [p.x, p.y]).collect();
        Self(ImmutableKdTree::new_from_slice(&coords).ok())
    }

    fn distance_m(&self, p: &Point2) -> f64 {
        self.0.as_ref().map_or(f64::INFINITY, |tree| {
            tree.query(&[p.x, p.y])
                .nearest_one::<SquaredEuclidean<f64>>()
                .execute()
                .distance
                .sqrt()
        })
    }
}

/// One map's points against the other map (see [`evidence`]).
#[derive(Default)]
struct Tally {
    agree: usize,
    disagree: usize,
    /// Points where the other map knows the space …
    known: usize,
    /// … and the sum of their distances to its nearest return, capped (m).
    distance_sum_m: f64,
}

impl Tally {
    /// The mean capped distance; `cap_m` when no point overlaps (nothing shows agreement).
    fn mean_distance_m(&self, cap_m: f64) -> f64 {
        if self.known == 0 {
            cap_m
        } else {
            self.distance_sum_m / self.known as f64
        }
    }
}

/// Bearing bin of a point seen from the origin.
fn bearing_bin(p: &Point2) -> usize {
    let turns = (p.y.atan2(p.x) / std::f64::consts::TAU).rem_euclid(1.0);
    ((turns * BEARING_BINS as f64) as usize).min(BEARING_BINS - 1)
}

/// The evidence for `candidate_from_query` aligning `query`'s points (query frame) to
/// `candidate`'s (candidate frame); `flip_ratio` is passed in (it needs a second scan match)
/// and enters the score. When both keyframes carry their free space, the two maps are also
/// compared over their whole overlap ([`Evidence::agreement`]). Non-finite points are ignored.
pub fn evidence(
    query: &Keyframe,
    candidate: &Keyframe,
    candidate_from_query: &Se2,
    flip_ratio: f64,
    params: &EvidenceParams,
) -> Evidence {
    let finite = |points: &[Point2]| -> Vec<Point2> {
        let kept: Vec<Point2> = points
            .iter()
            .filter(|p| p.x.is_finite() && p.y.is_finite())
            .copied()
            .collect();
        voxel_downsample(&kept, params.voxel_m)
    };
    let free_spaces = query
        .free_space
        .as_deref()
        .zip(candidate.free_space.as_deref());
    let query = finite(&query.points_in_keyframe);
    let candidate = finite(&candidate.points_in_keyframe);
    let mut out = Evidence {
        query_points: query.len(),
        flip_ratio,
        ..Evidence::default()
    };
    if query.is_empty() || candidate.is_empty() {
        return out;
    }
    let query_in_candidate = transform_points(candidate_from_query, &query);
    let candidate_in_query = transform_points(&candidate_from_query.inverse(), &candidate);
    let near_candidate = Nearest::new(&candidate);
    let near_query = Nearest::new(&query);
    // 1. Completeness.
    let query_to_candidate_m: Vec<f64> = query_in_candidate
        .iter()
        .map(|p| near_candidate.distance_m(p))
        .collect();
    let inliers = query_to_candidate_m
        .iter()
        .filter(|&&d| d <= params.inlier_m)
        .count();
    out.inlier_fraction = inliers as f64 / query.len() as f64;
    // 2. Constraint: Σ n nᵀ over line-like matched query points (one per voxel, so each
    // stands for `voxel_m` of wall).
    let mut information = Matrix2::<f64>::zeros();
    let viewpoint = candidate_from_query.translation();
    for normal in estimate_normals(&query_in_candidate, params.normal_radius_m, 3, &viewpoint) {
        if normal.planarity >= params.min_planarity
            && near_candidate.distance_m(&normal.point) <= params.inlier_m
        {
            information += normal.normal * normal.normal.transpose();
        }
    }
    out.constraint_m = params.voxel_m * information.symmetric_eigenvalues().min().max(0.0);
    // 3. Free space: the query's nearest return per bearing, and candidate points in front.
    let mut range_m = [f64::INFINITY; BEARING_BINS];
    for p in &query {
        if let Some(r) = range_m.get_mut(bearing_bin(p)) {
            *r = r.min(p.norm());
        }
    }
    let (mut in_view, mut violations) = (0usize, 0usize);
    for p in &candidate_in_query {
        let bin = bearing_bin(p);
        let seen = [bin + BEARING_BINS - 1, bin, bin + 1].map(|b| {
            range_m
                .get(b % BEARING_BINS)
                .copied()
                .unwrap_or(f64::INFINITY)
        });
        if seen.iter().any(|r| !r.is_finite()) {
            continue;
        }
        in_view += 1;
        let in_front = seen
            .iter()
            .all(|r| p.norm() < r - params.free_space_margin_m);
        if in_front && near_query.distance_m(p) > params.violation_clearance_m {
            violations += 1;
        }
    }
    out.candidate_points_in_view = in_view;
    out.violation_fraction = if in_view > 0 {
        violations as f64 / in_view as f64
    } else {
        0.0
    };
    // 4. Whole-map agreement: each map's points against the other's returns and free space.
    if let Some((query_free, candidate_free)) = free_spaces {
        // Of `points` against a map's returns (distances given) and free space: agreeing and
        // disagreeing points, and the points where that map knows the space with the sum of
        // their capped distances (DM).
        // Each map's own points its beams saw through (`skip_transient`; none when off).
        let transient = |points: &[Point2], own_free: &FreeSpace| -> Vec<bool> {
            if !params.skip_transient {
                return Vec::new();
            }
            points.iter().map(|p| own_free.is_free_around(p)).collect()
        };
        let query_transient = transient(&query, query_free);
        let candidate_transient = transient(&candidate, candidate_free);
        let tally = |points: &[Point2],
                     distances_m: &mut dyn Iterator<Item = f64>,
                     transient: &[bool],
                     free: &FreeSpace| {
            let mut t = Tally::default();
            for (i, (p, d)) in points.iter().zip(distances_m).enumerate() {
                if transient.get(i).copied().unwrap_or(false) {
                    continue;
                }
                // Near a return the other map knows the space; beyond the clearance only
                // its free space does (and then the point disagrees).
                if d <= params.inlier_m {
                    t.agree += 1;
                } else if d > params.violation_clearance_m {
                    if !free.is_free(p) {
                        continue;
                    }
                    t.disagree += 1;
                }
                t.known += 1;
                t.distance_sum_m += d.min(params.distance_cap_m);
            }
            t
        };
        let query_tally = tally(
            &query_in_candidate,
            &mut query_to_candidate_m.iter().copied(),
            &query_transient,
            candidate_free,
        );
        let candidate_tally = tally(
            &candidate_in_query,
            &mut candidate_in_query.iter().map(|p| near_query.distance_m(p)),
            &candidate_transient,
            query_free,
        );
        let agree = query_tally.agree + candidate_tally.agree;
        let known = agree + query_tally.disagree + candidate_tally.disagree;
        out.overlap_points = known;
        out.agreement = if known > 0 {
            agree as f64 / known as f64
        } else {
            0.0
        };
        out.overlap_fraction =
            (query_tally.agree + query_tally.disagree) as f64 / query.len() as f64;
        out.distance_m = query_tally.mean_distance_m(params.distance_cap_m)
            + candidate_tally.mean_distance_m(params.distance_cap_m);
    }
    out.whole_map = free_spaces.is_some();
    out.score = out.score_with(params);
    out
}

impl Validate for EvidenceParams {
    fn check(&self, check: &mut Checker) {
        check
            .real("voxel_m", self.voxel_m, Real::within(0.0, 10.0))
            .real("inlier_m", self.inlier_m, Real::positive())
            .real(
                "free_space_margin_m",
                self.free_space_margin_m,
                Real::non_negative(),
            )
            .real(
                "violation_clearance_m",
                self.violation_clearance_m,
                Real::non_negative(),
            )
            .real(
                "violation_weight",
                self.violation_weight,
                Real::non_negative(),
            )
            .real("flip_weight", self.flip_weight, Real::non_negative())
            .real("flip_tolerance", self.flip_tolerance, Real::non_negative())
            .real(
                "full_constraint_m",
                self.full_constraint_m,
                Real::non_negative(),
            )
            .real(
                "min_overlap_fraction",
                self.min_overlap_fraction,
                Real::fraction(),
            )
            .real("agreement_z", self.agreement_z, Real::within(0.0, 10.0))
            .real_opt("max_distance_m", self.max_distance_m, Real::positive())
            .real("distance_cap_m", self.distance_cap_m, Real::positive())
            .real(
                "normal_radius_m",
                self.normal_radius_m,
                Real::positive_up_to(100.0),
            )
            .real("min_planarity", self.min_planarity, Real::fraction());
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    /// A keyframe of `points` without free space.
    fn kf(points: Vec<Point2>) -> Keyframe {
        Keyframe::new(0, points)
    }

    /// A keyframe of `points` seen from its origin, with the free space of those rays.
    fn seen_from_origin(points: Vec<Point2>) -> Keyframe {
        let rays: Vec<(Point2, Point2)> = points.iter().map(|p| (Point2::zeros(), *p)).collect();
        Keyframe::new(0, points).with_free_space(FreeSpace::from_rays(0.1, rays).unwrap())
    }

    #[test]
    fn the_wilson_lower_bound_matches_the_textbook_value_and_firms_up_with_more_points() {
        // p = 0.5 over 100 trials at 1.96 standard deviations: 0.4038 (Wilson 1927).
        assert!((wilson_lower_bound(0.5, 100, 1.96) - 0.4038).abs() < 1e-4);
        assert_eq!(wilson_lower_bound(0.97, 10, 0.0), 0.97);
        assert_eq!(wilson_lower_bound(0.97, 10, f64::NAN), 0.97);
        assert_eq!(wilson_lower_bound(0.97, 0, 3.0), 0.0);
        assert!((wilson_lower_bound(1.0, 1_000_000, 3.0) - 1.0).abs() < 1e-4);
        for p in [0.0, 0.3, 0.9, 0.99, 1.0] {
            let mut previous = 0.0;
            for n in [1, 10, 100, 1000, 10_000] {
                let bound = wilson_lower_bound(p, n, 3.0);
                assert!((0.0..=p + 1e-12).contains(&bound), "p {p} n {n}: {bound}");
                assert!(
                    bound >= previous - 1e-12,
                    "p {p} n {n}: {bound} < {previous}"
                );
                previous = bound;
            }
        }
        // In the score: the same agreement over more points scores higher.
        let parts = |overlap_points| Evidence {
            query_points: 100,
            inlier_fraction: 1.0,
            candidate_points_in_view: 100,
            violation_fraction: 0.0,
            constraint_m: 5.0,
            flip_ratio: 0.0,
            whole_map: true,
            overlap_points,
            agreement: 0.98,
            overlap_fraction: 1.0,
            distance_m: 0.0,
            score: 0.0,
        };
        let params = EvidenceParams {
            agreement_z: 3.0,
            ..EvidenceParams::default()
        };
        let (few, many) = (
            parts(200).score_with(&params),
            parts(5000).score_with(&params),
        );
        assert!(few < many && many < 0.98, "{few} {many}");
        assert_eq!(parts(200).score_with(&EvidenceParams::default()), 0.98);
    }

    #[test]
    fn whole_maps_agree_over_their_overlap_and_ignore_what_one_never_saw() {
        // The query is the whole room seen from its origin, aligned at the identity.
        let against = |candidate: &Keyframe| {
            evidence(
                &seen_from_origin(room()),
                candidate,
                &Se2::new(0.0, 0.0, 0.0),
                0.0,
                &EvidenceParams::default(),
            )
        };
        let same = against(&seen_from_origin(room()));
        assert!(same.agreement > 0.99, "{same:?}");
        assert!(same.overlap_fraction > 0.95, "{same:?}");
        // The candidate saw only the left part of the room: the rest is unknown to it, which
        // lowers the overlap but not the agreement.
        let left: Vec<Point2> = room().into_iter().filter(|p| p.x < 0.5).collect();
        let partial = against(&seen_from_origin(left));
        assert!(partial.agreement > 0.99, "{partial:?}");
        assert!(partial.overlap_fraction < 0.7, "{partial:?}");
        assert!(partial.inlier_fraction < 0.7, "{partial:?}");
        // A wall where the query saw through disagrees.
        let mut walled = room();
        walled.extend(wall((2.0, -2.0), (2.0, 2.0)));
        let wrong = against(&seen_from_origin(walled));
        assert!(wrong.agreement < 0.95, "{wrong:?}");
        // Without the candidate's free space there is no agreement to measure.
        let none = against(&kf(room()));
        assert_eq!((none.agreement, none.overlap_points), (0.0, 0));
        assert!(!none.whole_map && same.whole_map);
    }

    /// A person the query saw from one pose and its later beams crossed disagrees with a
    /// candidate that saw the room empty, unless points the own map saw through are skipped;
    /// a wall the candidate's beams never crossed disagrees either way.
    #[test]
    fn points_the_own_map_saw_through_can_be_skipped_and_walls_still_disagree() {
        let person: Vec<Point2> = (0..24)
            .map(|i| {
                let a = i as f64 * std::f64::consts::TAU / 24.0;
                Point2::new(2.0 + 0.15 * a.cos(), 0.15 * a.sin())
            })
            .collect();
        let mut rays: Vec<(Point2, Point2)> =
            room().iter().map(|p| (Point2::zeros(), *p)).collect();
        rays.extend(person.iter().map(|p| (Point2::new(-2.0, 0.5), *p)));
        let mut points = room();
        points.extend(person.iter().copied());
        let query =
            Keyframe::new(0, points).with_free_space(FreeSpace::from_rays(0.1, rays).unwrap());
        let skipping = EvidenceParams {
            skip_transient: true,
            ..EvidenceParams::default()
        };
        let at_identity = |candidate: &Keyframe, params: &EvidenceParams| {
            evidence(&query, candidate, &Se2::new(0.0, 0.0, 0.0), 0.0, params)
        };
        let empty_room = seen_from_origin(room());
        let counted = at_identity(&empty_room, &EvidenceParams::default());
        let skipped = at_identity(&empty_room, &skipping);
        assert!(counted.agreement < 0.99, "{counted:?}");
        assert!(skipped.agreement > 0.995, "{skipped:?}");
        assert!(skipped.overlap_points < counted.overlap_points);
        // A room with a wall across at x = 2, seen from its origin (nothing behind the wall).
        let mut walled: Vec<Point2> = room().into_iter().filter(|p| p.x < 2.0).collect();
        walled.extend(wall((2.0, -2.0), (2.0, 2.0)));
        let wrong = at_identity(&seen_from_origin(walled), &skipping);
        assert!(wrong.agreement < 0.95, "{wrong:?}");
    }

    #[test]
    fn the_distance_metric_grows_with_misalignment_and_can_refuse_a_placement() {
        let at = |x_m: f64, params: &EvidenceParams| {
            evidence(
                &seen_from_origin(room()),
                &seen_from_origin(room()),
                &Se2::new(x_m, 0.0, 0.0),
                0.0,
                params,
            )
        };
        let defaults = EvidenceParams::default();
        let distances: Vec<f64> = [0.0, 0.1, 0.2, 0.4]
            .iter()
            .map(|x| at(*x, &defaults).distance_m)
            .collect();
        assert!(distances[0] < 0.02, "{distances:?}");
        for pair in distances.windows(2) {
            assert!(pair[1] > pair[0], "{distances:?}");
        }
        // Within the inlier tolerance the agreement cannot tell 0 from 0.1 m; DM can.
        assert!(at(0.1, &defaults).agreement > 0.99);
        let strict = EvidenceParams {
            max_distance_m: Some(0.1),
            ..defaults
        };
        assert!(at(0.0, &strict).score > 0.9);
        assert_eq!(at(0.2, &strict).score, 0.0);
        assert!(at(0.2, &defaults).score > 0.0);
    }

    /// Points every 2 cm along the segment `a`–`b`.
    fn wall(a: (f64, f64), b: (f64, f64)) -> Vec<Point2> {
        let (a, b) = (Point2::new(a.0, a.1), Point2::new(b.0, b.1));
        let n = ((b - a).norm() / 0.02).ceil() as usize;
        (0..=n)
            .map(|i| a + (b - a) * (i as f64 / n as f64))
            .collect()
    }

    /// A room with an alcove, seen from inside.
    fn room() -> Vec<Point2> {
        [
            ((-3.0, -2.0), (4.0, -2.0)),
            ((4.0, -2.0), (4.0, 3.0)),
            ((4.0, 3.0), (1.0, 3.0)),
            ((1.0, 3.0), (1.0, 2.0)),
            ((1.0, 2.0), (-3.0, 2.0)),
            ((-3.0, 2.0), (-3.0, -2.0)),
        ]
        .iter()
        .flat_map(|(a, b)| wall(*a, *b))
        .collect()
    }

    #[test]
    fn a_true_alignment_scores_high() {
        let e = evidence(
            &kf(room()),
            &kf(room()),
            &Se2::new(0.0, 0.0, 0.0),
            0.0,
            &EvidenceParams::default(),
        );
        assert!(e.inlier_fraction > 0.99, "{e:?}");
        assert_eq!(e.violation_fraction, 0.0);
        assert!(e.constraint_m > 6.0, "{e:?}");
        assert!(e.score > 0.99, "{e:?}");
    }

    #[test]
    fn a_corridor_is_not_constrained() {
        let corridor: Vec<Point2> = wall((-8.0, -1.0), (8.0, -1.0))
            .into_iter()
            .chain(wall((-8.0, 1.0), (8.0, 1.0)))
            .collect();
        let e = evidence(
            &kf(corridor.clone()),
            &kf(corridor.clone()),
            &Se2::new(0.0, 0.0, 0.0),
            0.0,
            &EvidenceParams::default(),
        );
        assert!(e.inlier_fraction > 0.99);
        assert!(e.constraint_m < 0.3, "{e:?}");
        assert!(e.score < 0.1, "{e:?}");
    }

    #[test]
    fn candidate_walls_in_the_query_free_space_count_against() {
        // The candidate has a wall across the room where the query saw through.
        let mut candidate = room();
        candidate.extend(wall((2.0, -2.0), (2.0, 2.0)));
        let e = evidence(
            &kf(room()),
            &kf(candidate),
            &Se2::new(0.0, 0.0, 0.0),
            0.0,
            &EvidenceParams::default(),
        );
        assert!(e.violation_fraction > 0.1, "{e:?}");
        let clean = evidence(
            &kf(room()),
            &kf(room()),
            &Se2::new(0.0, 0.0, 0.0),
            0.0,
            &EvidenceParams::default(),
        );
        assert!(e.score < clean.score - 0.1);
    }

    #[test]
    fn a_good_flip_lowers_the_score_and_empty_input_scores_zero() {
        let params = EvidenceParams::default();
        let identity = Se2::new(0.0, 0.0, 0.0);
        let flipped = evidence(&kf(room()), &kf(room()), &identity, 0.8, &params);
        assert!(
            (flipped.score - (1.0 - 2.0 * 0.3)).abs() < 0.02,
            "{flipped:?}"
        );
        assert_eq!(
            evidence(&kf(vec![]), &kf(room()), &identity, 0.0, &params).score,
            0.0
        );
        let nan = [Point2::new(f64::NAN, 1.0)];
        assert_eq!(
            evidence(
                &kf(nan.to_vec()),
                &kf(nan.to_vec()),
                &identity,
                0.0,
                &params
            )
            .score,
            0.0
        );
    }
}
