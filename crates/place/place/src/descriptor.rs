//! The interface every place descriptor implements, so that Scan Context can be swapped for
//! another (e.g. a learned) descriptor without touching the index or the loop search.

use mapmerge_geometry::Se2;
use mapmerge_scan::{transform_points, Point2};

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

/// `points_in_keyframe` as seen from `offset_m` to the keyframe's left (negative: right),
/// with the same heading: the query a polar descriptor would get from a viewpoint beside the
/// robot (Kim et al., "Scan Context++", T-RO 2021, Sec. IV-B, lateral augmentation;
/// occlusion is not modelled). Non-finite points stay non-finite.
pub fn seen_from_beside(points_in_keyframe: &[Point2], offset_m: f64) -> Vec<Point2> {
    let viewpoint_from_keyframe = Se2::new(0.0, -offset_m, 0.0);
    transform_points(&viewpoint_from_keyframe, points_in_keyframe)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use mapmerge_sim::{LineSegment, RayCaster};

    use crate::{PlaceParams, SignatureExtractor};

    /// A 360° scan (1° beams, up to 20 m) from `(x, y)` with heading 0 among `walls`.
    fn scan(walls: &RayCaster, x: f64, y: f64) -> Vec<Point2> {
        (0..360)
            .filter_map(|i| {
                let angle_rad = f64::from(i).to_radians();
                let range_m = walls.cast(&Point2::new(x, y), angle_rad, 20.0)?;
                Some(Point2::new(angle_rad.cos(), angle_rad.sin()) * range_m)
            })
            .collect()
    }

    /// A robot 0.8 m to the left of an earlier keyframe in a corridor with side rooms: its
    /// scan described as seen from 0.8 m to its right matches the keyframe better than its
    /// own view does, and better than the view from the wrong side.
    #[test]
    fn a_view_from_beside_matches_a_keyframe_taken_there() {
        let p = Point2::new;
        let wall_ends = [
            (p(-10.0, -1.5), p(2.0, -1.5)),
            (p(2.0, -1.5), p(2.0, -5.0)),
            (p(2.0, -5.0), p(5.0, -5.0)),
            (p(5.0, -5.0), p(5.0, -1.5)),
            (p(5.0, -1.5), p(15.0, -1.5)),
            (p(-10.0, 1.5), p(-3.0, 1.5)),
            (p(-3.0, 1.5), p(-3.0, 4.0)),
            (p(-3.0, 4.0), p(0.5, 4.0)),
            (p(0.5, 4.0), p(0.5, 1.5)),
            (p(0.5, 1.5), p(15.0, 1.5)),
            (p(15.0, 1.5), p(15.0, -1.5)),
        ];
        let segments: Vec<LineSegment> = wall_ends
            .iter()
            .map(|(a, b)| LineSegment::new(*a, *b))
            .collect();
        let walls = RayCaster::from_segments(&segments, 1.0);
        let extractor = SignatureExtractor::new(&PlaceParams::default());
        let keyframe = extractor.describe(&scan(&walls, 1.0, -0.4));
        let beside = scan(&walls, 1.0, 0.4);
        let distance = |offset_m: f64| {
            extractor
                .describe(&seen_from_beside(&beside, offset_m))
                .compare(&keyframe)
                .distance
        };
        let (own, right, left) = (distance(0.0), distance(-0.8), distance(0.8));
        assert!(
            right < own && right < left,
            "right {right}, own {own}, left {left}"
        );
        assert!(seen_from_beside(&[p(f64::NAN, 1.0)], 1.0)[0].x.is_nan());
    }
}
