//! Arbitrary text into `parse_tum_planar`; whatever parses must write and parse back to the
//! same stamps and poses (yaw to rounding).

#![no_main]

use libfuzzer_sys::fuzz_target;
use mapmerge_io::{format_tum_planar, parse_tum_planar};

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(poses) = parse_tum_planar(text, "fuzz.tum") else {
        return;
    };
    let Ok(written) = format_tum_planar(&poses) else {
        return;
    };
    let again = match parse_tum_planar(&written, "fuzz-again.tum") {
        Ok(again) => again,
        Err(err) => panic!("written TUM must parse: {err}\n{written}"),
    };
    assert_eq!(again.len(), poses.len());
    for ((s0, p0), (s1, p1)) in poses.iter().zip(&again) {
        assert_eq!(s0, s1);
        assert_eq!((p0.x_m, p0.y_m), (p1.x_m, p1.y_m));
        let dyaw = mapmerge_geometry::wrap_angle_rad(p0.theta_rad - p1.theta_rad);
        assert!(dyaw.abs() < 1e-9, "{p0:?} vs {p1:?}");
    }
});
