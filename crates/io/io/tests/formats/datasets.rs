//! Every pose-graph file of the public datasets parses, with the expected counts, and survives a

#![allow(clippy::unwrap_used, clippy::expect_used)]
//! write → read round trip.

use std::path::{Path, PathBuf};

use mapmerge_io::{
    format_graph, parse_graph, read_graph, read_graph_with, AnyGraph, BadInformation, GraphFormat,
    IoError, LoadedGraph, ReadParams,
};
use mapmerge_posegraph::{EdgeId, EdgeKind, NodeId};

/// The one dataset with broken information matrices (5021 indefinite ones); it needs
/// [`BadInformation::KeepDiagonal`].
const CUBICLE: &str = "se-sync/cubicle.g2o.xz";

/// `(path under g2o/, format, spatial, vertices, edges, had_vertex_lines)`.
const GRAPHS: &[(&str, GraphFormat, bool, usize, usize, bool)] = &[
    (
        "hog-man/2D/w10000.graph.xz",
        GraphFormat::Toro,
        false,
        10000,
        64311,
        true,
    ),
    (
        "hog-man/3D/sphere_smallnoise.graph.xz",
        GraphFormat::Toro,
        true,
        2200,
        8647,
        true,
    ),
    (
        "hog-man/3D/sphere_mednoise.graph",
        GraphFormat::Toro,
        true,
        2200,
        8647,
        true,
    ),
    (
        "hog-man/3D/sphere_bignoise.graph",
        GraphFormat::Toro,
        true,
        2200,
        8647,
        true,
    ),
    (
        "openslam_g2o/intel.g2o",
        GraphFormat::G2o,
        false,
        943,
        1837,
        true,
    ),
    (
        "openslam_g2o/manhattanOlson3500.g2o",
        GraphFormat::G2o,
        false,
        3500,
        5598,
        true,
    ),
    (
        "se-sync/CSAIL.g2o",
        GraphFormat::G2o,
        false,
        1045,
        1172,
        false,
    ),
    ("se-sync/MIT.g2o", GraphFormat::G2o, false, 808, 827, true),
    (
        "se-sync/ais2klinik.g2o.xz",
        GraphFormat::G2o,
        false,
        15115,
        16727,
        true,
    ),
    (
        "se-sync/city10000.g2o.xz",
        GraphFormat::G2o,
        false,
        10000,
        20687,
        true,
    ),
    (
        "se-sync/cubicle.g2o.xz",
        GraphFormat::G2o,
        true,
        5750,
        16869,
        true,
    ),
    (
        "se-sync/intel.g2o",
        GraphFormat::G2o,
        false,
        1728,
        2512,
        true,
    ),
    (
        "se-sync/kitti_00.g2o",
        GraphFormat::G2o,
        false,
        4541,
        4677,
        false,
    ),
    (
        "se-sync/kitti_02.g2o",
        GraphFormat::G2o,
        false,
        4661,
        4703,
        false,
    ),
    (
        "se-sync/kitti_05.g2o",
        GraphFormat::G2o,
        false,
        2761,
        2826,
        false,
    ),
    (
        "se-sync/manhattan.g2o",
        GraphFormat::G2o,
        false,
        3500,
        5453,
        false,
    ),
    (
        "se-sync/parking-garage.g2o.xz",
        GraphFormat::G2o,
        true,
        1661,
        6275,
        true,
    ),
    (
        "se-sync/smallGrid3D.g2o",
        GraphFormat::G2o,
        true,
        125,
        297,
        true,
    ),
    (
        "se-sync/sphere2500.g2o.xz",
        GraphFormat::G2o,
        true,
        2500,
        4949,
        true,
    ),
    (
        "se-sync/sphere_bignoise_vertex3.g2o.xz",
        GraphFormat::G2o,
        true,
        2200,
        8647,
        true,
    ),
    (
        "se-sync/torus3D.g2o.xz",
        GraphFormat::G2o,
        true,
        5000,
        9048,
        true,
    ),
    (
        "vertigo/manhattan/originalDataset/Olson/manhattanOlson3500.g2o",
        GraphFormat::G2o,
        false,
        3500,
        5598,
        true,
    ),
    (
        "vertigo/ring/groundTruth/ring.g2o",
        GraphFormat::G2o,
        false,
        434,
        459,
        true,
    ),
    (
        "vertigo/ring/originalDataset/ring.g2o",
        GraphFormat::G2o,
        false,
        434,
        459,
        true,
    ),
    (
        "vertigo/ringCity/groundTruth/ringCity.g2o",
        GraphFormat::G2o,
        false,
        2361,
        3261,
        true,
    ),
    (
        "vertigo/ringCity/originalDataset/ringCity.g2o",
        GraphFormat::G2o,
        false,
        2361,
        3261,
        true,
    ),
];

/// Reads a dataset graph, repairing information matrices only for [`CUBICLE`].
fn load(path: &Path) -> LoadedGraph {
    let bad_information = if path.ends_with(CUBICLE) {
        BadInformation::KeepDiagonal
    } else {
        BadInformation::Reject
    };
    read_graph_with(path, &ReadParams { bad_information })
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Every `.g2o`/`.graph` file (optionally `.xz`) under `dir`, relative to it.
fn graph_files(dir: &Path, base: &Path, out: &mut Vec<String>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            graph_files(&path, base, out);
            continue;
        }
        let name = path.to_string_lossy().into_owned();
        let stem = name.strip_suffix(".xz").unwrap_or(&name);
        if stem.ends_with(".g2o") || stem.ends_with(".graph") {
            let relative = path
                .strip_prefix(base)
                .map(PathBuf::from)
                .unwrap_or(path.clone());
            out.push(relative.to_string_lossy().into_owned());
        }
    }
}

#[test]
fn every_dataset_graph_is_listed() {
    let Some(dir) = mapmerge_testkit::shared_data_dir() else {
        return;
    };
    let g2o_dir = dir.join("g2o");
    let mut found = Vec::new();
    graph_files(&g2o_dir, &g2o_dir, &mut found);
    found.sort();
    let mut listed: Vec<String> = GRAPHS.iter().map(|g| g.0.to_owned()).collect();
    listed.sort();
    assert_eq!(found, listed, "graph files on disk vs. the GRAPHS table");
}

#[test]
fn every_dataset_graph_parses_with_expected_counts() {
    let Some(dir) = mapmerge_testkit::shared_data_dir() else {
        return;
    };
    let mut failures = Vec::new();
    for &(relative, format, spatial, vertices, edges, had_vertices) in GRAPHS {
        let path = dir.join("g2o").join(relative);
        let loaded = match read_graph(&path) {
            Ok(loaded) => loaded,
            Err(err) if relative == CUBICLE => {
                assert!(err.to_string().contains("not positive definite"), "{err}");
                load(&path)
            }
            Err(err) => {
                failures.push(err.to_string());
                continue;
            }
        };
        let got = (
            loaded.format,
            matches!(loaded.graph, AnyGraph::Spatial(_)),
            loaded.graph.num_vertices(),
            loaded.graph.num_edges(),
            loaded.had_vertices,
        );
        if got != (format, spatial, vertices, edges, had_vertices) {
            failures.push(format!("{relative}: got {got:?}"));
        }
        if relative != CUBICLE && !loaded.repaired_edges.is_empty() {
            failures.push(format!(
                "{relative}: repaired edges with the default params"
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn cubicle_is_rejected_by_default_and_loads_with_diagonal_repair() {
    let Some(path) = mapmerge_testkit::shared_data(&format!("g2o/{CUBICLE}")) else {
        return;
    };
    match read_graph(&path) {
        Err(IoError::Parse { line, reason, .. }) => {
            assert_eq!(line, 5753, "{reason}");
            assert!(reason.contains("not positive definite"), "{reason}");
        }
        other => panic!("expected a parse error, got {other:?}"),
    }
    let loaded = load(&path);
    assert_eq!(loaded.repaired_edges.len(), 5021);
    assert_eq!(loaded.repaired_edges.first(), Some(&EdgeId(2)));
    let AnyGraph::Spatial(g) = &loaded.graph else {
        panic!("cubicle is 3D")
    };
    let edge = g.edge(EdgeId(2)).unwrap();
    // File diagonal (t, r) = (2.46483e6, 1.52034e7, 10, 10, 10, 91520.2); ours is (ω, v).
    let diagonal = [10.0, 10.0, 91520.2, 2.46483e6, 1.52034e7, 10.0];
    assert_eq!(
        edge.information,
        nalgebra::Matrix6::from_diagonal(&diagonal.into())
    );
}

#[test]
fn every_dataset_graph_round_trips_through_both_formats() {
    let Some(dir) = mapmerge_testkit::shared_data_dir() else {
        return;
    };
    for &(relative, format, spatial, ..) in GRAPHS {
        let loaded = load(&dir.join("g2o").join(relative));
        // Same format: identical graph, bit for bit (3D TORO: rotations through Euler angles).
        let text =
            format_graph(&loaded.graph, format).unwrap_or_else(|e| panic!("{relative}: {e}"));
        let again = parse_graph(&text, relative).unwrap_or_else(|e| panic!("{relative}: {e}"));
        if spatial && format == GraphFormat::Toro {
            assert_close(&again.graph, &loaded.graph, relative);
        } else {
            assert!(
                again.graph == loaded.graph,
                "{relative}: {format} round trip differs"
            );
        }
        // The other format: exact in 2D, up to Euler-angle rounding for 3D TORO.
        let other = if format == GraphFormat::G2o {
            GraphFormat::Toro
        } else {
            GraphFormat::G2o
        };
        let text = format_graph(&loaded.graph, other).unwrap_or_else(|e| panic!("{relative}: {e}"));
        let converted = parse_graph(&text, relative).unwrap_or_else(|e| panic!("{relative}: {e}"));
        assert_eq!(converted.format, other);
        if spatial {
            assert_close(&converted.graph, &loaded.graph, relative);
        } else {
            assert!(
                converted.graph == loaded.graph,
                "{relative}: conversion to {other} differs"
            );
        }
    }
}

/// Same ids, kinds and information; poses equal up to Euler-angle rounding (3D TORO) and
/// fixed flags ignored (TORO has none).
fn assert_close(a: &AnyGraph, b: &AnyGraph, relative: &str) {
    let (AnyGraph::Spatial(a), AnyGraph::Spatial(b)) = (a, b) else {
        panic!("{relative}: expected two 3D graphs")
    };
    assert_eq!(a.num_vertices(), b.num_vertices(), "{relative}");
    assert_eq!(a.num_edges(), b.num_edges(), "{relative}");
    let close = |p: &mapmerge_geometry::Se3, q: &mapmerge_geometry::Se3| {
        p.translation_m == q.translation_m && p.rotation.angle_to(&q.rotation) < 1e-9
    };
    for ((ia, va), (ib, vb)) in a.vertices().zip(b.vertices()) {
        assert!(
            ia == ib && close(&va.pose, &vb.pose),
            "{relative}: vertex {ia}"
        );
    }
    for ((ia, ea), (ib, eb)) in a.edges().zip(b.edges()) {
        assert_eq!(
            (ia, ea.from, ea.to, ea.kind),
            (ib, eb.from, eb.to, eb.kind),
            "{relative}"
        );
        assert_eq!(ea.information, eb.information, "{relative}: edge {ia}");
        assert!(
            close(&ea.measurement, &eb.measurement),
            "{relative}: edge {ia}"
        );
    }
}

#[test]
fn intel_first_edge_matches_the_file() {
    let Some(path) = mapmerge_testkit::shared_data("g2o/openslam_g2o/intel.g2o") else {
        return;
    };
    let LoadedGraph {
        graph: AnyGraph::Planar(g),
        ..
    } = load(&path)
    else {
        panic!("intel.g2o is 2D")
    };
    // First edge line: EDGE_SE2 0 1 -0.020000 0.010000 -0.000000 500 0 0 500 0 5000 … checked
    // against the file's text below, kind from the ids.
    let text = std::fs::read_to_string(&path).unwrap_or_default();
    let first_edge = text
        .lines()
        .find(|l| l.starts_with("EDGE_SE2"))
        .unwrap_or_default();
    let fields: Vec<f64> = first_edge
        .split_ascii_whitespace()
        .skip(1)
        .filter_map(|t| t.parse().ok())
        .collect();
    let (_, edge) = g.edges().next().unwrap_or_else(|| panic!("no edges"));
    assert_eq!(edge.from, NodeId(fields[0] as u64));
    assert_eq!(edge.to, NodeId(fields[1] as u64));
    assert_eq!(edge.measurement.x_m, fields[2]);
    assert_eq!(edge.information[(0, 0)], fields[5]);
    assert_eq!(edge.information[(2, 2)], fields[10]);
    let expected = if fields[1] == fields[0] + 1.0 {
        EdgeKind::Odometry
    } else {
        EdgeKind::Loop
    };
    assert_eq!(edge.kind, expected);
    let loops = g.edges().filter(|(_, e)| e.kind == EdgeKind::Loop).count();
    assert_eq!(
        loops,
        1837 - 942,
        "intel: every pose but the first has one odometry edge"
    );
}

#[test]
fn hog_man_sphere_matches_its_g2o_conversion() {
    // se-sync's sphere_bignoise_vertex3.g2o is the HOG-Man sphere_bignoise.graph converted to
    // quaternions; the TORO reader's roll/pitch/yaw convention must agree with it (to the
    // 3 significant digits of the TORO file).
    let Some(toro) = mapmerge_testkit::shared_data("g2o/hog-man/3D/sphere_bignoise.graph") else {
        return;
    };
    let Some(g2o) = mapmerge_testkit::shared_data("g2o/se-sync/sphere_bignoise_vertex3.g2o.xz")
    else {
        return;
    };
    let (AnyGraph::Spatial(a), AnyGraph::Spatial(b)) = (load(&toro).graph, load(&g2o).graph) else {
        panic!("both are 3D")
    };
    // TORO angles have 3 significant digits (rounding up to 5e-3 rad for |angle| > 1); a wrong
    // Euler convention would be off by up to radians.
    let mut angles: Vec<f64> = Vec::new();
    for ((ida, va), (idb, vb)) in a.vertices().zip(b.vertices()) {
        assert_eq!(ida, idb);
        angles.push(va.pose.rotation.angle_to(&vb.pose.rotation));
    }
    angles.sort_by(f64::total_cmp);
    let (median, worst) = (angles[angles.len() / 2], angles[angles.len() - 1]);
    assert!(
        median < 5e-3 && worst < 2e-2,
        "rotation differences: median {median}, worst {worst}"
    );
    // Information: TORO rotation 1000 on the diagonal, our order puts rotation first.
    let (_, edge) = a.edges().next().unwrap_or_else(|| panic!("no edges"));
    assert_eq!(edge.information[(0, 0)], 1000.0);
    assert_eq!(edge.information[(5, 5)], 1.0);
}
