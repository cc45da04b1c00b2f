//! Range checks of the association parameters.

use mapmerge_association::{
    sequence_matches, spectral_groups, verify_zones, AssociationError, DifferenceMatrix,
    GroupingError, GroupingParams, KMeansParams, SequenceParams, SingleFrameParams, ZoneError,
    ZoneParams,
};
use mapmerge_params::Validate;

#[test]
fn defaults_validate() {
    assert_eq!(Validate::validate(&SequenceParams::default()), Ok(()));
    assert_eq!(Validate::validate(&SingleFrameParams::default()), Ok(()));
    assert_eq!(Validate::validate(&ZoneParams::default()), Ok(()));
    assert_eq!(Validate::validate(&GroupingParams::default()), Ok(()));
    assert_eq!(Validate::validate(&KMeansParams::default()), Ok(()));
}

#[test]
fn the_line_search_is_limited_as_a_whole() {
    let wide = SequenceParams {
        sequence_length: 10_000,
        velocity_steps: 1000,
        ..SequenceParams::default()
    };
    let e = Validate::validate(&wide).unwrap_err();
    assert_eq!(e.field, "velocity_steps");
    let reversed = SequenceParams {
        velocity_min: 1.5,
        ..SequenceParams::default()
    };
    assert_eq!(
        Validate::validate(&reversed).unwrap_err().field,
        "velocity_max"
    );
}

#[test]
fn entry_points_name_the_refused_field() {
    let d = DifferenceMatrix::from_vec(2, 2, vec![0.0; 4]).unwrap();
    let huge = SequenceParams {
        sequence_length: usize::MAX,
        ..SequenceParams::default()
    };
    match sequence_matches(&d, &huge) {
        Err(AssociationError::InvalidParams(e)) => assert_eq!(e.field, "sequence_length"),
        other => panic!("{other:?}"),
    }
    let zones = ZoneParams {
        iterations: usize::MAX,
        ..ZoneParams::default()
    };
    match verify_zones(&[], &[], &[], &zones) {
        Err(ZoneError::InvalidParams(e)) => assert_eq!(e.field, "iterations"),
        other => panic!("{other:?}"),
    }
    let grouping = GroupingParams {
        kmeans: KMeansParams {
            restarts: usize::MAX,
            ..KMeansParams::default()
        },
        ..GroupingParams::default()
    };
    match spectral_groups(&[0.0], grouping) {
        Err(GroupingError::InvalidParams(e)) => assert_eq!(e.field, "kmeans.restarts"),
        other => panic!("{other:?}"),
    }
}
