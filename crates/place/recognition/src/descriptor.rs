//! The interface every place descriptor implements, so that Scan Context can be swapped for
//! another (e.g. a learned) descriptor without touching the index or the loop search.

use mapmerge_scan::Point2;

/// How well two descriptors match and at which relative heading.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DescriptorMatch {
    /// Dissimilarity, 0 for identical places; Scan Context's lies in `[0, 1]`.
    pub distance: f64,
    /// Estimated heading of the query in the candidate's frame (rad, in `(−π, π]`): the
    /// rotation part of `candidate_from_query`.
    pub yaw_rad: f64,
}

/// A global, rotation-invariant description of a place.
pub trait PlaceDescriptor: Send + Sync {
    /// The retrieval key: a short vector, invariant to the keyframe's heading, whose Euclidean
    /// distance ranks candidates before the full comparison (Scan Context's ring key).
    fn retrieval_key(&self) -> &[f32];

    /// Full comparison of `self` (the query) against `candidate`, with the yaw estimate.
    fn compare(&self, candidate: &Self) -> DescriptorMatch;

    /// A second, translation-invariant description of the place for a second retrieval list
    /// ([`crate::PlaceIndex`] fuses both): a unit vector compared by cosine distance, or
    /// empty when the descriptor has none (the default).
    fn appearance(&self) -> &[f32] {
        &[]
    }
}

/// Builds descriptors from keyframe points (the extractor holds the descriptor's parameters).
pub trait DescriptorExtractor: Send + Sync {
    /// The descriptor it builds.
    type Descriptor: PlaceDescriptor;

    /// Describes the place seen by `points_in_keyframe` (keyframe frame, m). Must accept any
    /// input: empty sets and non-finite points give a valid (possibly empty) descriptor.
    fn describe(&self, points_in_keyframe: &[Point2]) -> Self::Descriptor;
}
