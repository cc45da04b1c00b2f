//! The production [`GeometricVerifier`]: the correlative scan matcher with ICP
//! (`mapmerge-scanmatch`), searching a window around the descriptor's yaw guess.

use mapmerge_geometry::Se2;
use mapmerge_scanmatch::{ScanMatchParams, ScanMatcher, SearchWindow};

use crate::{GeometricVerifier, Keyframe, Verification};

/// Verifies candidates with [`ScanMatcher`]: the candidate's points become the match target and
/// the query's points are searched within `window` around the guess. Scan Context's yaw is good
/// to a sector or two and its translation guess is zero, so the default window is ±2 m, ±15°.
pub struct ScanMatchVerifier {
    matcher: ScanMatcher,
    window: SearchWindow,
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
        })
    }
}

impl Default for ScanMatchVerifier {
    fn default() -> Self {
        Self {
            matcher: ScanMatcher::default(),
            window: SearchWindow::new(2.0, 15f64.to_radians()),
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
        // Building a target costs tens of ms; verification runs on a few candidates per query.
        let target = self.matcher.target(&candidate.points_in_keyframe).ok()?;
        let found = self.matcher.match_scan(
            &target,
            &query.points_in_keyframe,
            guess_candidate_from_query,
            &self.window,
        )?;
        Some(Verification {
            candidate_from_query: found.target_from_query,
            score: found.score,
            covariance: found.covariance,
        })
    }
}
