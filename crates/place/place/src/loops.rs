//! Loop candidates between two keyframe sets: describe, index B, query every keyframe of A,
//! verify the best candidates geometrically, and say how unambiguous each match is.

use std::borrow::Cow;
use std::collections::HashMap;

use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_params::{Checker, Real, Validate};
use nalgebra::Matrix3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::descriptor::DescriptorExtractor;
use crate::index::{Candidate, IndexParams, PlaceIndex};
use crate::keyframe::{Keyframe, KeyframeId};
use crate::scan_context::ScanContextParams;
use crate::signature::SignatureExtractor;
use crate::submap_descriptor::RingSpectrumParams;
use crate::verify::{GeometricVerifier, Verification};

/// Parameters of [`find_loop_candidates`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlaceParams {
    /// The descriptor (default: [`ScanContextParams::default`]).
    pub descriptor: ScanContextParams,
    /// The index (default: [`IndexParams::default`]).
    pub index: IndexParams,
    /// How many of the best-ranked candidates of each query are verified (default: 5). More
    /// finds places the descriptor ranked lower and sharpens the confidence, at one
    /// verification each.
    pub candidates_per_query: usize,
    /// Candidates whose descriptor distance exceeds this are not verified (default: 0.6;
    /// Scan Context distances lie in `[0, 1]`). Lower saves verifications but misses places
    /// seen from further away.
    pub max_descriptor_distance: f64,
    /// The ring spectrum that gives a second retrieval list (default: none, Scan Context
    /// alone). With it, [`crate::PlaceIndex`] returns the `candidates_per_query` best of each
    /// list.
    pub appearance: Option<RingSpectrumParams>,
    /// Candidates of the second list whose cosine distance exceeds this are not verified
    /// unless their Scan Context distance passes `max_descriptor_distance` (default: 1, the
    /// distance of uncorrelated spectra).
    pub max_appearance_distance: f64,
    /// A verification is accepted when its score reaches this (default: 0.5, in the
    /// verifier's units).
    pub min_score: f64,
    /// Without poses of B ([`find_loop_candidates`]): two candidates are the same place when
    /// their positions in `keyframes_b` differ by at most this many keyframes (default: 10):
    /// consecutive keyframes see the same place, so they must not count as rivals when the
    /// confidence is computed.
    pub distinct_index_gap: usize,
    /// With poses of B ([`find_loop_candidates_with_poses`]): two candidates are the same
    /// place when the positions of `a` they imply in B's map are within this distance (m)
    /// (default: 1.0).
    pub same_place_m: f64,
    /// See `same_place_m`: and their headings within this angle (rad) (default: 0.35, 20°).
    pub same_place_rad: f64,
}

impl Default for PlaceParams {
    fn default() -> Self {
        Self {
            descriptor: ScanContextParams::default(),
            index: IndexParams::default(),
            candidates_per_query: 5,
            max_descriptor_distance: 0.6,
            appearance: None,
            max_appearance_distance: 1.0,
            min_score: 0.5,
            distinct_index_gap: 10,
            same_place_m: 1.0,
            same_place_rad: 0.35,
        }
    }
}

/// An accepted match: keyframe `a` of the first set seen again as keyframe `b` of the second.
#[derive(Clone, Debug, PartialEq)]
pub struct VerifiedLoop {
    /// The query keyframe (from `keyframes_a`).
    pub a: KeyframeId,
    /// The matched keyframe (from `keyframes_b`).
    pub b: KeyframeId,
    /// Pose of `a` in `b`'s frame, from the verifier.
    pub b_from_a: Se2,
    /// The verifier's score.
    pub score: f64,
    /// How unambiguous the match is, in `[0, 1]`: `(s₁ − s₂) / s₁` with `s₁` the best score and
    /// `s₂` the best verified score of a candidate showing a *distinct* place (see
    /// [`find_loop_candidates_with_poses`]), 0 when there is none. Look-alike places (identical rooms) verify
    /// nearly as well as the true one and get a confidence near 0.
    pub confidence: f64,
    /// Covariance of `b_from_a`, from the verifier.
    pub covariance: Matrix3<f64>,
}

/// Loop candidates between two keyframe sets described as `params` says (Scan Context with
/// `params.descriptor`, and the ring spectrum's second list with `params.appearance`): at
/// most one [`VerifiedLoop`] per keyframe of `keyframes_a`, in the
/// order of `keyframes_a`. The rotation guess handed to the verifier is the descriptor's yaw
/// with zero translation.
pub fn find_loop_candidates(
    keyframes_a: &[Keyframe],
    keyframes_b: &[Keyframe],
    verifier: &impl GeometricVerifier,
    params: &PlaceParams,
) -> Vec<VerifiedLoop> {
    search(
        &SignatureExtractor::new(params),
        keyframes_a,
        keyframes_b,
        None,
        verifier,
        params,
    )
}

/// As [`find_loop_candidates`], with the poses of `keyframes_b` in their session's map
/// (`map_from_b[i]` for `keyframes_b[i]`, e.g. from B's optimised pose graph). Two candidates
/// are then the same place when the poses of `a` they imply in B's map agree within
/// `params.same_place_m` and `params.same_place_rad`, which also holds for places B visited
/// several times; without poses ([`find_loop_candidates`]) only keyframes close in B's order
/// count as the same place, so a place B revisited lowers the confidence. A `map_from_b`
/// shorter than `keyframes_b` falls back to the index gap for the keyframes without a pose.
pub fn find_loop_candidates_with_poses(
    keyframes_a: &[Keyframe],
    keyframes_b: &[Keyframe],
    map_from_b: &[Se2],
    verifier: &impl GeometricVerifier,
    params: &PlaceParams,
) -> Vec<VerifiedLoop> {
    search(
        &SignatureExtractor::new(params),
        keyframes_a,
        keyframes_b,
        Some(map_from_b),
        verifier,
        params,
    )
}

/// As [`find_loop_candidates`] with any descriptor (`params.descriptor` is then unused).
/// Queries run in parallel (rayon); the output does not depend on the number of threads.
pub fn find_loop_candidates_with<E: DescriptorExtractor>(
    extractor: &E,
    keyframes_a: &[Keyframe],
    keyframes_b: &[Keyframe],
    verifier: &impl GeometricVerifier,
    params: &PlaceParams,
) -> Vec<VerifiedLoop> {
    search(extractor, keyframes_a, keyframes_b, None, verifier, params)
}

/// A retrieved place to verify: keyframe `keyframe` of B (its position `ordinal` in B), the
/// descriptor's yaw guess of the query in its frame, and its pose in B's map when known.
#[derive(Clone, Copy, Debug)]
pub struct PlaceCandidate<'a> {
    /// Position of the keyframe in B (consecutive keyframes see the same place).
    pub ordinal: usize,
    /// The candidate keyframe.
    pub keyframe: &'a Keyframe,
    /// The descriptor's estimate of the query's yaw in the candidate's frame (rad).
    pub yaw_rad: f64,
    /// The candidate's pose in B's map, when known.
    pub map_from_keyframe: Option<Se2>,
}

impl PlaceParams {
    /// Whether a retrieved candidate is close enough in either list to be verified.
    pub fn admits(&self, candidate: &Candidate) -> bool {
        candidate.descriptor_distance <= self.max_descriptor_distance
            || candidate.appearance_distance <= self.max_appearance_distance
    }

    /// The default same-place rule of [`verify_candidates`]: verified candidates `x` and `y`
    /// show the same place of B when the poses of the query they imply in B's map agree
    /// within `same_place_m` and `same_place_rad` (both with `map_from_keyframe`), else when
    /// their ordinals differ by at most `distinct_index_gap`.
    pub fn same_place(
        &self,
        x: (&PlaceCandidate, &Verification),
        y: (&PlaceCandidate, &Verification),
    ) -> bool {
        match (x.0.map_from_keyframe, y.0.map_from_keyframe) {
            (Some(map_from_x), Some(map_from_y)) => {
                // Where each candidate puts `a` in B's map.
                let a_via_x = map_from_x.compose(&x.1.candidate_from_query);
                let a_via_y = map_from_y.compose(&y.1.candidate_from_query);
                (a_via_x.translation() - a_via_y.translation()).norm() <= self.same_place_m
                    && wrap_angle_rad(a_via_x.theta_rad - a_via_y.theta_rad).abs()
                        <= self.same_place_rad
            }
            _ => x.0.ordinal.abs_diff(y.0.ordinal) <= self.distinct_index_gap,
        }
    }
}

/// Verifies the retrieved `candidates` of `query` (those [`PlaceParams::admits`] should be
/// passed; the guess is the descriptor's yaw with
/// zero translation) and accepts the best when its score reaches `params.min_score`, with a
/// confidence against the best rival showing a distinct place (see [`VerifiedLoop`]). The
/// step shared by [`find_loop_candidates`] and incremental SLAM, which keeps its own index.
pub fn verify_candidates(
    query: &Keyframe,
    candidates: &[PlaceCandidate],
    verifier: &impl GeometricVerifier,
    params: &PlaceParams,
) -> Option<VerifiedLoop> {
    verify_candidates_by(query, candidates, verifier, params, |x, y| {
        params.same_place(x, y)
    })
}

/// As [`verify_candidates`], with the caller's rule for when two verified candidates show the
/// same place (and so are no rivals): e.g. candidates already joined by accepted loops, which
/// a search without poses cannot know from `map_from_keyframe`.
pub fn verify_candidates_by(
    query: &Keyframe,
    candidates: &[PlaceCandidate],
    verifier: &impl GeometricVerifier,
    params: &PlaceParams,
    same_place: impl Fn((&PlaceCandidate, &Verification), (&PlaceCandidate, &Verification)) -> bool,
) -> Option<VerifiedLoop> {
    let verified: Vec<(&PlaceCandidate, Verification)> = candidates
        .iter()
        .filter_map(|c| {
            let guess = Se2::new(0.0, 0.0, c.yaw_rad);
            let v = verifier.verify(query, c.keyframe, &guess)?;
            v.score.is_finite().then_some((c, v))
        })
        .collect();
    accept_verified(query, &verified, params, same_place)
}

/// The acceptance step of [`verify_candidates_by`] for candidates the caller verified itself
/// (pairs with a finite score): the best when it reaches `params.min_score`, with its
/// confidence against the best rival that `same_place` says shows another place.
pub fn accept_verified(
    query: &Keyframe,
    verified: &[(&PlaceCandidate, Verification)],
    params: &PlaceParams,
    same_place: impl Fn((&PlaceCandidate, &Verification), (&PlaceCandidate, &Verification)) -> bool,
) -> Option<VerifiedLoop> {
    let (best_candidate, best) = verified.iter().max_by(|x, y| {
        x.1.score
            .total_cmp(&y.1.score)
            .then(y.0.ordinal.cmp(&x.0.ordinal))
    })?;
    if best.score < params.min_score {
        return None;
    }
    let rival = verified
        .iter()
        .filter(|(c, v)| !same_place((best_candidate, best), (c, v)))
        .map(|(_, v)| v.score.max(0.0))
        .fold(0.0f64, f64::max);
    let confidence = if best.score > 0.0 {
        ((best.score - rival) / best.score).clamp(0.0, 1.0)
    } else {
        0.0
    };
    Some(VerifiedLoop {
        a: query.id,
        b: best_candidate.keyframe.id,
        b_from_a: best.candidate_from_query,
        score: best.score,
        confidence,
        covariance: best.covariance,
    })
}

/// The loop search shared by the public entry points.
fn search<E: DescriptorExtractor>(
    extractor: &E,
    keyframes_a: &[Keyframe],
    keyframes_b: &[Keyframe],
    map_from_b: Option<&[Se2]>,
    verifier: &impl GeometricVerifier,
    params: &PlaceParams,
) -> Vec<VerifiedLoop> {
    PlaceDatabase::new(
        extractor,
        Cow::Borrowed(keyframes_b),
        map_from_b.map(Cow::Borrowed),
        params,
    )
    .search(extractor, keyframes_a, verifier, params)
}

/// Keyframe set B described and indexed once, to be searched by many query sets (e.g. an
/// inactive map that every new keyframe of a live robot is looked up in): what
/// [`find_loop_candidates_with_poses`] builds on each call.
/// It borrows the keyframes for a one-off search and owns them when kept (`'static`).
pub struct PlaceDatabase<'k, D: crate::descriptor::PlaceDescriptor = crate::PlaceSignature> {
    keyframes: Cow<'k, [Keyframe]>,
    map_from_keyframe: Option<Cow<'k, [Se2]>>,
    index: PlaceIndex<D>,
    ordinal_of: HashMap<KeyframeId, usize>,
}

impl<'k, D: crate::descriptor::PlaceDescriptor> PlaceDatabase<'k, D> {
    /// Describes and indexes `keyframes` (with their poses in B's map when known, see
    /// [`find_loop_candidates_with_poses`]).
    pub fn new<E: DescriptorExtractor<Descriptor = D>>(
        extractor: &E,
        keyframes: Cow<'k, [Keyframe]>,
        map_from_keyframe: Option<Cow<'k, [Se2]>>,
        params: &PlaceParams,
    ) -> Self {
        let descriptors: Vec<D> = keyframes
            .par_iter()
            .map(|k| extractor.describe(&k.points_in_keyframe))
            .collect();
        let mut index: PlaceIndex<D> = PlaceIndex::new(params.index.clone());
        for (keyframe, descriptor) in keyframes.iter().zip(descriptors) {
            index.insert(keyframe.id, descriptor);
        }
        let mut ordinal_of: HashMap<KeyframeId, usize> = HashMap::with_capacity(keyframes.len());
        for (ordinal, keyframe) in keyframes.iter().enumerate() {
            ordinal_of.entry(keyframe.id).or_insert(ordinal);
        }
        Self {
            keyframes,
            map_from_keyframe,
            index,
            ordinal_of,
        }
    }

    /// The indexed keyframes.
    pub fn keyframes(&self) -> &[Keyframe] {
        &self.keyframes
    }

    /// Queries every keyframe of `keyframes_a`, verifies its best candidates and accepts the
    /// best by score, rated against distinct rivals: at most one [`VerifiedLoop`] per query,
    /// in query order. Queries run in parallel; the output does not depend on the threads.
    pub fn search<E: DescriptorExtractor<Descriptor = D>>(
        &self,
        extractor: &E,
        keyframes_a: &[Keyframe],
        verifier: &impl GeometricVerifier,
        params: &PlaceParams,
    ) -> Vec<VerifiedLoop> {
        keyframes_a
            .par_iter()
            .filter_map(|query| {
                let descriptor = extractor.describe(&query.points_in_keyframe);
                let candidates: Vec<PlaceCandidate> = self
                    .index
                    .query(&descriptor, params.candidates_per_query)
                    .iter()
                    .filter(|c| params.admits(c))
                    .filter_map(|c| {
                        let ordinal = *self.ordinal_of.get(&c.keyframe)?;
                        Some(PlaceCandidate {
                            ordinal,
                            keyframe: self.keyframes.get(ordinal)?,
                            yaw_rad: c.yaw_rad,
                            map_from_keyframe: self
                                .map_from_keyframe
                                .as_ref()
                                .and_then(|m| m.get(ordinal).copied()),
                        })
                    })
                    .collect();
                verify_candidates(query, &candidates, verifier, params)
            })
            .collect()
    }
}

impl Validate for PlaceParams {
    fn check(&self, check: &mut Checker) {
        check
            .nested("descriptor", &self.descriptor)
            .nested("index", &self.index)
            .size("candidates_per_query", self.candidates_per_query, 1, 1000)
            .real(
                "max_descriptor_distance",
                self.max_descriptor_distance,
                Real::fraction(),
            )
            .nested_opt("appearance", self.appearance.as_ref())
            .real(
                "max_appearance_distance",
                self.max_appearance_distance,
                Real::within(0.0, 2.0),
            )
            .real("min_score", self.min_score, Real::fraction())
            .size("distinct_index_gap", self.distinct_index_gap, 0, 1_000_000)
            .real("same_place_m", self.same_place_m, Real::non_negative())
            .real(
                "same_place_rad",
                self.same_place_rad,
                Real::within(0.0, std::f64::consts::PI),
            );
    }
}
