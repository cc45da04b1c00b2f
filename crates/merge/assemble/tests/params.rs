//! Range checks of the assembly's parameters: the defaults and presets pass, out-of-range
//! values are refused with their path.

use mapmerge_assemble::{
    AssembleError, AssembleParams, Assembler, GroundSlice, KittiFolderOptions, SubmapParams,
};
use mapmerge_params::Validate;

/// `mapmerge-jobs`' `default_params(true)`: the outdoor submaps for 3D segments.
fn outdoor() -> AssembleParams {
    let mut params = AssembleParams::default();
    let submaps = SubmapParams::outdoor();
    params.descriptor.max_radius_m = submaps.radius_m;
    params.submaps = submaps;
    params
}

fn refused_field(params: &AssembleParams) -> String {
    match params.validate() {
        Err(e) => e.field,
        Ok(()) => "accepted".into(),
    }
}

#[test]
fn defaults_and_presets_validate() {
    assert_eq!(AssembleParams::default().validate(), Ok(()));
    assert_eq!(outdoor().validate(), Ok(()));
    assert_eq!(Validate::validate(&SubmapParams::outdoor()), Ok(()));
    assert_eq!(Validate::validate(&GroundSlice::default()), Ok(()));
    assert_eq!(Validate::validate(&KittiFolderOptions::default()), Ok(()));
    // `mapmerge-jobs`' conversion keeps every point this way.
    let every_point = KittiFolderOptions {
        voxel_m: 0.0,
        max_range_m: f64::MAX.sqrt(),
        stride: 1,
    };
    assert_eq!(Validate::validate(&every_point), Ok(()));
    assert!(Assembler::new(outdoor()).is_ok());
}

#[test]
fn out_of_range_values_are_refused_with_their_path() {
    let mut p = AssembleParams::default();
    p.association.sequence.sequence_length = usize::MAX;
    assert_eq!(refused_field(&p), "association.sequence.sequence_length");

    let mut p = AssembleParams::default();
    p.graph.dcs_phi = -1.0;
    assert_eq!(refused_field(&p), "graph.dcs_phi");

    let mut p = AssembleParams::default();
    p.submaps.radius_m = -1.0;
    assert_eq!(refused_field(&p), "submaps.radius_m");

    let mut p = AssembleParams::default();
    p.association.sequence.velocity_min = 2.0;
    assert_eq!(refused_field(&p), "association.sequence.velocity_max");

    let mut p = AssembleParams::default();
    p.association.zones.min_inliers = 2;
    assert_eq!(refused_field(&p), "association.zones.min_inliers");

    let mut p = AssembleParams::default();
    p.association.verification.window_deg = 270.0;
    assert_eq!(refused_field(&p), "association.verification.window_deg");

    let mut p = AssembleParams::default();
    p.grouping.kmeans.max_iterations = usize::MAX;
    assert_eq!(refused_field(&p), "grouping.kmeans.max_iterations");

    let mut p = AssembleParams::default();
    p.max_pair_residual.1 = f64::NAN;
    assert_eq!(refused_field(&p), "max_pair_residual[1]");

    let mut p = AssembleParams::default();
    p.descriptor.ring_count = 0;
    assert_eq!(refused_field(&p), "descriptor.ring_count");
}

#[test]
fn the_assembler_refuses_out_of_range_params() {
    let mut p = AssembleParams::default();
    p.association.sequence.velocity_steps = usize::MAX;
    match Assembler::new(p) {
        Err(AssembleError::InvalidParams(e)) => {
            assert_eq!(e.field, "association.sequence.velocity_steps");
            assert_eq!(e.allowed, "must be in [1, 1000]");
        }
        Err(e) => panic!("wrong error {e}"),
        Ok(_) => panic!("accepted"),
    }
    let slice = GroundSlice {
        min_height_m: 1.0,
        max_height_m: 1.0,
        ..GroundSlice::default()
    };
    match slice.validate() {
        Err(AssembleError::InvalidParams(e)) => assert_eq!(e.field, "max_height_m"),
        other => panic!("{other:?}"),
    }
}
