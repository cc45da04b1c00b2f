//! The production [`GeometricVerifier`]: the correlative scan matcher with ICP
//! (`mapmerge-scanmatch`), searching a window around the descriptor's yaw guess, optionally
//! scored by the [`Evidence`] the alignment gives.

use mapmerge_geometry::Se2;
use mapmerge_params::{Checker, Validate};
use mapmerge_scanmatch::{
    match_scan_above, Match, ScanMatchError, ScanMatchParams, ScanMatchTarget, ScanMatcher,
    SearchWindow,
};
use serde::{Deserialize, Serialize};
use std::sync::Mutex;

use crate::evidence::{disagreement_ratio, evidence, Evidence, EvidenceParams};
use crate::{GeometricVerifier, Keyframe, Verification};

/// The verifier of place recognition without a pose prior (the atlas's merge search, the
/// better-hypothesis detector): the correlative matcher with ICP within `window` around the
/// descriptor's yaw guess, scored by its [`Evidence`] (`mapmerge-place`'s benchmark
/// configuration, with a coarser search query).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlaceVerifierParams {
    /// The matcher (default: [`ScanMatchParams::default`] with a query thinned to one point
    /// per 0.4 m cell, `correlative.query_voxel_m`, for the search and ICP; the evidence
    /// still sees every point). A local map of a few metres keeps its shape, and the search
    /// costs in proportion to the query's points: 0.05 m took twice the time of 0.2 m for
    /// as many merges on the simulator's tuning seeds, and 0.4 m recalled as many places as
    /// 0.2 m on the tuning logs in 0.6–0.7 of the time.
    pub matcher: ScanMatchParams,
    /// Search window around the guess (default: ±2 m, ±15°: Scan Context's yaw is good to
    /// a sector or two and its translation guess is zero).
    pub window: SearchWindow,
    /// The evidence that scores an alignment (default: [`EvidenceParams::default`]).
    pub evidence: EvidenceParams,
}

impl Default for PlaceVerifierParams {
    fn default() -> Self {
        let mut matcher = ScanMatchParams::default();
        matcher.correlative.query_voxel_m = 0.4;
        Self {
            matcher,
            window: SearchWindow::new(2.0, 15f64.to_radians()),
            evidence: EvidenceParams::default(),
        }
    }
}

impl PlaceVerifierParams {
    /// The same parameters with the flip measured on the whole-map scale
    /// ([`EvidenceParams::flip_by_agreement`]).
    pub fn with_flip_by_agreement(mut self) -> Self {
        self.evidence.flip_by_agreement = true;
        self
    }

    /// The verifier (fails on invalid matcher parameters).
    pub fn verifier(&self) -> Result<ScanMatchVerifier, ScanMatchError> {
        Ok(ScanMatchVerifier::new(self.matcher, self.window)?.with_evidence(self.evidence))
    }
}

/// Verifies candidates with [`ScanMatcher`]: the candidate's points become the match target and
/// the query's points are searched within `window` around the guess. Scan Context's yaw is good
/// to a sector or two and its translation guess is zero, so the default window is ±2 m, ±15°.
///
/// By default the score is the matcher's (mean likelihood of the query points). With
/// [`ScanMatchVerifier::with_evidence`] it is the [`Evidence::score`] instead, which also
/// searches the query turned by 180° (twice the matching time) and is what place recognition
/// without a pose prior needs: the matcher's score is as high in the wrong section of a
/// corridor as in the right one.
pub struct ScanMatchVerifier {
    matcher: ScanMatcher,
    window: SearchWindow,
    evidence: Option<EvidenceParams>,
    /// Targets built before, whose memory the next candidates' targets reuse (one per
    /// thread verifying at a time): a local map's grid and levels are megabytes, and fresh
    /// ones cost more in page faults than in rasterising.
    spare_targets: Mutex<Vec<ScanMatchTarget>>,
}

impl ScanMatchVerifier {
    /// A verifier with the matcher's parameters and the search window around the guess.
    /// Each candidate's target is built for this window only: its branch-and-bound depth is
    /// at most what the window needs ([`SearchWindow::branch_and_bound_depth`]; the same
    /// matches, fewer levels to precompute).
    pub fn new(
        mut params: ScanMatchParams,
        window: SearchWindow,
    ) -> Result<Self, mapmerge_scanmatch::ScanMatchError> {
        if let Some(depth) = window.branch_and_bound_depth(params.correlative.resolution_m) {
            let correlative = &mut params.correlative;
            correlative.branch_and_bound_depth = correlative.branch_and_bound_depth.min(depth);
        }
        Ok(Self {
            matcher: ScanMatcher::new(params)?,
            window,
            evidence: None,
            spare_targets: Mutex::new(Vec::new()),
        })
    }

    /// The same verifier scoring by [`Evidence::score`] with `params`.
    pub fn with_evidence(mut self, params: EvidenceParams) -> Self {
        self.evidence = Some(params);
        self
    }

    /// The candidate as a match target (in a spare target's memory when there is one), and
    /// the query matched against it within the window around the guess. Hand the target
    /// back with [`ScanMatchVerifier::spare`].
    fn search(
        &self,
        query: &Keyframe,
        candidate: &Keyframe,
        guess_candidate_from_query: &Se2,
        window: &SearchWindow,
    ) -> (Option<ScanMatchTarget>, Option<Match>) {
        let spare = self
            .spare_targets
            .lock()
            .ok()
            .and_then(|mut spare| spare.pop());
        let target = match spare {
            Some(mut target) => self
                .matcher
                .retarget(&mut target, &candidate.points_in_keyframe)
                .is_ok()
                .then_some(target),
            None => self.matcher.target(&candidate.points_in_keyframe).ok(),
        };
        let found = target.as_ref().and_then(|target| {
            self.matcher.match_scan(
                target,
                &query.points_in_keyframe,
                guess_candidate_from_query,
                window,
            )
        });
        (target, found)
    }

    /// Keeps `target`'s memory for the next candidate.
    fn spare(&self, target: Option<ScanMatchTarget>) {
        if let (Some(target), Ok(mut spare)) = (target, self.spare_targets.lock()) {
            spare.push(target);
        }
    }

    /// As [`GeometricVerifier::verify`], with the evidence (computed with the default
    /// [`EvidenceParams`] when the verifier has none; the score is then still the matcher's).
    pub fn verify_with_evidence(
        &self,
        query: &Keyframe,
        candidate: &Keyframe,
        guess_candidate_from_query: &Se2,
    ) -> Option<(Verification, Evidence)> {
        self.verify_within(query, candidate, guess_candidate_from_query, &self.window)
    }

    /// As [`ScanMatchVerifier::verify_with_evidence`], searching `window` around the guess
    /// in place of the verifier's own: a guess known to a few centimetres (an alignment
    /// found before and carried along the query's path) needs a far smaller window. The
    /// search for the query turned around keeps the verifier's window.
    pub fn verify_within(
        &self,
        query: &Keyframe,
        candidate: &Keyframe,
        guess_candidate_from_query: &Se2,
        window: &SearchWindow,
    ) -> Option<(Verification, Evidence)> {
        let (target, found) = self.search(query, candidate, guess_candidate_from_query, window);
        let verified = target.as_ref().zip(found).map(|(target, found)| {
            self.weigh(query, candidate, target, found, guess_candidate_from_query)
        });
        self.spare(target);
        verified
    }

    /// The evidence for the alignment `found` of `query` against `candidate`'s `target`.
    fn weigh(
        &self,
        query: &Keyframe,
        candidate: &Keyframe,
        target: &ScanMatchTarget,
        found: Match,
        guess_candidate_from_query: &Se2,
    ) -> (Verification, Evidence) {
        // The same search with the query turned around: symmetric places fit both ways.
        let turned = Se2::new(
            guess_candidate_from_query.x_m,
            guess_candidate_from_query.y_m,
            guess_candidate_from_query.theta_rad + std::f64::consts::PI,
        );
        let params = self.evidence.unwrap_or_default();
        // A whole-circle search has already weighed the turned pose against the best one
        // (it would find the same optimum again): no flip test then. Only a turned fit
        // above `flip_tolerance` of the best lowers the score, so the search for it prunes
        // everything below (the same score, far fewer candidates); `flip_ratio` reads 0 for
        // a turned fit below the floor. The ratio is of correlative scores, so no ICP.
        let flipped = if self.window.angular_rad >= std::f64::consts::PI || found.score <= 0.0 {
            None
        } else {
            let floor = (params.flip_tolerance * found.score)
                .max(self.matcher.params().correlative.min_score);
            match_scan_above(
                target.correlative(),
                &query.points_in_keyframe,
                &turned,
                &self.window,
                floor,
            )
        };
        let flip_ratio = flipped
            .as_ref()
            .map_or(0.0, |flipped| flipped.score / found.score);
        let mut proof = evidence(
            query,
            candidate,
            &found.target_from_query,
            flip_ratio,
            &params,
        );
        if params.flip_by_agreement && proof.whole_map {
            // The turned placement weighed on the same whole-map scale as the best one.
            proof.flip_ratio = flipped.map_or(0.0, |flipped| {
                let turned = evidence(query, candidate, &flipped.target_from_query, 0.0, &params);
                disagreement_ratio(proof.agreement, turned.agreement)
            });
            proof.score = proof.score_with(&params);
        }
        (
            Verification {
                candidate_from_query: found.target_from_query,
                score: if self.evidence.is_some() {
                    proof.score
                } else {
                    found.score
                },
                covariance: found.covariance,
            },
            proof,
        )
    }
}

impl Default for ScanMatchVerifier {
    fn default() -> Self {
        Self {
            matcher: ScanMatcher::default(),
            window: SearchWindow::new(2.0, 15f64.to_radians()),
            evidence: None,
            spare_targets: Mutex::new(Vec::new()),
        }
    }
}

impl GeometricVerifier for ScanMatchVerifier {
    fn verify(
        &self,
        query: &Keyframe,
        candidate: &Keyframe,
        guess_candidate_from_query: &Se2,
    ) -> Option<Verification> {
        if self.evidence.is_some() {
            return self
                .verify_with_evidence(query, candidate, guess_candidate_from_query)
                .map(|(v, _)| v);
        }
        let (target, found) =
            self.search(query, candidate, guess_candidate_from_query, &self.window);
        self.spare(target);
        let found = found?;
        Some(Verification {
            candidate_from_query: found.target_from_query,
            score: found.score,
            covariance: found.covariance,
        })
    }
}

impl Validate for PlaceVerifierParams {
    fn check(&self, check: &mut Checker) {
        check
            .nested("matcher", &self.matcher)
            .nested("window", &self.window)
            .nested("evidence", &self.evidence);
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use mapmerge_geometry::LieGroup;
    use mapmerge_scan::Point2;

    /// Points every 3 cm along the closed polygon `corners`.
    fn walls(corners: &[Point2]) -> Vec<Point2> {
        let mut points = Vec::new();
        for (i, a) in corners.iter().enumerate() {
            let b = corners[(i + 1) % corners.len()];
            let n = ((b - a).norm() / 0.03).ceil() as usize;
            points.extend((0..n).map(|j| a + (b - a) * (j as f64 / n as f64)));
        }
        points
    }

    /// The evidence with the flipped search run in full, as before the floor existed.
    fn unpruned_score(
        verifier: &ScanMatchVerifier,
        query: &Keyframe,
        candidate: &Keyframe,
        guess: &Se2,
    ) -> f64 {
        let (target, found) = verifier.search(query, candidate, guess, &verifier.window);
        let (target, found) = (target.unwrap(), found.unwrap());
        let turned = Se2::new(guess.x_m, guess.y_m, guess.theta_rad + std::f64::consts::PI);
        let flip_ratio = verifier
            .matcher
            .match_scan(
                &target,
                &query.points_in_keyframe,
                &turned,
                &verifier.window,
            )
            .map_or(0.0, |flipped| flipped.score / found.score);
        evidence(
            query,
            candidate,
            &found.target_from_query,
            flip_ratio,
            &verifier.evidence.unwrap_or_default(),
        )
        .score
    }

    /// The flipped search prunes below `flip_tolerance` of the best fit: the score is the
    /// full search's, in a rectangle (the turned query fits as well: penalised) and in an
    /// irregular room (it does not: no penalty either way).
    /// An irregular room's walls (no turned or shifted fit).
    fn irregular_room() -> Vec<Point2> {
        walls(&[
            Point2::new(-3.0, -2.5),
            Point2::new(5.0, -2.0),
            Point2::new(4.0, 3.0),
            Point2::new(-1.2, 3.0),
            Point2::new(-3.5, 1.0),
        ])
    }

    /// The default verifier with a query thinned to 0.2 m: these rooms are small, and at the
    /// default 0.4 m the irregular one keeps too few points to tell its turned fit from the
    /// rectangle's.
    fn fine_verifier() -> ScanMatchVerifier {
        let mut params = PlaceVerifierParams::default();
        params.matcher.correlative.query_voxel_m = 0.2;
        params.verifier().unwrap()
    }

    /// `room` as a candidate keyframe, and as a query seen from `candidate_from_query`.
    fn candidate_and_query(room: &[Point2], candidate_from_query: &Se2) -> (Keyframe, Keyframe) {
        let query_from_candidate = candidate_from_query.inverse();
        let query = room
            .iter()
            .map(|p| query_from_candidate.transform_point(p))
            .collect::<Vec<_>>();
        (Keyframe::new(1, room.to_vec()), Keyframe::new(2, query))
    }

    #[test]
    fn the_pruned_flip_search_gives_the_full_searchs_score() {
        let rectangle = walls(&[
            Point2::new(-3.0, -2.0),
            Point2::new(3.0, -2.0),
            Point2::new(3.0, 2.0),
            Point2::new(-3.0, 2.0),
        ]);
        let verifier = fine_verifier();
        let candidate_from_query = Se2::new(0.3, -0.2, 0.1);
        let mut flips = Vec::new();
        for room in [rectangle, irregular_room()] {
            let (candidate, query) = candidate_and_query(&room, &candidate_from_query);
            let guess = Se2::new(0.0, 0.0, 0.05);
            let (verification, proof) = verifier
                .verify_with_evidence(&query, &candidate, &guess)
                .unwrap();
            let full = unpruned_score(&verifier, &query, &candidate, &guess);
            assert!(
                (verification.score - full).abs() < 1e-12,
                "{verification:?} vs {full}"
            );
            flips.push(proof.flip_ratio);
        }
        assert!(flips[0] > 0.5, "the rectangle fits turned: {flips:?}");
        assert!(flips[1] <= 0.5, "the irregular room does not: {flips:?}");
    }

    /// A small window around a guess a few centimetres off finds the alignment and score of
    /// the whole window around a guess with no translation; around a guess 1 m off, it
    /// searches the small window only.
    #[test]
    fn a_small_window_around_a_close_guess_verifies_as_the_whole_window() {
        let verifier = fine_verifier();
        let candidate_from_query = Se2::new(0.8, -0.6, 0.1);
        let (candidate, query) = candidate_and_query(&irregular_room(), &candidate_from_query);
        let (whole, _) = verifier
            .verify_with_evidence(&query, &candidate, &Se2::new(0.0, 0.0, 0.05))
            .unwrap();
        let small = SearchWindow::new(0.3, 3f64.to_radians());
        let close = Se2::new(0.86, -0.55, 0.12);
        let (near, _) = verifier
            .verify_within(&query, &candidate, &close, &small)
            .unwrap();
        let offset = whole.candidate_from_query.between(&candidate_from_query);
        assert!(offset.translation().norm() < 0.05, "{whole:?}");
        let apart = near
            .candidate_from_query
            .between(&whole.candidate_from_query);
        assert!(
            apart.translation().norm() < 0.02 && apart.theta_rad.abs() < 0.01,
            "{near:?}"
        );
        assert!(
            (near.score - whole.score).abs() < 0.02,
            "{near:?} {whole:?}"
        );
        // The search stays inside the small window: from a guess 1 m off, whatever it finds
        // is within 0.3 m (and ICP's last step) of that guess, not the true alignment.
        let far = Se2::new(1.8, -0.6, 0.1);
        if let Some((v, _)) = verifier.verify_within(&query, &candidate, &far, &small) {
            let moved = far.between(&v.candidate_from_query).translation();
            assert!(moved.x.abs() < 0.4 && moved.y.abs() < 0.4, "{v:?}");
        }
    }

    /// A 360° scan (720 beams, robot frame) of the closed polygon `corners` from
    /// `world_from_robot` by the simulator's ray caster, as a keyframe with the free space
    /// its beams crossed.
    fn scanned(corners: &[Point2], world_from_robot: &Se2, id: u64) -> Keyframe {
        let walls: Vec<mapmerge_sim::LineSegment> = corners
            .iter()
            .zip(corners.iter().cycle().skip(1))
            .map(|(a, b)| mapmerge_sim::LineSegment::new(*a, *b))
            .collect();
        let caster = mapmerge_sim::RayCaster::from_segments(&walls, 1.0);
        let origin = world_from_robot.translation();
        let points: Vec<Point2> = (0..720)
            .filter_map(|i| {
                let bearing = i as f64 * std::f64::consts::TAU / 720.0;
                let range_m = caster.cast(&origin, world_from_robot.theta_rad + bearing, 30.0)?;
                Some(Point2::new(bearing.cos(), bearing.sin()) * range_m)
            })
            .collect();
        let rays = points
            .iter()
            .map(|p| (Point2::zeros(), *p))
            .collect::<Vec<_>>();
        let free = crate::FreeSpace::from_rays(0.1, rays).unwrap();
        Keyframe::new(id, points).with_free_space(free)
    }

    /// Whole maps: in a corridor with one niche the turned placement fits the matcher almost
    /// as well (the true place is scored down), while over the whole overlap it disagrees
    /// where the niche opens, so measured by agreement the true place keeps its score. A
    /// rectangle fits turned either way, and both measures say so.
    #[test]
    fn the_flip_by_agreement_spares_a_corridor_and_still_catches_a_symmetric_room() {
        let corridor = [
            Point2::new(-6.0, -1.0),
            Point2::new(6.0, -1.0),
            Point2::new(6.0, 1.0),
            Point2::new(2.5, 1.0),
            Point2::new(2.5, 2.5),
            Point2::new(1.5, 2.5),
            Point2::new(1.5, 1.0),
            Point2::new(-6.0, 1.0),
        ];
        let rectangle = [
            Point2::new(-3.0, -2.0),
            Point2::new(3.0, -2.0),
            Point2::new(3.0, 2.0),
            Point2::new(-3.0, 2.0),
        ];
        let by_matcher = PlaceVerifierParams::default();
        let by_agreement = PlaceVerifierParams::default().with_flip_by_agreement();
        let guess = Se2::new(0.0, 0.0, 0.05);
        let proofs = |corners: &[Point2]| {
            let candidate = scanned(corners, &Se2::new(0.0, 0.0, 0.0), 1);
            let query = scanned(corners, &Se2::new(0.3, -0.2, 0.1), 2);
            [&by_matcher, &by_agreement].map(|params| {
                let (verification, proof) = params
                    .verifier()
                    .unwrap()
                    .verify_with_evidence(&query, &candidate, &guess)
                    .unwrap();
                assert!(proof.whole_map);
                (verification.score, proof.flip_ratio)
            })
        };
        let [(matcher_score, matcher_flip), (agreement_score, agreement_flip)] = proofs(&corridor);
        assert!(
            matcher_flip > 0.5,
            "the corridor fits the matcher turned: {matcher_flip}"
        );
        assert!(matcher_score < 0.7, "{matcher_score}");
        assert!(
            agreement_flip <= 0.5,
            "but disagrees turned: {agreement_flip}"
        );
        assert!(agreement_score > 0.9, "{agreement_score}");
        let [(_, matcher_flip), (agreement_score, agreement_flip)] = proofs(&rectangle);
        assert!(matcher_flip > 0.5, "{matcher_flip}");
        assert!(
            agreement_flip > 0.5,
            "the rectangle agrees turned: {agreement_flip}"
        );
        assert!(agreement_score < 0.5, "{agreement_score}");
    }

    #[test]
    fn disagreement_ratio_is_one_for_an_equal_fit_and_falls_with_the_turned_disagreement() {
        assert_eq!(disagreement_ratio(1.0, 1.0), 1.0);
        assert_eq!(disagreement_ratio(0.95, 0.97), 1.0);
        assert!((disagreement_ratio(0.98, 0.9) - 0.2).abs() < 1e-12);
        assert_eq!(disagreement_ratio(1.0, 0.8), 0.0);
    }

    /// A target rebuilt in a spare target's memory verifies as a fresh one: a big room, then
    /// a small one (the grid shrinks), then the big one again (it grows), each against a
    /// verifier that never verified before.
    #[test]
    fn reused_targets_verify_as_fresh_ones() {
        let big = walls(&[
            Point2::new(-6.0, -4.0),
            Point2::new(7.0, -3.5),
            Point2::new(6.0, 5.0),
            Point2::new(-5.5, 4.0),
        ]);
        let small = walls(&[
            Point2::new(-2.0, -1.5),
            Point2::new(2.5, -1.0),
            Point2::new(2.0, 2.0),
            Point2::new(-1.5, 1.5),
        ]);
        let reused = PlaceVerifierParams::default().verifier().unwrap();
        let moved = Se2::new(0.3, -0.2, 0.1).inverse();
        for room in [&big, &small, &big] {
            let candidate = Keyframe::new(1, room.clone());
            let query = Keyframe::new(
                2,
                room.iter()
                    .map(|p| moved.transform_point(p))
                    .collect::<Vec<_>>(),
            );
            let guess = Se2::new(0.0, 0.0, 0.05);
            let fresh = PlaceVerifierParams::default().verifier().unwrap();
            assert_eq!(
                reused.verify_with_evidence(&query, &candidate, &guess),
                fresh.verify_with_evidence(&query, &candidate, &guess)
            );
        }
        assert_eq!(reused.spare_targets.lock().unwrap().len(), 1);
    }
}
