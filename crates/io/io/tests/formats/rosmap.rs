//! ROS map_server maps: every public grid map loads with the size of the data README, survives
//! write → read and the trinary grid round trip; malformed YAML and PGM give exact messages.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

use mapmerge_grid::{log_odds_of, CellClass, ClassThresholds, GridGeometry, OccupancyGrid, Point2};
use mapmerge_io::{
    format_ros_map_yaml, parse_pgm, parse_ros_map_yaml, read_ros_map, write_ros_map, IoError,
    MapMode, RosMap, FREE_PROBABILITY, OCCUPIED_PROBABILITY,
};

/// `(yaml under gridmaps/, width, height, resolution, origin x, origin y)` (data README).
#[rustfmt::skip]
const MAPS: &[(&str, usize, usize, f64, f64, f64)] = &[
    ("intel-bwi/intel.yaml", 579, 581, 0.1, 0.0, 0.0),
    ("utexas-gdc-1/1.yaml", 1857, 1255, 0.05, -60.45, -23.4),
    ("utexas-gdc-1n/1n.yaml", 1857, 573, 0.05, -60.45, -23.4),
    ("utexas-gdc-1s/1s.yaml", 1857, 573, 0.05, -50.0, -50.0),
    ("utexas-gdc-2/2.yaml", 1800, 1400, 0.05, -53.95, -29.15),
    ("utexas-gdc-3/3.yaml", 1857, 1255, 0.05, -60.45, -23.4),
    ("utexas-gdc-3ne/3ne.yaml", 1857, 573, 0.05, -60.45, -23.4),
    ("utexas-gdc-4/4.yaml", 1857, 1255, 0.05, -60.45, -23.4),
    ("willow-2010-02-18/willow-2010-02-18-0.10.yaml", 566, 608, 0.1, 0.0, 0.0),
    ("willow-full/willow-full.yaml", 540, 587, 0.1, 0.0, 0.0),
];

/// A fresh folder for this test (removed by the caller).
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("mapmerge-io-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn every_map_on_disk_is_listed() {
    let Some(dir) = mapmerge_testkit::shared_data_dir() else {
        return;
    };
    let mut found = Vec::new();
    for entry in std::fs::read_dir(dir.join("gridmaps")).unwrap().flatten() {
        for file in std::fs::read_dir(entry.path())
            .into_iter()
            .flatten()
            .flatten()
        {
            let name = file.file_name().to_string_lossy().into_owned();
            if name.ends_with(".yaml") {
                found.push(format!("{}/{name}", entry.file_name().to_string_lossy()));
            }
        }
    }
    found.sort();
    let listed: Vec<String> = MAPS.iter().map(|m| m.0.to_owned()).collect();
    assert_eq!(found, listed);
}

#[test]
fn every_map_loads_round_trips_and_converts() {
    let out = scratch("rosmap-data");
    let thresholds = ClassThresholds::default();
    for &(relative, width, height, resolution, x, y) in MAPS {
        let Some(path) = mapmerge_testkit::shared_data(&format!("gridmaps/{relative}")) else {
            return;
        };
        let map = read_ros_map(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((map.width, map.height), (width, height), "{relative}");
        assert_eq!(map.pixels.len(), width * height);
        assert_eq!(map.resolution_m, resolution, "{relative}");
        assert_eq!(
            (map.origin_x_m, map.origin_y_m, map.origin_yaw_rad),
            (x, y, 0.0)
        );
        assert_eq!(
            (map.negate, map.mode),
            (false, MapMode::Trinary),
            "{relative}"
        );
        // The YAML names the image without `.xz`, as written.
        assert!(!map.image.to_string_lossy().ends_with(".xz"), "{relative}");

        // write → read gives the same map.
        let yaml = out.join(relative);
        write_ros_map(&yaml, &map).unwrap();
        let again = read_ros_map(&yaml).unwrap();
        assert!(again == map, "{relative}: write → read differs");

        // Grid: size and placement, image top row = grid top row.
        let grid = map.to_grid().unwrap();
        let geometry = grid.geometry();
        assert_eq!((geometry.width, geometry.height), (width, height));
        assert_eq!(geometry.origin_m, Point2::new(x, y));
        let top_left = grid.log_odds()[(height - 1) * width];
        let from_pixel = RosMap {
            pixels: vec![map.pixels[0]],
            width: 1,
            height: 1,
            ..map.clone()
        };
        assert_eq!(
            top_left,
            from_pixel.to_grid().unwrap().log_odds()[0],
            "{relative}"
        );
        let classes = grid.classes(&thresholds);
        let count = |class| classes.iter().filter(|&&c| c == class).count();
        // willow-2010-02-18 is a faint SLAM map: 544 occupied pixels.
        assert!(count(CellClass::Occupied) > 500, "{relative}");
        assert!(count(CellClass::Free) > 10_000, "{relative}");

        // Trinary: grid → map → grid is exact (three values), and map → grid → map keeps
        // every pixel's class.
        let trinary = RosMap::from_grid(&grid, MapMode::Trinary, &thresholds);
        assert_eq!(trinary.to_grid().unwrap(), grid, "{relative}");
        let canonical = |v: u8, m: &RosMap| {
            let p = f64::from(255 - v) / 255.0;
            if p > m.occupied_thresh {
                0
            } else if p < m.free_thresh {
                254
            } else {
                205
            }
        };
        assert!(trinary
            .pixels
            .iter()
            .zip(&map.pixels)
            .all(|(&t, &v)| t == canonical(v, &map)));
    }
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn utexas_partial_map_matches_its_floor() {
    // README: 1n largely coincides with the bottom 573 rows of floor 1 (about 87 % equal).
    let (Some(full), Some(part)) = (
        mapmerge_testkit::shared_data("gridmaps/utexas-gdc-1/1.yaml"),
        mapmerge_testkit::shared_data("gridmaps/utexas-gdc-1n/1n.yaml"),
    ) else {
        return;
    };
    let (full, part) = (read_ros_map(&full).unwrap(), read_ros_map(&part).unwrap());
    let bottom = &full.pixels[(full.height - part.height) * full.width..];
    let equal = bottom
        .iter()
        .zip(&part.pixels)
        .filter(|(a, b)| a == b)
        .count();
    let fraction = equal as f64 / part.pixels.len() as f64;
    assert!((0.85..0.9).contains(&fraction), "{fraction}");
}

#[test]
fn written_map_is_named_after_the_yaml_and_can_be_compressed() {
    let dir = scratch("rosmap-write");
    let occupied = log_odds_of(OCCUPIED_PROBABILITY);
    let free = log_odds_of(FREE_PROBABILITY);
    let geometry = GridGeometry {
        resolution_m: 0.05,
        origin_m: Point2::new(-3.25, 1e-7),
        width: 3,
        height: 2,
    };
    let grid =
        OccupancyGrid::from_log_odds(geometry, vec![occupied, free, 0.0, 0.0, 0.0, free]).unwrap();
    let map = RosMap::from_grid(&grid, MapMode::Trinary, &ClassThresholds::default());
    let yaml = dir.join("sub/floor.yaml");
    write_ros_map(&yaml, &map).unwrap();
    let text = std::fs::read_to_string(&yaml).unwrap();
    assert_eq!(
        text,
        "image: floor.pgm\nresolution: 0.05\norigin: [-3.25, 1e-7, 0]\nnegate: 0\n\
         occupied_thresh: 0.65\nfree_thresh: 0.196\nmode: trinary\n"
    );
    let pgm = std::fs::read(dir.join("sub/floor.pgm")).unwrap();
    assert_eq!(pgm, b"P5\n3 2\n255\n\xcd\xcd\xfe\x00\xfe\xcd");
    let again = read_ros_map(&yaml).unwrap();
    assert_eq!(again.to_grid().unwrap(), grid);
    assert_eq!(again.image, Path::new("floor.pgm"));
    // Compressed storage behind a plain name: the YAML names `floor.pgm`, the file is
    // `floor.pgm.xz`, and reading falls back to it.
    let packed = dir.join("packed/floor.yaml");
    mapmerge_io::write_ros_map_with(&packed, &map, true).unwrap();
    assert!(dir.join("packed/floor.pgm.xz").exists() && !dir.join("packed/floor.pgm").exists());
    assert_eq!(std::fs::read_to_string(&packed).unwrap(), text);
    assert_eq!(read_ros_map(&packed).unwrap().to_grid().unwrap(), grid);
    // An `.xz` image name is written compressed and read back.
    let compressed = RosMap {
        image: PathBuf::from("img/floor.pgm.xz"),
        mode: MapMode::Scale,
        ..map.clone()
    };
    write_ros_map(&dir.join("c.yaml"), &compressed).unwrap();
    let bytes = std::fs::read(dir.join("img/floor.pgm.xz")).unwrap();
    assert!(bytes.starts_with(b"\xfd7zXZ\0"));
    assert_eq!(read_ros_map(&dir.join("c.yaml")).unwrap(), compressed);
    // Names YAML would misread are quoted.
    for name in ["true", "12", "null", "a: b", "#x", "yes"] {
        let odd = RosMap {
            image: PathBuf::from(name),
            ..map.clone()
        };
        let text = format_ros_map_yaml(&odd).unwrap();
        let back = parse_ros_map_yaml(&text, "odd.yaml").unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(back.image, Path::new(name), "{text}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

const GOOD: &str = "image: m.pgm\nresolution: 0.05\norigin: [-1.5, 2, 0.1]\nnegate: 0\n\
                    occupied_thresh: 0.65\nfree_thresh: 0.196\nmode: scale\n";

/// `GOOD` with the line starting with `key` replaced by `line` (or removed when empty).
fn with_line(key: &str, line: &str) -> String {
    GOOD.lines()
        .filter_map(|l| {
            if l.starts_with(key) {
                (!line.is_empty()).then(|| line.to_owned())
            } else {
                Some(l.to_owned())
            }
        })
        .map(|l| l + "\n")
        .collect()
}

#[track_caller]
fn expect_yaml_error(text: &str, message: &str) {
    match parse_ros_map_yaml(text, "m.yaml") {
        Err(err) => assert_eq!(err.to_string(), message),
        Ok(map) => panic!("expected {message:?}, got {map:?}"),
    }
}

#[test]
fn yaml_fields_and_leniency() {
    let map = parse_ros_map_yaml(GOOD, "m.yaml").unwrap();
    assert_eq!(map.image, Path::new("m.pgm"));
    assert_eq!(
        (
            map.resolution_m,
            map.origin_x_m,
            map.origin_y_m,
            map.origin_yaw_rad
        ),
        (0.05, -1.5, 2.0, 0.1)
    );
    assert_eq!((map.occupied_thresh, map.free_thresh), (0.65, 0.196));
    assert_eq!(
        (map.negate, map.mode, map.width, map.height),
        (false, MapMode::Scale, 0, 0)
    );
    // Block lists, booleans, quoted numbers, comments, extra keys, no mode.
    let other = "# map\nimage: \"a b.pgm\"\nresolution: '0.1'\norigin:\n  - 1\n  - 2\n  - 0\n\
                 negate: true\noccupied_thresh: 1\nfree_thresh: 0\nunused: [1, 2]\n";
    let map = parse_ros_map_yaml(other, "o.yaml").unwrap();
    assert_eq!(map.image, Path::new("a b.pgm"));
    assert_eq!(
        (map.resolution_m, map.origin_x_m, map.negate),
        (0.1, 1.0, true)
    );
    assert_eq!(map.mode, MapMode::Trinary);
    // Formatting and parsing again gives the same fields.
    let text = format_ros_map_yaml(&map).unwrap();
    assert_eq!(parse_ros_map_yaml(&text, "again.yaml").unwrap(), map);
}

#[test]
fn yaml_errors_name_file_line_and_reason() {
    expect_yaml_error(
        &with_line("resolution", ""),
        "m.yaml: missing key `resolution`",
    );
    expect_yaml_error(&with_line("negate", ""), "m.yaml: missing key `negate`");
    expect_yaml_error(&with_line("image", ""), "m.yaml: missing key `image`");
    expect_yaml_error(
        &with_line("resolution", "resolution: fine"),
        "m.yaml:2: resolution `fine` is not a finite number",
    );
    expect_yaml_error(
        &with_line("resolution", "resolution: .inf"),
        "m.yaml:2: resolution `.inf` is not a finite number",
    );
    expect_yaml_error(
        &with_line("resolution", "resolution: -0.05"),
        "m.yaml:2: resolution -0.05 must be a positive number of metres",
    );
    expect_yaml_error(
        &with_line("resolution", "resolution: 0"),
        "m.yaml:2: resolution 0 must be a positive number of metres",
    );
    expect_yaml_error(
        &with_line("origin", "origin: [1, 2]"),
        "m.yaml:3: origin must be a list of 3 numbers [x, y, yaw], found a list of 2",
    );
    expect_yaml_error(
        &with_line("origin", "origin: 5"),
        "m.yaml:3: origin must be a list of 3 numbers [x, y, yaw], found `5`",
    );
    expect_yaml_error(
        &with_line("origin", "origin: [1, x, 0]"),
        "m.yaml:3: origin `x` is not a finite number",
    );
    expect_yaml_error(
        &with_line("negate", "negate: 2"),
        "m.yaml:4: negate `2` must be 0 or 1",
    );
    expect_yaml_error(
        &with_line("occupied_thresh", "occupied_thresh: 1.5"),
        "m.yaml:5: occupied_thresh 1.5 is outside [0, 1]",
    );
    expect_yaml_error(
        &with_line("free_thresh", "free_thresh: 0.7"),
        "m.yaml:6: free_thresh 0.7 is above occupied_thresh 0.65",
    );
    expect_yaml_error(
        &with_line("mode", "mode: trinery"),
        "m.yaml:7: mode `trinery` must be trinary, scale or raw",
    );
    expect_yaml_error(
        &with_line("image", "image: 12"),
        "m.yaml:1: image `12` is not a file name",
    );
    expect_yaml_error(
        "- a\n- b\n",
        "m.yaml: a map_server YAML must be a mapping of keys to values, found a list",
    );
    expect_yaml_error(
        "",
        "m.yaml: a map_server YAML must be a mapping of keys to values, found nothing",
    );
    // Syntax errors carry the parser's line.
    match parse_ros_map_yaml(
        "image: a.pgm\nresolution: 1\norigin: [1, 2\nnegate: 0\n",
        "m.yaml",
    ) {
        Err(IoError::Parse { file, line, reason }) => {
            assert_eq!(file, "m.yaml");
            assert!((3..=5).contains(&line), "{line}: {reason}");
            assert!(reason.starts_with("invalid YAML: "), "{reason}");
        }
        other => panic!("{other:?}"),
    }
    match parse_ros_map_yaml("image: a\nimage: b\n", "m.yaml") {
        Err(IoError::Parse { reason, .. }) => {
            assert!(reason.contains("duplicate"), "{reason}");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn missing_image_and_bad_pgm_through_read_ros_map() {
    let dir = scratch("rosmap-errors");
    let yaml = dir.join("m.yaml");
    std::fs::write(&yaml, GOOD).unwrap();
    let err = read_ros_map(&yaml).unwrap_err();
    assert_eq!(
        err.to_string(),
        format!(
            "{}:1: image file `{}` does not exist (nor with .xz)",
            yaml.display(),
            dir.join("m.pgm").display()
        )
    );
    std::fs::write(dir.join("m.pgm"), b"P5 2 2 255\n\0\0\0").unwrap();
    let err = read_ros_map(&yaml).unwrap_err();
    assert_eq!(
        err.to_string(),
        format!(
            "{}: PGM pixel data holds 3 bytes, expected 4 (2 x 2, 1 byte(s) per pixel)",
            dir.join("m.pgm").display()
        )
    );
    std::fs::write(dir.join("m.pgm"), b"P2\n2 2\n255\n0 1\n2 x\n").unwrap();
    let err = read_ros_map(&yaml).unwrap_err();
    assert_eq!(
        err.to_string(),
        format!(
            "{}:5: PGM sample `x` is not an integer in 0..=255",
            dir.join("m.pgm").display()
        )
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn unwritable_maps() {
    let mut map = parse_ros_map_yaml(GOOD, "m.yaml").unwrap();
    map.width = 2;
    map.height = 2;
    map.pixels = vec![0; 3];
    let dir = scratch("rosmap-unwritable");
    let err = write_ros_map(&dir.join("m.yaml"), &map).unwrap_err();
    assert_eq!(
        err.to_string(),
        "cannot write the data as PGM: 3 pixels for a 2 x 2 image"
    );
    map.pixels.push(0);
    map.resolution_m = f64::NAN;
    assert!(matches!(
        write_ros_map(&dir.join("m.yaml"), &map),
        Err(IoError::Unwritable { .. })
    ));
    assert!(matches!(map.to_grid(), Err(IoError::Invalid { .. })));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn pgm_formats() {
    let (w, h, pixels) = parse_pgm(b"P2\n# c\n3 1\n65535\n0 32768 65535\n", "p.pgm").unwrap();
    assert_eq!((w, h, pixels), (3, 1, vec![0, 128, 255]));
}
