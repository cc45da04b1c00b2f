"""read_graph, write_graph, Graph.with_poses and optimize against the file and the CLI."""

import numpy as np
import pytest

import mapmerge
from common import cli_error, cli_json, in_testdata, shared_data, without_timings


def vertex_lines(path):
    """The `VERTEX_SE2 id x y yaw` lines of a plain g2o file, as {id: [x, y, yaw]}."""
    rows = {}
    for line in open(path):
        fields = line.split()
        if fields and fields[0] == "VERTEX_SE2":
            rows[int(fields[1])] = [float(v) for v in fields[2:5]]
    return rows


def test_read_graph_gives_the_files_ids_poses_and_edges():
    path = shared_data("g2o/openslam_g2o/intel.g2o")
    graph = mapmerge.read_graph(path)
    assert (graph.dimension, graph.format, len(graph)) == (2, "g2o", 943)
    assert graph.poses.shape == (943, 3) and graph.poses.dtype == np.float64
    assert graph.edges.shape == (1837, 2) and graph.num_edges == 1837
    in_file = vertex_lines(path)
    assert list(graph.ids) == sorted(in_file)
    np.testing.assert_array_equal(graph.poses, np.array([in_file[i] for i in sorted(in_file)]))
    first_edge = next(l.split() for l in open(path) if l.startswith("EDGE_SE2"))
    assert list(graph.edges[0]) == [int(first_edge[1]), int(first_edge[2])]
    assert graph.source == str(path)


def test_read_graph_reads_3d_graphs_with_unit_quaternions():
    graph = mapmerge.read_graph(shared_data("g2o/se-sync/smallGrid3D.g2o"))
    assert graph.dimension == 3 and graph.poses.shape == (len(graph), 7)
    np.testing.assert_allclose(np.linalg.norm(graph.poses[:, 3:], axis=1), 1.0, atol=1e-9)


def test_write_graph_round_trips_and_converts_formats(tmp_path):
    graph = mapmerge.read_graph(in_testdata("sim_manhattan_500.g2o"))
    mapmerge.write_graph(tmp_path / "again.g2o", graph)
    again = mapmerge.read_graph(tmp_path / "again.g2o")
    np.testing.assert_array_equal(again.poses, graph.poses)
    np.testing.assert_array_equal(again.edges, graph.edges)
    mapmerge.write_graph(tmp_path / "toro.graph", graph, "toro")
    assert open(tmp_path / "toro.graph").readline().startswith("VERTEX2 ")
    toro = mapmerge.read_graph(tmp_path / "toro.graph")
    assert toro.format == "toro"
    np.testing.assert_array_equal(toro.poses, graph.poses)
    with pytest.raises(mapmerge.BadInputError, match="possible values are g2o, toro"):
        mapmerge.write_graph(tmp_path / "x", graph, "tum")


def test_with_poses_replaces_the_poses_and_keeps_the_edges():
    graph = mapmerge.read_graph(in_testdata("sim_manhattan_500.g2o"))
    optimized, report = mapmerge.optimize(graph)
    moved = graph.with_poses(optimized.poses)
    np.testing.assert_array_equal(moved.poses, optimized.poses)
    # Scored without optimising, the new poses have the optimum's chi2.
    _, scored = mapmerge.optimize(moved, init="none", max_iterations=0)
    assert scored["initial_chi2"] == pytest.approx(report["final_chi2"], rel=1e-9)
    assert scored["initial_chi2"] < 0.5 * report["initial_chi2"]
    with pytest.raises(mapmerge.BadInputError, match=r"poses must have shape \(500, 3\)"):
        graph.with_poses(np.zeros((3, 3)))


def test_optimize_gives_the_clis_report_and_file(tmp_path):
    path = shared_data("g2o/openslam_g2o/intel.g2o")
    ours = tmp_path / "python.g2o"
    optimized, report = mapmerge.optimize(mapmerge.read_graph(path), output=ours)
    theirs = tmp_path / "cli.g2o"
    expected = cli_json("optimize", path, "-o", theirs)
    for r in (report, expected):
        r["output"] = None
    assert without_timings(report) == without_timings(expected)
    assert ours.read_bytes() == theirs.read_bytes()
    np.testing.assert_array_equal(optimized.poses, mapmerge.read_graph(theirs).poses)
    assert report["final_chi2"] < report["initial_chi2"]


def test_gnc_with_global_init_rejects_a_false_loop_as_the_cli_does(tmp_path):
    # The simulated Manhattan graph with one false loop closure appended (edge index 757).
    text = open(in_testdata("sim_manhattan_500.g2o")).read()
    corrupted = tmp_path / "corrupted.g2o"
    corrupted.write_text(text + "EDGE_SE2 10 400 25 -12 2.5 100 0 0 100 0 400\n")
    optimized, report = mapmerge.optimize(corrupted, robust="gnc", init="global")
    assert [e["edge"] for e in report["rejected_edges"]] == [757]
    assert report["rejected_edges"][0]["from"] == 10 and report["gnc_steps"] > 0
    expected = cli_json(
        "optimize", corrupted, "-o", tmp_path / "cli.g2o", "--robust", "gnc", "--init", "global"
    )
    report["output"] = expected["output"] = None
    assert without_timings(report) == without_timings(expected)
    np.testing.assert_array_equal(
        optimized.poses, mapmerge.read_graph(tmp_path / "cli.g2o").poses
    )


def test_errors_raise_the_clis_messages(tmp_path):
    missing = tmp_path / "missing.g2o"
    with pytest.raises(mapmerge.BadInputError) as raised:
        mapmerge.read_graph(missing)
    assert str(raised.value) == f"{missing}: cannot read or write the file: No such file or directory (os error 2)"
    assert isinstance(raised.value, ValueError) and isinstance(raised.value, mapmerge.MapmergeError)
    assert cli_error("optimize", missing, "-o", tmp_path / "o.g2o") == (2, str(raised.value))

    bad = tmp_path / "bad.g2o"
    bad.write_text("VERTEX_SE2 0 0 0\n")
    with pytest.raises(mapmerge.BadInputError) as raised:
        mapmerge.optimize(bad)
    assert str(raised.value) == f"{bad}:1: truncated VERTEX_SE2 line: expected 4 fields after the tag, found 3"
    assert cli_error("optimize", bad, "-o", tmp_path / "o.g2o") == (2, str(raised.value))

    # A file that cannot be written is bad input too (issue 67); the CLI refuses it before
    # the work, naming what is in the way.
    graph_path = in_testdata("sim_manhattan_500.g2o")
    graph = mapmerge.read_graph(graph_path)
    (tmp_path / "a-file").write_text("")
    unwritable = tmp_path / "a-file" / "out.g2o"
    with pytest.raises(mapmerge.BadInputError) as raised:
        mapmerge.write_graph(unwritable, graph)
    assert str(raised.value).startswith(f"{unwritable}: cannot read or write the file: ")
    with pytest.raises(mapmerge.BadInputError) as from_optimize:
        mapmerge.optimize(graph, output=unwritable)
    assert str(from_optimize.value) == str(raised.value)
    code, message = cli_error("optimize", graph_path, "-o", unwritable)
    assert code == 2 and message.endswith(f"{tmp_path / 'a-file'} is a file"), message
    with pytest.raises(mapmerge.BadInputError, match="invalid value 'tls' for robust"):
        mapmerge.optimize(graph, robust="tls")
    with pytest.raises(TypeError):
        mapmerge.optimize(42)
