//! The geometric-verification interface: a scan matcher (written elsewhere) confirms or
//! rejects what the descriptors proposed.

use mapmerge_geometry::Se2;
use nalgebra::Matrix3;

use crate::keyframe::Keyframe;

/// A confirmed alignment of a query keyframe to a candidate keyframe.
#[derive(Clone, Debug, PartialEq)]
pub struct Verification {
    /// Pose of the query keyframe in the candidate keyframe's frame.
    pub candidate_from_query: Se2,
    /// Match quality, higher is better; by convention in `[0, 1]` (e.g. the fraction of query
    /// points explained by the candidate).
    pub score: f64,
    /// Covariance of `candidate_from_query` in the tangent order `(vx, vy, ω)` (m², rad²).
    pub covariance: Matrix3<f64>,
}

/// Aligns two keyframes from an initial guess (a correlative scan matcher, ICP, ...).
/// Implementations must be thread-safe: [`crate::find_loop_candidates`] verifies in parallel.
pub trait GeometricVerifier: Sync {
    /// Aligns `query` to `candidate` starting from `guess_candidate_from_query`; `None` when
    /// no acceptable alignment exists.
    fn verify(
        &self,
        query: &Keyframe,
        candidate: &Keyframe,
        guess_candidate_from_query: &Se2,
    ) -> Option<Verification>;
}

/// A borrowed verifier verifies as its referent does, so `&dyn GeometricVerifier` serves where
/// the place functions take a sized one.
impl<T: GeometricVerifier + ?Sized> GeometricVerifier for &T {
    fn verify(
        &self,
        query: &Keyframe,
        candidate: &Keyframe,
        guess_candidate_from_query: &Se2,
    ) -> Option<Verification> {
        (**self).verify(query, candidate, guess_candidate_from_query)
    }
}
