//! Arbitrary bytes (lossy UTF-8) into `parse_ros_map_yaml`; whatever parses must format and
//! parse again to the same fields, and convert to a grid (with a small image) without panic.

#![no_main]

use libfuzzer_sys::fuzz_target;
use mapmerge_io::{format_ros_map_yaml, parse_ros_map_yaml};

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let Ok(mut map) = parse_ros_map_yaml(&text, "fuzz.yaml") else {
        return;
    };
    let written = match format_ros_map_yaml(&map) {
        Ok(written) => written,
        Err(err) => panic!("a parsed YAML must be writable: {err}"),
    };
    let again = match parse_ros_map_yaml(&written, "fuzz-again.yaml") {
        Ok(again) => again,
        Err(err) => panic!("re-parse failed: {err}\n--- written:\n{written}"),
    };
    assert_eq!(again, map);
    // Every grey level once, under this YAML's semantics.
    map.width = 16;
    map.height = 16;
    map.pixels = (0..=255).collect();
    let _ = map.to_grid();
});
