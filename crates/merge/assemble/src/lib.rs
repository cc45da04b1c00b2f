//! (being written)
//! Assembling many trajectory segments without initial guesses, in any order (Yin et al.,
//! AutoMerge, T-RO 2023): segments → submaps every d metres → viewpoint-invariant descriptors →
//! association (`mapmerge-association`) → geometric verification → confidences and spectral
//! groups → one robust pose graph per group.

pub mod assembly;
pub mod associate;
pub mod descriptor;
mod error;
pub mod optimize;
pub mod segment;
pub mod submap;
pub mod three_d;

pub use assembly::{Arrival, AssembleParams, Assembler};
pub use associate::{
    associate_pair, AssociationParams, PairAssociation, PreparedSegment, SegmentLoop,
    VerificationParams,
};
pub use descriptor::{
    cosine_distance, describe_submaps, DescriptorRows, RingSpectrum3Params, RingSpectrumDescriptor,
    RingSpectrumDescriptor3, RingSpectrumParams, SubmapDescriptor, YawEstimate,
};
pub use error::AssembleError;
pub use optimize::{solve_group, solve_group_without, GroupGraphParams, GroupSolution};
pub use segment::{Point3, Segment, Segment3, SegmentPoints};
pub use submap::{
    build_submaps, submap_centres, voxel_downsample, SegmentSubmap, Submap2, Submap3, SubmapParams,
    SubmapPoint, SubmapsOf,
};
pub use three_d::{
    load_kitti_folder, prepare_3d, project_pose, segment3_from_clouds, GroundSlice,
    KittiFolderOptions,
};
