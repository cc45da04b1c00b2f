//! Submap descriptors for association: the descriptors themselves are `mapmerge-place`'s
//! ([`mapmerge_place::submap_descriptor`], shared with every other place search); this module
//! describes an assembly's submaps with them.

use rayon::prelude::*;

pub use mapmerge_place::submap_descriptor::{
    cosine_distance, DescriptorRows, RingSpectrum3Params, RingSpectrumDescriptor,
    RingSpectrumDescriptor3, RingSpectrumParams, SubmapDescriptor, YawEstimate,
};

use crate::submap::SegmentSubmap;

/// Describes every submap, in parallel; rows are in submap order.
pub fn describe_submaps<D: SubmapDescriptor, G: Sync>(
    descriptor: &D,
    submaps: &[SegmentSubmap<D::Point, G>],
) -> DescriptorRows
where
    D::Point: Sync,
{
    let dim = descriptor.dim();
    let mut values = vec![0.0f32; dim * submaps.len()];
    if dim > 0 {
        values
            .par_chunks_mut(dim)
            .zip(submaps.par_iter())
            .for_each(|(row, submap)| descriptor.describe_into(&submap.points_in_centre, row));
    }
    DescriptorRows { dim, values }
}
