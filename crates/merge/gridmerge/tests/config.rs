//! The shipped configuration parses and equals the defaults.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_gridmerge::{DecisionTable, ReversibleParams};

#[test]
fn the_shipped_decision_table_is_the_default() {
    let text = include_str!("../config/decision_table.yaml");
    let table: DecisionTable = serde_yaml_ng::from_str(text).unwrap();
    assert_eq!(table, DecisionTable::default());
}

#[test]
fn params_default_every_field_and_refuse_unknown_ones() {
    let params: ReversibleParams = serde_yaml_ng::from_str("mode: single_map\n").unwrap();
    assert_eq!(
        params,
        ReversibleParams {
            mode: mapmerge_gridmerge::ReversibleMode::SingleMap,
            ..ReversibleParams::default()
        }
    );
    let params: ReversibleParams =
        serde_yaml_ng::from_str("fusion:\n  repeat_thresholds: [-0.1, 0.2, 0.4]\n").unwrap();
    assert_eq!(params.fusion.repeat_thresholds, [-0.1, 0.2, 0.4]);
    assert!(serde_yaml_ng::from_str::<ReversibleParams>("check_every: 3\n").is_err());
    assert!(serde_yaml_ng::from_str::<ReversibleParams>("fusion:\n  repeats: 3\n").is_err());
}
