//! Arbitrary bytes into `parse_pgm`; whatever parses must hold `width · height` pixels, write
//! and parse again to the same image, and survive the map_server grid conversions.

#![no_main]

use libfuzzer_sys::fuzz_target;
use mapmerge_grid::ClassThresholds;
use mapmerge_io::{format_pgm, parse_pgm, MapMode, RosMap};

fuzz_target!(|data: &[u8]| {
    let Ok((width, height, pixels)) = parse_pgm(data, "fuzz.pgm") else {
        return;
    };
    assert_eq!(Some(pixels.len()), width.checked_mul(height));
    let written = match format_pgm(width, height, &pixels) {
        Ok(written) => written,
        Err(err) => panic!("a parsed image must be writable: {err}"),
    };
    let again = parse_pgm(&written, "fuzz-again.pgm");
    assert_eq!(again.ok(), Some((width, height, pixels.clone())));
    let map = RosMap {
        image: "fuzz.pgm".into(),
        resolution_m: 0.05,
        origin_x_m: 0.0,
        origin_y_m: 0.0,
        origin_yaw_rad: 0.0,
        negate: false,
        occupied_thresh: 0.65,
        free_thresh: 0.196,
        mode: MapMode::Trinary,
        width,
        height,
        pixels,
    };
    let Ok(grid) = map.to_grid() else {
        return;
    };
    let thresholds = ClassThresholds::default();
    let trinary = RosMap::from_grid(&grid, MapMode::Trinary, &thresholds);
    assert_eq!(trinary.to_grid().ok().as_ref(), Some(&grid));
});
