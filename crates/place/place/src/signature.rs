//! The place signature every place search indexes: Scan Context (ring key for the first
//! retrieval list, column shift for the yaw) plus, when configured, the translation-invariant
//! ring spectrum ([`RingSpectrumDescriptor`]) for a second list.
//!
//! Why two lists: Scan Context is egocentric, so a place seen again from a metre or two away
//! falls out of its top k, while the spectrum ignores translation but not clutter. On the
//! tuning logs (`examples/retrieval_study.rs`, scans as keyframes) a true revisit was in Scan
//! Context's top 10 for 70 % of the revisits, in the spectrum's for 80 %, and in the union of
//! both top-5 lists (at most 10 candidates, as many verifications) for 81 %.

use mapmerge_scan::Point2;

use crate::descriptor::{DescriptorExtractor, DescriptorMatch, PlaceDescriptor};
use crate::loops::PlaceParams;
use crate::scan_context::{ScanContext, ScanContextParams};
use crate::submap_descriptor::{RingSpectrumDescriptor, SubmapDescriptor};

/// Scan Context and, optionally, the ring spectrum of one keyframe.
#[derive(Clone, Debug, PartialEq)]
pub struct PlaceSignature {
    context: ScanContext,
    appearance: Box<[f32]>,
}

impl PlaceSignature {
    /// The Scan Context part.
    pub fn context(&self) -> &ScanContext {
        &self.context
    }
}

impl PlaceDescriptor for PlaceSignature {
    fn retrieval_key(&self) -> &[f32] {
        self.context.retrieval_key()
    }

    fn compare(&self, candidate: &Self) -> DescriptorMatch {
        self.context.compare(&candidate.context)
    }

    fn appearance(&self) -> &[f32] {
        &self.appearance
    }
}

/// Builds [`PlaceSignature`]s from a [`PlaceParams`] (`descriptor`, `appearance`). Building one
/// plans the spectrum's FFTs: keep it.
#[derive(Clone, Debug)]
pub struct SignatureExtractor {
    context: ScanContextParams,
    appearance: Option<RingSpectrumDescriptor>,
}

impl SignatureExtractor {
    /// The extractor of `params`.
    pub fn new(params: &PlaceParams) -> Self {
        Self {
            context: params.descriptor.clone(),
            appearance: params.appearance.as_ref().map(RingSpectrumDescriptor::new),
        }
    }
}

impl DescriptorExtractor for SignatureExtractor {
    type Descriptor = PlaceSignature;

    fn describe(&self, points_in_keyframe: &[Point2]) -> PlaceSignature {
        PlaceSignature {
            context: ScanContext::new(points_in_keyframe, &self.context),
            appearance: self
                .appearance
                .as_ref()
                .map(|a| a.describe(points_in_keyframe).into_boxed_slice())
                .unwrap_or_default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::submap_descriptor::RingSpectrumParams;

    #[test]
    fn without_appearance_it_is_scan_context() {
        let points = [Point2::new(2.0, 0.5), Point2::new(-1.0, 3.0)];
        let params = PlaceParams::default();
        let signature = SignatureExtractor::new(&params).describe(&points);
        assert!(signature.appearance().is_empty());
        assert_eq!(
            signature.context(),
            &ScanContext::new(&points, &params.descriptor)
        );
        let with = SignatureExtractor::new(&PlaceParams {
            appearance: Some(RingSpectrumParams::default()),
            ..PlaceParams::default()
        })
        .describe(&points);
        assert_eq!(
            with.appearance().len(),
            RingSpectrumDescriptor::default().dim()
        );
    }
}
