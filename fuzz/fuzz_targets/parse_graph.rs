//! Arbitrary bytes (lossy UTF-8) into `parse_graph`; whatever parses must format and parse
//! again to the same graph (exactly, except 3D TORO whose rotations pass through Euler angles).

#![no_main]

use libfuzzer_sys::fuzz_target;
use mapmerge_io::{format_graph, parse_graph, AnyGraph, GraphFormat};

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let Ok(loaded) = parse_graph(&text, "fuzz") else {
        return;
    };
    let exact = !(loaded.format == GraphFormat::Toro && matches!(loaded.graph, AnyGraph::Spatial(_)));
    for format in [GraphFormat::G2o, GraphFormat::Toro] {
        let Ok(written) = format_graph(&loaded.graph, format) else {
            // Only priors in TORO are unwritable for a graph that parsed.
            assert_eq!(format, GraphFormat::Toro, "g2o must write every parsed graph");
            continue;
        };
        let again = match parse_graph(&written, "fuzz-again") {
            Ok(again) => again,
            Err(err) => panic!("re-parse failed: {err}\n--- written:\n{written}"),
        };
        assert_eq!(again.graph.num_vertices(), loaded.graph.num_vertices());
        assert_eq!(again.graph.num_edges(), loaded.graph.num_edges());
        if format == GraphFormat::G2o && exact {
            assert_eq!(again.graph, loaded.graph, "g2o round trip differs");
        }
    }
});
