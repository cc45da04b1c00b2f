//! Randomised smoke test that runs without nightly (the cargo-fuzz targets in `fuzz/` go
//! further): mutated pieces of real and synthetic graph files, CARMEN logs, map_server YAMLs
//! and PGM images never make a parser panic, and whatever parses writes and reads back.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_io::{
    format_carmen, format_graph, format_pgm, format_ros_map_yaml, parse_carmen, parse_graph,
    parse_pgm, parse_ros_map_yaml, read_carmen, read_graph, GraphFormat, IoError,
};

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

const CARMEN_TOKENS: &[&str] = &[
    "PARAM",
    "ODOM",
    "FLASER",
    "RLASER",
    "ROBOTLASER1",
    "RAWLASER2",
    "NEFF",
    "0",
    "1",
    "2",
    "180",
    "-1",
    "81.91",
    "nan",
    "1e39",
    "1e308",
    "18446744073709551615",
    "robot_front_laser_max",
    "pippo",
    "#",
    "\n",
    " ",
    "\r\n",
    "é",
];

const YAML_TOKENS: &[&str] = &[
    "image:",
    "resolution:",
    "origin:",
    "negate:",
    "occupied_thresh:",
    "free_thresh:",
    "mode:",
    "scale",
    "raw",
    "[",
    "]",
    "{",
    "}",
    ",",
    "-",
    ":",
    "'",
    "\"",
    "&a",
    "*a",
    "!!str",
    "~",
    ".inf",
    ".nan",
    "1e309",
    "-0",
    "0x10",
    "true",
    "#",
    "\n",
    "\n  ",
    "\t",
];

fn mutate(rng: &mut SplitMix, text: &str) -> String {
    mutate_with(rng, text, TOKENS)
}

fn mutate_with(rng: &mut SplitMix, text: &str, table: &[&str]) -> String {
    let mut tokens: Vec<String> = text.split(' ').map(str::to_owned).collect();
    for _ in 0..=rng.below(4) {
        let len = tokens.len();
        match rng.below(6) {
            0 if len > 1 => {
                tokens.remove(rng.below(len));
            }
            1 => {
                let pick = table[rng.below(table.len())].to_owned();
                tokens.insert(rng.below(len + 1), pick);
            }
            2 => {
                let at = rng.below(len);
                tokens[at] = table[rng.below(table.len())].to_owned();
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

/// Parses a CARMEN text; whatever parses must write (unless a number overflows to infinity on
/// the way, e.g. a field of view of 1e308 rad per beam) and read back with the same content.
fn check_carmen(text: &str) -> bool {
    let Ok(log) = parse_carmen(text, "smoke") else {
        return false;
    };
    let written = match format_carmen(&log) {
        Ok(written) => written,
        Err(IoError::Unwritable { reason, .. }) if reason.contains("non-finite") => return true,
        Err(err) => panic!("{err}\ninput:\n{text}"),
    };
    let again = parse_carmen(&written, "smoke-again")
        .unwrap_or_else(|e| panic!("{e}\ninput:\n{text}\nwritten:\n{written}"));
    assert_eq!(again.odometry, log.odometry, "{text}");
    assert_eq!(again.params, log.params, "{text}");
    assert_eq!(again.scans.len(), log.scans.len(), "{text}");
    for (a, b) in again.scans.iter().zip(&log.scans) {
        assert_eq!(a.scan.ranges_m, b.scan.ranges_m, "{text}");
        assert_eq!(a.scan.range_max_m, b.scan.range_max_m, "{text}");
        assert_eq!(a.odom_from_robot, b.odom_from_robot, "{text}");
    }
    true
}

#[test]
fn mutated_carmen_logs_never_panic() {
    let mut seeds = vec![
        "PARAM robot_front_laser_max 80 nohost 0\nODOM 0 0 0 0 0 0 1 h 1\n\
         FLASER 3 1 2 81.91 0 0 0 0 0 0 2 h 2\nNEFF 30\n"
            .to_owned(),
        "# c\nRLASER 2 5 30 0 0 3.14 0 0 0 12 h 12\nFLASER 1 81.91 1 2 0.5 1 2 0.4 3 h 3\n"
            .to_owned(),
        "RAWLASER3 0 -1 2 0.5 30 0.01 0 3 1 2 3 2 7 8 100.5 host 0.5\n\
         ROBOTLASER1 0 -1.5 3 1 50 0.01 0 2 1 50 0 1 2 0.1 1 2 0.1 0.3 0.1 0 0 0 101 host 1\n"
            .to_owned(),
    ];
    if let Some(dir) = mapmerge_testkit::shared_data_dir() {
        for file in [
            "carmen/orebro-corrected.log.xz",
            "carmen/robot-mapping-course/csail.log.xz",
        ] {
            let log = read_carmen(&dir.join(file)).unwrap();
            let text = format_carmen(&log).unwrap();
            seeds.push(text.lines().take(6).collect::<Vec<_>>().join("\n"));
        }
    }
    let mut rng = SplitMix(0xCA4_4E11);
    let mut parsed = 0;
    for round in 0..20_000 {
        let text = mutate_with(&mut rng, &seeds[round % seeds.len()], CARMEN_TOKENS);
        if check_carmen(&text) {
            parsed += 1;
        }
    }
    assert!(parsed > 1000, "only {parsed} mutated logs parsed");
}

#[test]
fn mutated_map_yamls_never_panic() {
    let mut seeds = vec![
        "image: m.pgm\nresolution: 0.05\norigin: [-1.5, 2, 0.1]\nnegate: 0\n\
         occupied_thresh: 0.65\nfree_thresh: 0.196\nmode: scale\n"
            .to_owned(),
        "image: \"a b.pgm\"\nresolution: '0.1'\norigin:\n  - 1\n  - 2\n  - 0\nnegate: true\n\
         occupied_thresh: 1\nfree_thresh: 0\n"
            .to_owned(),
    ];
    if let Some(dir) = mapmerge_testkit::shared_data_dir() {
        for file in [
            "gridmaps/willow-full/willow-full.yaml",
            "gridmaps/intel-bwi/intel.yaml",
        ] {
            seeds.push(std::fs::read_to_string(dir.join(file)).unwrap());
        }
    }
    let mut rng = SplitMix(0x7A31);
    let mut parsed = 0;
    for round in 0..20_000 {
        let text = mutate_with(&mut rng, &seeds[round % seeds.len()], YAML_TOKENS);
        let Ok(map) = parse_ros_map_yaml(&text, "smoke.yaml") else {
            continue;
        };
        parsed += 1;
        let written = format_ros_map_yaml(&map).unwrap_or_else(|e| panic!("{e}\n{text}"));
        let again = parse_ros_map_yaml(&written, "again.yaml")
            .unwrap_or_else(|e| panic!("{e}\ninput:\n{text}\nwritten:\n{written}"));
        assert_eq!(again, map, "{text}");
    }
    // About one in twenty mutations of each seed still parses.
    assert!(
        parsed > 250 * seeds.len(),
        "only {parsed} mutated YAMLs of {} seeds parsed",
        seeds.len()
    );
}

/// Byte-level mutations (PGM is binary).
fn mutate_bytes(rng: &mut SplitMix, seed: &[u8]) -> Vec<u8> {
    const PIECES: &[&[u8]] = &[
        b"P5", b"P2", b" ", b"\n", b"#", b"255", b"65535", b"0", b"9",
    ];
    let mut bytes = seed.to_vec();
    for _ in 0..=rng.below(3) {
        let len = bytes.len();
        match rng.below(4) {
            0 if len > 0 => {
                bytes.remove(rng.below(len));
            }
            1 => {
                let piece = PIECES[rng.below(PIECES.len())];
                let at = rng.below(len + 1);
                bytes.splice(at..at, piece.iter().copied());
            }
            2 if len > 0 => {
                let at = rng.below(len);
                bytes[at] ^= 1 << rng.below(8);
            }
            _ => bytes.truncate(rng.below(len + 1)),
        }
    }
    bytes
}

#[test]
fn mutated_pgms_never_panic() {
    let seeds: Vec<Vec<u8>> = vec![
        b"P5\n# c\n3 2\n255\n\x00\x80\xff\xcd\xfe\x01".to_vec(),
        b"P2\n2 2\n15\n0 15\n8 1\n".to_vec(),
        b"P5 2 1 65535\n\xff\xff\x80\x00".to_vec(),
        b"P5\n1 1\n1\n\x01".to_vec(),
    ];
    let mut rng = SplitMix(0x96E);
    let mut parsed = 0;
    for round in 0..20_000 {
        let bytes = mutate_bytes(&mut rng, &seeds[round % seeds.len()]);
        let Ok((width, height, pixels)) = parse_pgm(&bytes, "smoke.pgm") else {
            continue;
        };
        parsed += 1;
        assert_eq!(pixels.len(), width * height);
        let written = format_pgm(width, height, &pixels).unwrap();
        assert_eq!(
            parse_pgm(&written, "again.pgm").unwrap(),
            (width, height, pixels)
        );
    }
    assert!(parsed > 1000, "only {parsed} mutated PGMs parsed");
}
