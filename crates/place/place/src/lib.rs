//! Place recognition for 2D laser keyframes: say where a keyframe was seen before, without an
//! initial guess, so that sessions and robots can be merged.
//!
//! Entry points:
//! - [`ScanContext`] (built with [`ScanContextParams`]): a rotation-invariant polar
//!   descriptor in the spirit of Scan Context (Kim & Kim, IROS 2018), with a ring key for
//!   retrieval and a column-shift distance that also estimates the yaw. Other descriptors
//!   plug in through [`PlaceDescriptor`] and [`DescriptorExtractor`].
//! - [`PlaceIndex`]: tens of thousands of keyframes in a k-d tree over ring keys;
//!   [`PlaceIndex::query`] returns [`Candidate`]s ranked by the full descriptor distance.
//! - [`find_loop_candidates`]: indexes one keyframe set, queries every keyframe of another,
//!   verifies the best candidates with a [`GeometricVerifier`] (a scan matcher) and returns
//!   [`VerifiedLoop`]s with a confidence that is low for look-alike places;
//!   [`find_loop_candidates_with_poses`] does the same when B's poses are known, which lets
//!   places B visited several times count as one place.
//! - [`PlaceDatabase`]: one keyframe set described and indexed once, searched by many query
//!   sets (what the two functions above build on each call).
//! - [`verify_candidates`] (and [`verify_candidates_by`] with the caller's same-place rule):
//!   the per-query step for a caller that keeps its own index, e.g. a SLAM front-end.
//! - [`PlaceSignature`] (built by [`SignatureExtractor`] from [`PlaceParams`]): what every
//!   place search indexes, Scan Context plus, when `PlaceParams::appearance` is set, the ring
//!   spectrum for a second retrieval list that [`PlaceIndex`] fuses with the first.
//! - [`RingSpectrumDescriptor`] (and its 3D sibling in [`submap_descriptor`]): a
//!   translation- and rotation-invariant submap descriptor behind [`SubmapDescriptor`],
//!   compared by cosine distance.
//! - [`ScanMatchVerifier`]: the production verifier; [`ScanMatchVerifier::with_evidence`]
//!   scores alignments by their [`Evidence`], which is what searches without a pose prior need
//!   (`examples/place_benchmark.rs` measures precision and recall on the public logs).
//!
//! ```
//! use mapmerge_place::{KeyframeId, PlaceDescriptor, PlaceIndex, ScanContext, ScanContextParams};
//! use mapmerge_scan::Point2;
//! // An L-shaped corner seen from the origin, and the same corner after the robot turned.
//! let corner: Vec<Point2> = (0..100)
//!     .flat_map(|i| {
//!         let t = f64::from(i) * 0.05;
//!         [Point2::new(t - 1.0, 2.0), Point2::new(3.0, t - 2.0)]
//!     })
//!     .collect();
//! let turned: Vec<Point2> = corner
//!     .iter()
//!     .map(|p| nalgebra::Rotation2::new(-0.5) * p)
//!     .collect();
//! let params = ScanContextParams::default();
//! let mut index = PlaceIndex::default();
//! index.insert(KeyframeId(7), ScanContext::new(&corner, &params));
//! index.insert(KeyframeId(8), ScanContext::new(&[Point2::new(1.0, 0.0)], &params));
//! let found = index.query(&ScanContext::new(&turned, &params), 1);
//! assert_eq!(found[0].keyframe, KeyframeId(7));
//! assert!((found[0].yaw_rad - 0.5).abs() < 0.1); // the turn, within one 6° sector
//! ```

#![warn(missing_docs)]

mod descriptor;
mod evidence;
mod index;
mod keyframe;
mod loops;
mod scan_context;
mod scan_match_verifier;
mod self_similarity;
mod signature;
pub mod submap_descriptor;
mod verify;

pub use descriptor::{seen_from_beside, DescriptorExtractor, DescriptorMatch, PlaceDescriptor};
pub use evidence::{disagreement_ratio, evidence, Evidence, EvidenceParams};
pub use index::{Candidate, IndexParams, PlaceIndex};
pub use keyframe::{Keyframe, KeyframeId};
pub use loops::{
    accept_verified, find_loop_candidates, find_loop_candidates_with,
    find_loop_candidates_with_poses, verify_candidates, verify_candidates_by, PlaceCandidate,
    PlaceDatabase, PlaceParams, VerifiedLoop,
};
/// The free space a [`Keyframe`] may carry (re-exported: it is part of the keyframe).
pub use mapmerge_grid::FreeSpace;
pub use scan_context::{ScanContext, ScanContextParams};
pub use scan_match_verifier::{PlaceVerifierParams, ScanMatchVerifier};
pub use self_similarity::{SelfSimilarity, SelfSimilarityParams};
pub use signature::{PlaceSignature, SignatureExtractor};
pub use submap_descriptor::{
    cosine_distance, DescriptorRows, RingSpectrumDescriptor, RingSpectrumParams, SubmapDescriptor,
    YawEstimate,
};
pub use verify::{GeometricVerifier, Verification};
