//! Integration tests of `mapmerge simulate`, `corrupt` and `compare` (the binary itself).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use mapmerge_io::{read_graph, AnyGraph};
use mapmerge_posegraph::{EdgeId, EdgeKind};

use crate::common::{ok_json, p, run, scratch, testdata};

fn planar(path: &Path) -> mapmerge_posegraph::PoseGraph2 {
    match read_graph(path).unwrap().graph {
        AnyGraph::Planar(g) => g,
        AnyGraph::Spatial(_) => panic!("{} is 3D", path.display()),
    }
}

/// The shared data directory, or `None` (with the reason printed) when it is absent outside CI.
fn data_dir() -> Option<PathBuf> {
    mapmerge_testkit::shared_data_dir()
}

#[test]
fn simulate_is_reproducible_and_writes_ground_truth() {
    let dir = scratch("simulate");
    let (a, b, c, gt) = (
        dir.join("a.g2o"),
        dir.join("b.g2o"),
        dir.join("c.g2o"),
        dir.join("gt.g2o"),
    );
    let report = ok_json(&[
        "simulate",
        "-o",
        p(&a),
        "--ground-truth",
        p(&gt),
        "--poses",
        "300",
        "--seed",
        "5",
        "--json",
    ]);
    ok_json(&[
        "simulate",
        "-o",
        p(&b),
        "--poses",
        "300",
        "--seed",
        "5",
        "--json",
    ]);
    ok_json(&[
        "simulate",
        "-o",
        p(&c),
        "--poses",
        "300",
        "--seed",
        "6",
        "--json",
    ]);
    let (ta, tb, tc) = (
        std::fs::read_to_string(&a).unwrap(),
        std::fs::read_to_string(&b).unwrap(),
        std::fs::read_to_string(&c).unwrap(),
    );
    assert_eq!(ta, tb);
    assert_ne!(ta, tc);
    let (noisy, truth) = (planar(&a), planar(&gt));
    assert_eq!(noisy.num_vertices(), 300);
    assert_eq!(report["vertices"], 300);
    assert_eq!(report["edges"], noisy.num_edges());
    assert_eq!(truth.num_edges(), noisy.num_edges());
    let loops = report["loop_closures"].as_u64().unwrap();
    assert!(loops > 30, "{loops} loop closures");
    assert_eq!(noisy.num_edges() as u64, 299 + loops);
    // chi2 at the truth is about 3 per edge; the drifting initial guess is far worse.
    let e = noisy.num_edges() as f64;
    assert!((truth.chi2() - 3.0 * e).abs() < 5.0 * (6.0 * e).sqrt());
    assert!(noisy.chi2() > 20.0 * truth.chi2());
}

#[test]
fn checked_in_testdata_is_what_simulate_writes() {
    let dir = scratch("testdata");
    let (out, gt) = (dir.join("sim.g2o"), dir.join("truth.g2o"));
    ok_json(&[
        "simulate",
        "-o",
        p(&out),
        "--ground-truth",
        p(&gt),
        "--json",
    ]);
    let same = |a: &Path, b: &Path| std::fs::read(a).unwrap() == std::fs::read(b).unwrap();
    assert!(
        same(&out, &testdata("sim_manhattan_500.g2o")),
        "regenerate testdata (see README)"
    );
    assert!(same(&gt, &testdata("sim_manhattan_500_truth.g2o")));
}

#[test]
fn corrupt_appends_the_reported_false_edges() {
    let dir = scratch("corrupt");
    let (out, again, list) = (dir.join("c.g2o"), dir.join("c2.g2o"), dir.join("false.txt"));
    let input = testdata("sim_manhattan_500.g2o");
    let original = planar(&input);
    let true_loops = original
        .edges()
        .filter(|(_, e)| e.kind != EdgeKind::Odometry)
        .count() as u64;
    let report = ok_json(&[
        "corrupt",
        p(&input),
        "-o",
        p(&out),
        "--outlier-fraction",
        "0.2",
        "--seed",
        "3",
        "--false-edges",
        p(&list),
        "--json",
    ]);
    assert_eq!(report["true_loops"], true_loops);
    assert_eq!(report["original_edges"], original.num_edges());
    let expected_false = (0.2 / 0.8 * true_loops as f64).round() as u64;
    assert_eq!(report["false_loops"], expected_false);
    let false_edges: Vec<u64> = report["false_edges"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    assert_eq!(false_edges.len() as u64, expected_false);
    let listed: Vec<u64> = std::fs::read_to_string(&list)
        .unwrap()
        .lines()
        .map(|l| l.parse().unwrap())
        .collect();
    assert_eq!(listed, false_edges);

    let corrupted = planar(&out);
    assert_eq!(
        corrupted.num_edges() as u64,
        original.num_edges() as u64 + expected_false
    );
    // Everything before the false edges is unchanged; they are loop closures.
    for (id, e) in original.edges() {
        let c = corrupted.edge(id).unwrap();
        assert_eq!((c.from, c.to, c.kind), (e.from, e.to, e.kind));
    }
    for (k, index) in false_edges.iter().enumerate() {
        assert_eq!(*index, original.num_edges() as u64 + k as u64);
        let e = corrupted.edge(EdgeId(*index)).unwrap();
        assert_eq!(e.kind, EdgeKind::Loop);
        assert!(e.to.0 >= e.from.0 + 2);
    }
    // Same seed, same file.
    ok_json(&[
        "corrupt",
        p(&input),
        "-o",
        p(&again),
        "--outlier-fraction",
        "0.2",
        "--seed",
        "3",
        "--json",
    ]);
    assert_eq!(std::fs::read(&out).unwrap(), std::fs::read(&again).unwrap());
}

#[test]
fn corrupt_converts_formats_with_fraction_zero() {
    let dir = scratch("convert");
    let (toro, back) = (dir.join("g.graph"), dir.join("back.g2o"));
    let input = testdata("sim_manhattan_500.g2o");
    let r = ok_json(&[
        "corrupt",
        p(&input),
        "-o",
        p(&toro),
        "--outlier-fraction",
        "0",
        "--format",
        "toro",
        "--json",
    ]);
    assert_eq!(r["false_loops"], 0);
    assert!(std::fs::read_to_string(&toro)
        .unwrap()
        .starts_with("VERTEX2 "));
    ok_json(&[
        "corrupt",
        p(&toro),
        "-o",
        p(&back),
        "--outlier-fraction",
        "0",
        "--format",
        "g2o",
        "--json",
    ]);
    let (a, b) = (planar(&input), planar(&back));
    assert_eq!(a.num_edges(), b.num_edges());
    assert_eq!(a.num_vertices(), b.num_vertices());
    for (id, vertex) in a.vertices() {
        let back = b.vertex(id).unwrap().pose;
        assert!((vertex.pose.translation() - back.translation()).norm() < 1e-9);
        assert!((vertex.pose.theta_rad - back.theta_rad).abs() < 1e-9);
    }
}

#[test]
fn compare_reports_zero_for_identical_graphs_and_alignment_helps() {
    let dir = scratch("compare");
    let moved = dir.join("moved.g2o");
    let truth = testdata("sim_manhattan_500_truth.g2o");
    let r = ok_json(&["compare", p(&truth), p(&truth), "--json"]);
    assert_eq!(r["matched"], 500);
    assert!(r["rms_m"].as_f64().unwrap() < 1e-12);
    // A rigidly moved copy: large error without alignment, none with it.
    let mut g = planar(&truth);
    let motion = mapmerge_geometry::Se2::new(3.0, -2.0, 0.7);
    for (_, v) in g.vertices_mut() {
        v.pose = mapmerge_geometry::LieGroup::compose(&motion, &v.pose);
    }
    mapmerge_io::write_graph(&moved, &AnyGraph::Planar(g), mapmerge_io::GraphFormat::G2o).unwrap();
    let raw = ok_json(&["compare", p(&truth), p(&moved), "--json"]);
    let aligned = ok_json(&["compare", p(&truth), p(&moved), "--align", "--json"]);
    assert!(raw["rms_m"].as_f64().unwrap() > 1.0);
    assert!(aligned["rms_m"].as_f64().unwrap() < 1e-9, "{aligned}");
    assert_eq!(aligned["aligned"], true);
}

#[test]
fn optimizing_the_simulated_graph_approaches_the_truth() {
    let dir = scratch("e2e");
    let out = dir.join("opt.g2o");
    let input = testdata("sim_manhattan_500.g2o");
    let truth = testdata("sim_manhattan_500_truth.g2o");
    let opt = ok_json(&["optimize", p(&input), "-o", p(&out), "--json"]);
    assert!(opt["final_chi2"].as_f64().unwrap() < opt["initial_chi2"].as_f64().unwrap());
    let before = ok_json(&["compare", p(&truth), p(&input), "--align", "--json"]);
    let after = ok_json(&["compare", p(&truth), p(&out), "--align", "--json"]);
    let (b, a) = (
        before["rms_m"].as_f64().unwrap(),
        after["rms_m"].as_f64().unwrap(),
    );
    assert!(a < 0.25 && a < b / 5.0, "RMS {b} m before, {a} m after");
}

#[test]
fn gnc_rejects_the_false_loop_closures() {
    let dir = scratch("gnc");
    let (bad, out) = (dir.join("bad.g2o"), dir.join("out.g2o"));
    let input = testdata("sim_manhattan_500.g2o");
    let c = ok_json(&[
        "corrupt",
        p(&input),
        "-o",
        p(&bad),
        "--outlier-fraction",
        "0.3",
        "--seed",
        "1",
        "--json",
    ]);
    let false_edges: Vec<EdgeId> = c["false_edges"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| EdgeId(v.as_u64().unwrap()))
        .collect();
    let o = ok_json(&[
        "optimize",
        p(&bad),
        "-o",
        p(&out),
        "--robust",
        "gnc",
        "--json",
    ]);
    let rejected: Vec<EdgeId> = o["rejected_edges"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| EdgeId(v["edge"].as_u64().unwrap()))
        .collect();
    let rejected: BTreeSet<EdgeId> = rejected.into_iter().collect();
    let false_edges: BTreeSet<EdgeId> = false_edges.into_iter().collect();
    let caught = rejected.intersection(&false_edges).count() as f64;
    let (precision, recall) = (
        caught / rejected.len() as f64,
        caught / false_edges.len() as f64,
    );
    assert!(recall > 0.95 && precision > 0.9, "{precision} {recall}");
}

#[test]
fn malformed_or_missing_input_exits_with_2() {
    let dir = scratch("bad");
    let bad = dir.join("bad.g2o");
    std::fs::write(
        &bad,
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0\nEDGE_SE2 0 1 1 0 0\n",
    )
    .unwrap();
    let good = testdata("sim_manhattan_500_truth.g2o");
    let out = dir.join("out.g2o");
    let missing = dir.join("does-not-exist.g2o");
    let cases: Vec<Vec<&str>> = vec![
        vec![
            "corrupt",
            p(&bad),
            "-o",
            p(&out),
            "--outlier-fraction",
            "0.1",
        ],
        vec![
            "corrupt",
            p(&missing),
            "-o",
            p(&out),
            "--outlier-fraction",
            "0.1",
        ],
        vec![
            "corrupt",
            p(&good),
            "-o",
            p(&out),
            "--outlier-fraction",
            "1.0",
        ],
        vec![
            "corrupt",
            p(&good),
            "-o",
            p(&out),
            "--outlier-fraction",
            "-0.5",
        ],
        vec!["compare", p(&bad), p(&good)],
        vec!["compare", p(&good), p(&bad)],
        vec!["compare", p(&good), p(&missing)],
        vec!["simulate", "-o", p(&out), "--poses", "1"],
        vec!["simulate", "-o", p(&out), "--sigma-xy-m", "0"],
        vec!["corrupt", p(&good), "-o", p(&out)], // missing required --outlier-fraction
    ];
    for args in cases {
        let o = run(&args);
        assert_eq!(
            o.status.code(),
            Some(2),
            "mapmerge {args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(!o.stderr.is_empty());
    }
    assert!(!out.exists(), "nothing is written on bad input");
}

#[test]
fn compare_rejects_disjoint_ids_and_mixed_dimensions() {
    let dir = scratch("disjoint");
    let (a, b, c) = (dir.join("a.g2o"), dir.join("b.g2o"), dir.join("c.g2o"));
    std::fs::write(&a, "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n").unwrap();
    std::fs::write(&b, "VERTEX_SE2 5 0 0 0\nVERTEX_SE2 6 1 0 0\n").unwrap();
    std::fs::write(&c, "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n").unwrap();
    for args in [["compare", p(&a), p(&b)], ["compare", p(&a), p(&c)]] {
        assert_eq!(run(&args).status.code(), Some(2), "{args:?}");
    }
}

#[test]
fn corrupt_m3500_adds_the_documented_number_of_outliers() {
    let Some(data) = data_dir() else { return };
    let dir = scratch("m3500");
    let out = dir.join("m3500_bad.g2o");
    let input = data.join("g2o/openslam_g2o/manhattanOlson3500.g2o");
    let r = ok_json(&[
        "corrupt",
        p(&input),
        "-o",
        p(&out),
        "--outlier-fraction",
        "0.1",
        "--seed",
        "42",
        "--json",
    ]);
    // 5598 edges: 3499 odometry + 2099 loop closures; 2099 / 9 = 233.2 -> 233.
    assert_eq!(r["original_edges"], 5598);
    assert_eq!(r["true_loops"], 2099);
    assert_eq!(r["false_loops"], 233);
    assert_eq!(planar(&out).num_edges(), 5598 + 233);
}

#[test]
fn corrupt_initialises_files_without_vertices() {
    let Some(data) = data_dir() else { return };
    let dir = scratch("novertex");
    let out = dir.join("csail_bad.g2o");
    let input = data.join("g2o/se-sync/CSAIL.g2o");
    ok_json(&[
        "corrupt",
        p(&input),
        "-o",
        p(&out),
        "--outlier-fraction",
        "0.1",
        "--json",
    ]);
    let g = planar(&out);
    // Odometry-chained, not all at the identity: the odometry edges fit exactly.
    let odo: Vec<_> = g
        .edges()
        .filter(|(_, e)| e.kind == EdgeKind::Odometry)
        .collect();
    assert!(!odo.is_empty());
    let fitting = odo
        .iter()
        .filter(|(_, e)| g.edge_chi2(e).unwrap() < 1e-6)
        .count();
    assert!(
        fitting as f64 >= 0.95 * odo.len() as f64,
        "{fitting} of {} fit",
        odo.len()
    );
}
