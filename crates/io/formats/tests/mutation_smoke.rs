//! Randomised smoke test that runs without nightly (the cargo-fuzz target in `fuzz/` goes
//! further): mutated pieces of real and synthetic graph files never make the parser panic, and
//! whatever parses writes and reads back.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_io::{format_graph, parse_graph, read_graph, GraphFormat};

/// Small deterministic generator (SplitMix64), so failures reproduce.
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

const TOKENS: &[&str] = &[
    "VERTEX_SE2",
    "EDGE_SE2",
    "VERTEX_SE3:QUAT",
    "EDGE_SE3:QUAT",
    "FIX",
    "VERTEX2",
    "EDGE2",
    "VERTEX3",
    "EDGE3",
    "EDGE_PRIOR_SE2",
    "EDGE_SE3_PRIOR",
    "PARAMS_SE3OFFSET",
    "nan",
    "-inf",
    "1e400",
    "-1",
    "0",
    "1",
    "18446744073709551616",
    "#",
    "\n",
    " ",
    "\r\n",
    "é",
    "0.5",
    "-0",
];

fn mutate(rng: &mut SplitMix, text: &str) -> String {
    let mut tokens: Vec<String> = text.split(' ').map(str::to_owned).collect();
    for _ in 0..=rng.below(4) {
        let len = tokens.len();
        match rng.below(6) {
            0 if len > 1 => {
                tokens.remove(rng.below(len));
            }
            1 => {
                let pick = TOKENS[rng.below(TOKENS.len())].to_owned();
                tokens.insert(rng.below(len + 1), pick);
            }
            2 => {
                let at = rng.below(len);
                tokens[at] = TOKENS[rng.below(TOKENS.len())].to_owned();
            }
            3 if len > 1 => {
                let (a, b) = (rng.below(len), rng.below(len));
                tokens.swap(a, b);
            }
            4 => {
                let at = rng.below(len);
                let dup = tokens[at].clone();
                tokens.insert(at, dup);
            }
            _ => {
                let at = rng.below(len);
                let mut bytes = tokens[at].clone().into_bytes();
                if !bytes.is_empty() {
                    let i = rng.below(bytes.len());
                    bytes[i] ^= 1 << rng.below(8);
                }
                tokens[at] = String::from_utf8_lossy(&bytes).into_owned();
            }
        }
    }
    tokens.join(" ")
}

fn check(text: &str) -> bool {
    let Ok(loaded) = parse_graph(text, "smoke") else {
        return false;
    };
    for format in [GraphFormat::G2o, GraphFormat::Toro] {
        if let Ok(written) = format_graph(&loaded.graph, format) {
            let again = parse_graph(&written, "smoke-again")
                .unwrap_or_else(|e| panic!("{e}\ninput:\n{text}\nwritten:\n{written}"));
            assert_eq!(again.graph.num_edges(), loaded.graph.num_edges());
        }
    }
    true
}

#[test]
fn mutated_graphs_never_panic() {
    let mut seeds = vec![
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nFIX 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n"
            .to_owned(),
        "VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 1 0 1 1 0 0\n".to_owned(),
        "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nPARAMS_SE3OFFSET 0 0 0 0 0 0 0 1\n\
         EDGE_SE3_PRIOR 0 0 1 2 3 0 0 0 1 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1\n"
            .to_owned(),
    ];
    if let Some(dir) = mapmerge_testkit::shared_data_dir() {
        for file in [
            "g2o/openslam_g2o/intel.g2o",
            "g2o/se-sync/smallGrid3D.g2o",
            "g2o/se-sync/CSAIL.g2o",
            "g2o/hog-man/3D/sphere_smallnoise.graph.xz",
        ] {
            let loaded = read_graph(&dir.join(file)).unwrap();
            // The first few lines of the file as written by us (same format).
            let text = format_graph(&loaded.graph, loaded.format).unwrap();
            seeds.push(text.lines().take(12).collect::<Vec<_>>().join("\n"));
        }
    }
    let mut rng = SplitMix(0x5EED);
    let mut parsed = 0;
    for round in 0..50_000 {
        let seed = &seeds[round % seeds.len()];
        let text = mutate(&mut rng, seed);
        if check(&text) {
            parsed += 1;
        }
    }
    // The mutations must leave some inputs valid, or the round trip is never exercised.
    assert!(parsed > 1000, "only {parsed} mutated inputs parsed");
}
