//! Matching crops of real building maps with known transforms (skipped without the data
//! folder, except under CI=true).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_gridmatch::{match_grids, GridMatchParams};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

mod common;
use common::crops;

fn check_map(folder_file: &str, side_m: f64, pairs: usize, seed: u64) {
    let Some(path) = mapmerge_testkit::shared_data(folder_file) else {
        return;
    };
    let map = crops::read_map(&path).expect("readable map");
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let params = GridMatchParams::default();
    let (mut right, mut total) = (0, 0);
    for _ in 0..pairs {
        let pair = crops::crop_pair(&map, &mut rng, side_m, 0.3, 0.7, 2.0).expect("a crop pair");
        let result = match_grids(&pair.a, &pair.b, &params).unwrap();
        let best = &result.hypotheses[0];
        let (cells, rad) =
            crops::error(&pair.b, &pair.a_from_b, &best.a_from_b, result.resolution_m);
        let found = cells <= 2.0 && rad.to_degrees() <= 1.0;
        assert!(
            found || !result.accepted,
            "{folder_file}: accepted a wrong transform ({cells:.1} cells, {:.2}°)",
            rad.to_degrees()
        );
        right += usize::from(found && result.accepted);
        total += 1;
    }
    assert!(
        right * 10 >= total * 8,
        "{folder_file}: only {right} of {total} found and accepted"
    );
}

#[test]
fn finds_turned_and_coarsened_crops_of_gdc_floor_2() {
    check_map("gridmaps/utexas-gdc-2/2.yaml", 40.0, 5, 7);
}

#[test]
fn finds_turned_and_coarsened_crops_of_intel() {
    check_map("gridmaps/intel-bwi/intel.yaml", 30.0, 5, 3);
}

#[test]
fn finds_the_1000_cell_pair_and_is_deterministic() {
    let Some(path) = mapmerge_testkit::shared_data("gridmaps/utexas-gdc-1/1.yaml") else {
        return;
    };
    let map = crops::read_map(&path).expect("readable map");
    let (a, b, truth) = crops::pair_1000(&map);
    let params = GridMatchParams::default();
    let first = match_grids(&a, &b, &params).unwrap();
    assert!(first.accepted, "{:?}", first.rejection);
    let (cells, rad) = crops::error(
        &b,
        &truth,
        &first.hypotheses[0].a_from_b,
        first.resolution_m,
    );
    assert!(
        cells <= 2.0 && rad.to_degrees() <= 1.0,
        "{cells} cells, {rad} rad"
    );
    assert_eq!(match_grids(&a, &b, &params).unwrap(), first);
}
