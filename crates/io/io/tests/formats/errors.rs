//! Malformed inputs: each gives the right error at the right line, and never a panic.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_geometry::Se2;
use mapmerge_io::{
    format_graph, parse_graph, read_graph, write_graph, write_tum, AnyGraph, GraphFormat, IoError,
};
use mapmerge_posegraph::{EdgeId, EdgeKind, NodeId};

const V01: &str = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n";
const INFO2: &str = "1 0 0 1 0 1";

/// Parses `text` expecting a parse error at `line` whose reason contains `needle`.
#[track_caller]
fn expect_error(text: &str, line: usize, needle: &str) {
    match parse_graph(text, "bad.g2o") {
        Err(IoError::Parse {
            file,
            line: got,
            reason,
        }) => {
            assert_eq!(file, "bad.g2o");
            assert_eq!((got, needle), (line, needle), "reason: {reason}");
            assert!(
                reason.contains(needle),
                "reason {reason:?} lacks {needle:?}"
            );
        }
        other => panic!("expected a parse error at line {line} ({needle}), got {other:?}"),
    }
}

#[test]
fn display_is_file_line_reason() {
    let err = parse_graph("# header\nVERTEX_SE2 0 0 0 zero\n", "graphs/a.g2o").unwrap_err();
    assert_eq!(
        err.to_string(),
        "graphs/a.g2o:2: field 4 `zero` is not a number"
    );
}

#[test]
fn truncated_lines() {
    expect_error(
        "VERTEX_SE2 0 0 0\n",
        1,
        "truncated VERTEX_SE2 line: expected 4 fields",
    );
    expect_error(
        &format!("{V01}EDGE_SE2 0 1 1 0 0 1 0 0 1 0\n"),
        3,
        "found 10",
    );
    expect_error(
        "VERTEX_SE3:QUAT 0 0 0 0 0 0 1\n",
        1,
        "truncated VERTEX_SE3:QUAT",
    );
    expect_error("VERTEX3 0 0 0 0 0 0\n", 1, "truncated VERTEX3");
    expect_error("VERTEX2 0 0 0 0\nEDGE2 0\n", 2, "truncated EDGE2");
    expect_error(&format!("{V01}FIX\n"), 3, "truncated FIX");
    // The last line may lack its newline.
    expect_error("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0", 2, "truncated");
}

#[test]
fn too_many_fields() {
    expect_error(
        "VERTEX_SE2 0 0 0 0 0\n",
        1,
        "too many fields on VERTEX_SE2 line: expected 4 after the tag, found 5",
    );
    expect_error(
        &format!("{V01}EDGE_SE2 0 1 1 0 0 {INFO2} 7\n"),
        3,
        "too many fields",
    );
    expect_error("VERTEX2 0 0 0 0\nVERTEX2 1 0 0 0 9 9\n", 2, "found 6");
}

#[test]
fn bad_numbers() {
    expect_error(
        "VERTEX_SE2 0 1.0.0 0 0\n",
        1,
        "field 2 `1.0.0` is not a number",
    );
    expect_error(
        "VERTEX_SE2 0 0 nan 0\n",
        1,
        "field 3 `nan` is not a finite number",
    );
    expect_error("VERTEX_SE2 0 0 0 inf\n", 1, "not a finite number");
    expect_error("VERTEX_SE2 0 1e999 0 0\n", 1, "not a finite number");
    expect_error(
        &format!("{V01}EDGE_SE2 0 1 1 0 0 1 0 0 1 0 NaN\n"),
        3,
        "field 11 `NaN`",
    );
    expect_error("VERTEX_SE2 x 0 0 0\n", 1, "field 1 `x` is not a vertex id");
    expect_error("VERTEX_SE2 1.5 0 0 0\n", 1, "not a vertex id");
    expect_error(
        "VERTEX_SE2 99999999999999999999999 0 0 0\n",
        1,
        "does not fit in 64 bits",
    );
}

#[test]
fn negative_ids() {
    expect_error("VERTEX_SE2 -1 0 0 0\n", 1, "negative vertex id `-1`");
    expect_error(
        &format!("{V01}EDGE_SE2 0 -1 1 0 0 {INFO2}\n"),
        3,
        "field 2: negative vertex id",
    );
    expect_error(&format!("{V01}FIX -3\n"), 3, "negative");
}

#[test]
fn unknown_tags_and_comments() {
    expect_error("FOO 1 2 3\n", 1, "unknown tag `FOO`");
    expect_error(
        &format!("{V01}\n# fine\n   \nVERTEX_XY 5 1 2\n"),
        6,
        "unknown tag `VERTEX_XY`",
    );
    let ok = format!("# comment\n\n  # indented comment\r\n{V01}\t\n#EDGE_SE2 broken\n");
    assert_eq!(parse_graph(&ok, "ok.g2o").unwrap().graph.num_vertices(), 2);
}

#[test]
fn crlf_line_endings_are_accepted() {
    let text = format!("{V01}EDGE_SE2 0 1 1 0 0 {INFO2}\n").replace('\n', "\r\n");
    assert_eq!(parse_graph(&text, "crlf.g2o").unwrap().graph.num_edges(), 1);
}

#[test]
fn duplicate_vertex() {
    expect_error(
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0 0 0\nVERTEX_SE2 0 1 1 1\n",
        3,
        "duplicate vertex id 0",
    );
    expect_error(
        "VERTEX3 4 0 0 0 0 0 0\nVERTEX3 4 0 0 0 0 0 0\n",
        2,
        "duplicate vertex id 4",
    );
}

#[test]
fn edges_to_missing_vertices() {
    let text = format!("{V01}EDGE_SE2 0 1 1 0 0 {INFO2}\nEDGE_SE2 1 7 1 0 0 {INFO2}\n");
    expect_error(
        &text,
        4,
        "edge 1 -> 7 refers to vertex 7, which no VERTEX_SE2 line defines",
    );
    // Vertices may come after edges: references are checked at the end.
    let late = format!("EDGE_SE2 0 1 1 0 0 {INFO2}\n{V01}");
    assert!(parse_graph(&late, "late.g2o").unwrap().had_vertices);
    expect_error(&format!("{V01}FIX 0 9\n"), 3, "FIX refers to vertex 9");
}

#[test]
fn self_loops() {
    expect_error(
        &format!("{V01}EDGE_SE2 1 1 0 0 0 {INFO2}\n"),
        3,
        "self-loop edge 1 -> 1",
    );
    expect_error(
        "VERTEX2 0 0 0 0\nEDGE2 0 0 1 0 0 1 0 1 1 0 0\n",
        2,
        "self-loop",
    );
}

#[test]
fn information_not_positive_definite() {
    let not_pd = "information matrix is not positive definite";
    expect_error(&format!("{V01}EDGE_SE2 0 1 1 0 0 0 0 0 0 0 0\n"), 3, not_pd);
    expect_error(
        &format!("{V01}EDGE_SE2 0 1 1 0 0 1 0 0 1 0 -5\n"),
        3,
        "Cholesky fails at row 3",
    );
    expect_error(&format!("{V01}EDGE_SE2 0 1 1 0 0 1 2 0 1 0 1\n"), 3, not_pd);
    // TORO order: I11 I12 I22 I33 I13 I23 — a zero I33 is singular.
    expect_error(
        "VERTEX2 0 0 0 0\nVERTEX2 1 0 0 0\nEDGE2 0 1 1 0 0 1 0 1 0 0 0\n",
        3,
        not_pd,
    );
    let mut info3 = vec!["0"; 21];
    for p in [0, 6, 11, 15, 18] {
        info3[p] = "1";
    }
    let text = format!(
        "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 0 0 0 0 0 0 1\n\
         EDGE_SE3:QUAT 0 1 0 0 0 0 0 0 1 {}\n",
        info3.join(" ")
    );
    // The missing entry is g2o's yaw; in our (ω, v) order it is row 3.
    expect_error(&text, 3, "Cholesky fails at row 3");
}

#[test]
fn mixing_dimensions_and_formats() {
    expect_error(
        &format!("{V01}VERTEX_SE3:QUAT 2 0 0 0 0 0 0 1\n"),
        3,
        "is 3D but the file is 2D",
    );
    expect_error(
        "VERTEX3 0 0 0 0 0 0 0\nEDGE2 0 1 1 0 0 1 0 1 1 0 0\n",
        2,
        "mixing 2D and 3D",
    );
    expect_error(
        &format!("{V01}VERTEX2 2 0 0 0\n"),
        3,
        "is TORO but the file is g2o",
    );
    expect_error("VERTEX2 0 0 0 0\nFIX 0\n", 2, "mixing formats");
}

#[test]
fn empty_files() {
    // A parameter line alone used to parse to an empty graph, which wrote an empty file.
    let params_only = "PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1\n";
    for text in ["", "\n\n", "# only a comment\n", "  \t \r\n", params_only] {
        match parse_graph(text, "empty.g2o") {
            Err(IoError::Empty { file }) => assert_eq!(file, "empty.g2o"),
            other => panic!("{text:?}: expected Empty, got {other:?}"),
        }
    }
    // FIX alone names a vertex that does not exist.
    assert!(matches!(
        parse_graph("FIX 0\n", "fix.g2o"),
        Err(IoError::Empty { .. })
    ));
}

#[test]
fn quaternions() {
    let v = |q: &str| format!("VERTEX_SE3:QUAT 0 1 2 3 {q}\n");
    expect_error(&v("0 0 0 0"), 1, "has norm 0, too far from 1");
    expect_error(&v("0 0 0 2"), 1, "too far from 1");
    // Slightly off is normalised.
    let loaded = parse_graph(&v("0 0 0.1 0.9955"), "q.g2o").unwrap();
    let AnyGraph::Spatial(g) = loaded.graph else {
        panic!("3D")
    };
    let q = g.vertex(NodeId(0)).unwrap().pose.rotation;
    assert!((q.quaternion().norm() - 1.0).abs() < 1e-15);
}

#[test]
fn g2o_priors_and_offsets() {
    let info = ["1"; 21].join(" ");
    let _ = info;
    let mut diag = vec!["0"; 21];
    for p in [0, 6, 11, 15, 18, 20] {
        diag[p] = "1";
    }
    let diag = diag.join(" ");
    let v = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n";
    expect_error(
        &format!("{v}EDGE_SE3_PRIOR 0 0 1 2 3 0 0 0 1 {diag}\n"),
        2,
        "no earlier PARAMS_SE3OFFSET",
    );
    expect_error(
        "PARAMS_SE3OFFSET 0 1 0 0 0 0 0 1\n",
        1,
        "only identity PARAMS_SE3OFFSET",
    );
    let ok =
        format!("{v}PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1\nEDGE_SE3_PRIOR 0 0 1 2 3 0 0 0 1 {diag}\n");
    let AnyGraph::Spatial(g) = parse_graph(&ok, "prior.g2o").unwrap().graph else {
        panic!("3D")
    };
    let (_, e) = g.edges().next().unwrap();
    assert_eq!(
        (e.from, e.to, e.kind),
        (NodeId(0), NodeId(0), EdgeKind::Prior)
    );
    let prior2 = format!("{V01}EDGE_PRIOR_SE2 1 5 6 0.5 {INFO2}\n");
    let AnyGraph::Planar(g) = parse_graph(&prior2, "prior.g2o").unwrap().graph else {
        panic!("2D")
    };
    let (_, e) = g.edges().next().unwrap();
    assert_eq!(
        (e.kind, e.measurement),
        (EdgeKind::Prior, Se2::new(5.0, 6.0, 0.5))
    );
}

#[test]
fn files_without_vertex_lines_get_identity_vertices() {
    let text = format!("EDGE_SE2 3 4 1 0 0 {INFO2}\nEDGE_SE2 0 3 1 0 0 {INFO2}\nFIX 0\n");
    let loaded = parse_graph(&text, "edges.g2o").unwrap();
    assert!(!loaded.had_vertices);
    let AnyGraph::Planar(g) = loaded.graph else {
        panic!("2D")
    };
    let ids: Vec<u64> = g.vertices().map(|(id, _)| id.0).collect();
    assert_eq!(ids, [0, 3, 4]);
    assert!(g.vertices().all(|(_, v)| v.pose == Se2::new(0.0, 0.0, 0.0)));
    assert!(g.vertex(NodeId(0)).unwrap().fixed);
    // Edge ids follow the file order, kinds follow the ids.
    let edges: Vec<(EdgeId, u64, u64, EdgeKind)> = g
        .edges()
        .map(|(id, e)| (id, e.from.0, e.to.0, e.kind))
        .collect();
    assert_eq!(
        edges,
        [
            (EdgeId(0), 3, 4, EdgeKind::Odometry),
            (EdgeId(1), 0, 3, EdgeKind::Loop)
        ]
    );
}

#[test]
fn extreme_ids_do_not_overflow() {
    let max = u64::MAX;
    let text = format!(
        "EDGE_SE2 {} {max} 1 0 0 {INFO2}\nEDGE_SE2 {max} 0 1 0 0 {INFO2}\n",
        max - 1
    );
    let AnyGraph::Planar(g) = parse_graph(&text, "max.g2o").unwrap().graph else {
        panic!("2D")
    };
    let kinds: Vec<EdgeKind> = g.edges().map(|(_, e)| e.kind).collect();
    assert_eq!(kinds, [EdgeKind::Odometry, EdgeKind::Loop]);
}

/// A fresh path in the system temp directory.
fn temp_path(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("mapmerge-io-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

#[test]
fn files_plain_and_xz_and_io_errors() {
    let text = format!("{V01}EDGE_SE2 0 1 1 0 0 {INFO2}\n");
    let graph = parse_graph(&text, "mem").unwrap().graph;
    for name in ["g.g2o", "g.g2o.xz", "g.graph", "g.graph.xz"] {
        let path = temp_path(name);
        let format = if name.contains("g2o") {
            GraphFormat::G2o
        } else {
            GraphFormat::Toro
        };
        write_graph(&path, &graph, format).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(
            bytes.starts_with(&[0xFD, b'7', b'z', b'X', b'Z']),
            name.ends_with(".xz")
        );
        let loaded = read_graph(&path).unwrap();
        assert_eq!((loaded.graph, loaded.format), (graph.clone(), format));
    }
    let tum = temp_path("g.tum");
    write_tum(&tum, &graph).unwrap();
    assert_eq!(
        std::fs::read_to_string(&tum).unwrap(),
        "0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n"
    );

    match read_graph(&temp_path("does-not-exist.g2o")) {
        Err(err @ IoError::Io { .. }) => assert!(err.to_string().contains("does-not-exist.g2o")),
        other => panic!("expected an I/O error, got {other:?}"),
    }
    let bad_utf8 = temp_path("bad-utf8.g2o");
    std::fs::write(&bad_utf8, b"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 \xff 0 0\n").unwrap();
    match read_graph(&bad_utf8) {
        Err(IoError::Parse { line, reason, .. }) => {
            assert_eq!((line, reason.as_str()), (2, "invalid UTF-8"))
        }
        other => panic!("expected a parse error, got {other:?}"),
    }
    let corrupt_xz = temp_path("corrupt.g2o.xz");
    let mut xz = std::fs::read(temp_path("g.g2o.xz")).unwrap();
    xz.truncate(xz.len() / 2);
    std::fs::write(&corrupt_xz, xz).unwrap();
    assert!(matches!(read_graph(&corrupt_xz), Err(IoError::Io { .. })));
    let _ = std::fs::remove_dir_all(temp_path("cleanup").parent().unwrap());
}

#[test]
fn writing_keeps_ids_and_order() {
    let text = format!(
        "VERTEX_SE2 5 0 0 0\nVERTEX_SE2 2 1 0 0\nFIX 5\nEDGE_SE2 5 2 1 0 0 {INFO2}\nEDGE_SE2 2 5 1 0 0 {INFO2}\n"
    );
    let graph = parse_graph(&text, "mem").unwrap().graph;
    let out = format_graph(&graph, GraphFormat::G2o).unwrap();
    assert_eq!(
        out,
        "VERTEX_SE2 2 1 0 0\nVERTEX_SE2 5 0 0 0\nFIX 5\n\
         EDGE_SE2 5 2 1 0 0 1 0 0 1 0 1\nEDGE_SE2 2 5 1 0 0 1 0 0 1 0 1\n"
    );
}

#[test]
fn writing_creates_missing_output_folders() {
    let text = format!("{V01}EDGE_SE2 0 1 1 0 0 {INFO2}\n");
    let graph = parse_graph(&text, "mem").unwrap().graph;
    // Its own folder: the other file tests remove theirs while this one runs.
    let root = std::env::temp_dir().join(format!("mapmerge-io-mkdir-{}", std::process::id()));
    let path = root.join("new/folder/out.g2o");
    write_graph(&path, &graph, GraphFormat::G2o).unwrap();
    assert_eq!(read_graph(&path).unwrap().graph, graph);
    let _ = std::fs::remove_dir_all(&root);
}
