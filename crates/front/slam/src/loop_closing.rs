//! Loop closing: where to search and what to accept. Local loop closures search the finished
//! submaps near the current estimate within a window that grows with the distance travelled
//! since the last loop (the estimate's uncertainty); global ones come from place recognition
//! (`mapmerge-place`) when the robot has been without a loop for a while.

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_place::{GeometricVerifier, Keyframe, KeyframeId, PlaceParams, Verification};
use mapmerge_scanmatch::{ScanMatcher, SearchWindow};
use serde::{Deserialize, Serialize};

use crate::submap::Submap;

/// Parameters of loop closing, one default for every log.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LoopClosureParams {
    /// Search for loops at all (default: true).
    pub enabled: bool,
    /// A loop match is accepted when its score reaches this (default: 0.6).
    pub min_score: f64,
    /// Finished submaps with a keyframe within this distance (m) of the current estimate
    /// are searched (default: 5).
    pub max_distance_m: f64,
    /// At most this many nearby submaps are searched per keyframe, nearest first (default: 2).
    pub max_submaps_per_keyframe: usize,
    /// Translation half-width of the local search: `min + per_m · d`, not searched beyond `max`, with
    /// `d` the path since the submap or since the last long loop, whichever is shorter (m)
    /// (default: 0.5, 0.05, 7).
    pub window_linear: (f64, f64, f64),
    /// Heading half-width the same way (rad), clamped at `max` (default: 10°, 0.5°/m, 45°).
    pub window_angular: (f64, f64, f64),
    /// While that `d` is below this (m), ICP from the estimate is tried first and kept
    /// under the odometry's [`crate::RefineFirst`] rule (default: 5).
    pub refine_below_drift_m: f64,
    /// Place recognition runs once the robot travelled this far (m) without a long loop
    /// (default: 5) and the local search found nothing.
    pub place_after_m: f64,
    /// A loop whose ends are this far apart along the path (m) bounds the drift from then
    /// on (default: 30); shorter ones (to the submap just finished) do not reset it.
    pub long_loop_span_m: f64,
    /// Place recognition's retrieval and acceptance (default: 3 candidates within
    /// descriptor distance 0.4, score ≥ 0.65).
    pub place: PlaceParams,
    /// A place-recognition loop also needs this confidence (the gap to the best rival place,
    /// see `mapmerge_place::VerifiedLoop`) (default: 0.1): look-alike places are refused.
    pub place_min_confidence: f64,
    /// Window of the verification around the descriptor's guess (default: ±2 m, ±20°).
    pub place_window: SearchWindow,
    /// A place-recognition loop may move the keyframe's estimate by at most
    /// `a + b·d` (m) and `c + e·d` (rad), `d` the path since the candidate keyframe or since
    /// the last long loop, whichever is shorter (m)
    /// (default: 1 m + 10 %, 5° + 0.1°/m): Mahalanobis-style gating by the drift a
    /// scan-matching front-end accumulates, which refuses look-alike places far away.
    pub place_gate: (f64, f64, f64, f64),
    /// The graph is optimised after a loop when at least this many keyframes passed since
    /// the last optimisation (default: 10), and once at the end.
    pub optimize_every_keyframes: usize,
    /// A loop that corrects the keyframe's estimate by more than this (m, rad) needs a
    /// second loop implying the same correction (default: 0.3 m, 3°) ...
    pub confirm_above: (f64, f64),
    /// ... within this many keyframes (default: 5) ...
    pub confirm_within_keyframes: usize,
    /// ... agreeing within this (m, rad) (default: 0.3 m, 2°).
    pub confirm_agreement: (f64, f64),
    /// Smallest standard deviations of a loop edge (m, rad) (default: 10 cm, 2°). Loop edges
    /// come in dozens per revisit and each leans on a rigid submap whose shape carries the
    /// front-end's drift at building time; floored this loosely they close loops without
    /// bending the graph (simulated office ATE 10.6 → 4.4 cm, infinite corridor 5.0 → 0.96 m).
    pub min_edge_sigma: (f64, f64),
}

impl Default for LoopClosureParams {
    fn default() -> Self {
        let place = PlaceParams {
            candidates_per_query: 3,
            max_descriptor_distance: 0.4,
            min_score: 0.65,
            ..PlaceParams::default()
        };
        Self {
            enabled: true,
            min_score: 0.6,
            max_distance_m: 5.0,
            max_submaps_per_keyframe: 2,
            window_linear: (0.5, 0.05, 7.0),
            window_angular: (10f64.to_radians(), 0.5f64.to_radians(), 45f64.to_radians()),
            refine_below_drift_m: 5.0,
            place_after_m: 5.0,
            long_loop_span_m: 30.0,
            place,
            place_min_confidence: 0.1,
            place_window: SearchWindow::new(2.0, 20f64.to_radians()),
            place_gate: (1.0, 0.1, 5f64.to_radians(), 0.1f64.to_radians()),
            optimize_every_keyframes: 10,
            confirm_above: (0.3, 3f64.to_radians()),
            confirm_within_keyframes: 5,
            confirm_agreement: (0.3, 2f64.to_radians()),
            min_edge_sigma: (0.1, 2f64.to_radians()),
        }
    }
}

impl LoopClosureParams {
    /// The local search window after travelling `distance_m` without a loop; `None` once
    /// the drift may exceed the largest window, where a search would find only look-alikes
    /// of the place (place recognition, gated by the drift, takes over).
    pub fn local_window(&self, distance_m: f64) -> Option<SearchWindow> {
        let grow = |(min, per_m, _): (f64, f64, f64)| min + per_m * distance_m.max(0.0);
        let linear_m = grow(self.window_linear);
        (linear_m <= self.window_linear.2).then(|| {
            SearchWindow::new(
                linear_m,
                grow(self.window_angular).min(self.window_angular.2),
            )
        })
    }
}

/// Verifies a place-recognition candidate keyframe against the submap it belongs to (a
/// richer target than its single scan).
pub(crate) struct SubmapVerifier<'a> {
    pub matcher: &'a ScanMatcher,
    pub submaps: &'a [Submap],
    /// For a candidate keyframe: its submap and its pose in it.
    pub locate: &'a (dyn Fn(KeyframeId) -> Option<(usize, Se2)> + Sync),
    pub window: SearchWindow,
}

impl GeometricVerifier for SubmapVerifier<'_> {
    fn verify(
        &self,
        query: &Keyframe,
        candidate: &Keyframe,
        guess_candidate_from_query: &Se2,
    ) -> Option<Verification> {
        let (submap, submap_from_candidate) = (self.locate)(candidate.id)?;
        let target = self.submaps.get(submap)?.target();
        let guess = submap_from_candidate.compose(guess_candidate_from_query);
        let found =
            self.matcher
                .match_scan(target, &query.points_in_keyframe, &guess, &self.window)?;
        Some(Verification {
            candidate_from_query: submap_from_candidate.between(&found.target_from_query),
            score: found.score,
            covariance: found.covariance,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn local_window_grows_with_drift_and_stops_beyond_its_largest() {
        let params = LoopClosureParams::default();
        let (min_m, per_m, max_m) = params.window_linear;
        let near = params.local_window(0.0).map(|w| w.linear_m);
        assert_eq!(near, Some(min_m));
        let far = params.local_window(50.0).map(|w| w.linear_m);
        assert_eq!(far, Some(min_m + per_m * 50.0));
        assert!(params.local_window((max_m - min_m) / per_m + 1.0).is_none());
        // The heading window is clamped, not a reason to stop.
        let window = params.local_window(100.0).map(|w| w.angular_rad);
        assert_eq!(window, Some(params.window_angular.2));
    }
}
