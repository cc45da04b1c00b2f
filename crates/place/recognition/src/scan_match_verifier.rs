//! The production [`GeometricVerifier`]: the correlative scan matcher with ICP
//! (`mapmerge-scanmatch`), searching a window around the descriptor's yaw guess, optionally
//! scored by the [`Evidence`] the alignment gives.

use mapmerge_geometry::Se2;
use mapmerge_scanmatch::{Match, ScanMatchParams, ScanMatchTarget, ScanMatcher, SearchWindow};

use crate::evidence::{evidence, Evidence, EvidenceParams};
use crate::{GeometricVerifier, Keyframe, Verification};

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
}

impl ScanMatchVerifier {
    /// A verifier with the matcher's parameters and the search window around the guess.
    pub fn new(
        params: ScanMatchParams,
        window: SearchWindow,
    ) -> Result<Self, mapmerge_scanmatch::ScanMatchError> {
        Ok(Self {
            matcher: ScanMatcher::new(params)?,
            window,
            evidence: None,
        })
    }

    /// The same verifier scoring by [`Evidence::score`] with `params`.
    pub fn with_evidence(mut self, params: EvidenceParams) -> Self {
        self.evidence = Some(params);
        self
    }

    /// The candidate as a match target, and the query matched against it within the window
    /// around the guess. Building a target costs tens of ms; verification runs on a few
    /// candidates per query.
    fn search(
        &self,
        query: &Keyframe,
        candidate: &Keyframe,
        guess_candidate_from_query: &Se2,
    ) -> Option<(ScanMatchTarget, Match)> {
        let target = self.matcher.target(&candidate.points_in_keyframe).ok()?;
        let found = self.matcher.match_scan(
            &target,
            &query.points_in_keyframe,
            guess_candidate_from_query,
            &self.window,
        )?;
        Some((target, found))
    }

    /// As [`GeometricVerifier::verify`], with the evidence (computed with the default
    /// [`EvidenceParams`] when the verifier has none; the score is then still the matcher's).
    pub fn verify_with_evidence(
        &self,
        query: &Keyframe,
        candidate: &Keyframe,
        guess_candidate_from_query: &Se2,
    ) -> Option<(Verification, Evidence)> {
        let (target, found) = self.search(query, candidate, guess_candidate_from_query)?;
        // The same search with the query turned around: symmetric places fit both ways.
        let turned = Se2::new(
            guess_candidate_from_query.x_m,
            guess_candidate_from_query.y_m,
            guess_candidate_from_query.theta_rad + std::f64::consts::PI,
        );
        // A whole-circle search has already weighed the turned pose against the best one
        // (it would find the same optimum again): no flip test then.
        let flip_ratio = if self.window.angular_rad >= std::f64::consts::PI {
            0.0
        } else {
            match self
                .matcher
                .match_scan(&target, &query.points_in_keyframe, &turned, &self.window)
            {
                Some(flipped) if found.score > 0.0 => flipped.score / found.score,
                _ => 0.0,
            }
        };
        let params = self.evidence.unwrap_or_default();
        let proof = evidence(
            &query.points_in_keyframe,
            &candidate.points_in_keyframe,
            &found.target_from_query,
            flip_ratio,
            &params,
        );
        Some((
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
        ))
    }
}

impl Default for ScanMatchVerifier {
    fn default() -> Self {
        Self {
            matcher: ScanMatcher::default(),
            window: SearchWindow::new(2.0, 15f64.to_radians()),
            evidence: None,
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
        let (_, found) = self.search(query, candidate, guess_candidate_from_query)?;
        Some(Verification {
            candidate_from_query: found.target_from_query,
            score: found.score,
            covariance: found.covariance,
        })
    }
}
