"""read_log and slam: the log's own numbers, the CLI's trajectory, map and graph, its errors."""

import lzma

import numpy as np
import pytest

import mapmerge
from common import cli_error, cli_json, in_testdata, truncated_log

SESSION = in_testdata("sim/office-aliased/session_0.log.xz")


def read_tum(path):
    """(stamps, [x, y, yaw] rows) of a planar TUM file."""
    rows = np.loadtxt(path)
    yaw = np.arctan2(2 * (rows[:, 7] * rows[:, 6] + rows[:, 4] * rows[:, 5]),
                     1 - 2 * (rows[:, 5] ** 2 + rows[:, 6] ** 2))
    return rows[:, 0], np.column_stack([rows[:, 1], rows[:, 2], yaw])


def read_yaml_origin(path):
    for line in open(path):
        if line.startswith("origin:"):
            return [float(v) for v in line.split("[")[1].split("]")[0].split(",")]
    raise AssertionError(f"no origin in {path}")


def test_read_log_gives_the_scans_of_the_file():
    log = mapmerge.read_log(SESSION)
    lines = [l.split() for l in lzma.open(SESSION, "rt") if l.startswith("ROBOTLASER1")]
    assert log["ranges"].shape == (len(lines), 360) and log["ranges"].dtype == np.float32
    # ROBOTLASER1 type start fov resolution max_range accuracy remission_mode n ranges...
    # n_remissions laser_x laser_y laser_theta robot_x robot_y robot_theta ...
    for k in (0, len(lines) // 2, len(lines) - 1):
        fields = lines[k]
        n = int(fields[8])
        np.testing.assert_array_equal(log["ranges"][k], np.array(fields[9:9 + n], dtype=np.float32))
        assert log["angle_min"][k] == float(fields[2])
        assert log["range_max"][k] == pytest.approx(float(fields[5]))
        robot = [float(v) for v in fields[9 + n + 4:9 + n + 7]]
        np.testing.assert_allclose(log["odometry"][k], robot, atol=1e-12)
    assert log["stamps"].shape == (len(lines),) and np.all(np.diff(log["stamps"]) >= 0)
    np.testing.assert_array_equal(log["robot_from_sensor"], np.zeros((len(lines), 3)))


def test_slam_gives_the_clis_trajectory_map_and_graph(tmp_path):
    log = truncated_log(SESSION, tmp_path / "short.log", 500)
    result = mapmerge.slam(log)
    expected = cli_json("slam", log, "-o", tmp_path / "cli")
    assert result["scans"] == expected["scans"] == 500
    assert result["front_end"]["keyframes"] == expected["front_end"]["keyframes"]
    assert (result["graph_vertices"], result["graph_edges"]) == (
        expected["graph_vertices"], expected["graph_edges"])
    assert result["front_end"]["local_loops"] == expected["front_end"]["local_loops"] > 0
    stamps, poses = read_tum(tmp_path / "cli" / "trajectory.tum")
    assert result["trajectory"].shape == (500, 3)
    np.testing.assert_allclose(result["trajectory"][:, :2], poses[:, :2], atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (result["trajectory"][:, 2] - poses[:, 2]))), 0, atol=1e-9)
    np.testing.assert_array_equal(result["stamps"], stamps)
    # The map: the CLI's size and origin at 5 cm.
    assert result["grid_resolution_m"] == 0.05
    grid = result["grid"]
    origin = read_yaml_origin(tmp_path / "cli" / "map.yaml")
    assert result["grid_origin_m"] == pytest.approx(origin[:2])
    assert (grid > 0.65).sum() > 500 and (grid < 0.35).sum() > 5000
    # The graph is the CLI's graph.g2o.
    graph = mapmerge.read_graph(tmp_path / "cli" / "graph.g2o")
    np.testing.assert_array_equal(result["graph"].ids, graph.ids)
    np.testing.assert_allclose(result["graph"].poses, graph.poses, atol=1e-9)


def test_slam_errors_are_the_clis(tmp_path):
    empty = tmp_path / "odometry-only.log"
    empty.write_text("ODOM 1 2 0.5 0 0 0 10.0 host 10.0\n")
    with pytest.raises(mapmerge.BadInputError) as raised:
        mapmerge.slam(empty)
    assert str(raised.value) == f"{empty}: no laser scans"
    with pytest.raises(mapmerge.BadInputError, match=f"^{raised.value}$"):
        mapmerge.read_log(empty)
    assert cli_error("slam", empty, "-o", tmp_path / "out") == (2, str(raised.value))
    with pytest.raises(mapmerge.BadInputError) as raised:
        mapmerge.slam(SESSION, resolution=0.0)
    assert str(raised.value) == "--resolution must be a number of metres in [0.01, 100], got 0"
    assert cli_error("slam", SESSION, "-o", tmp_path / "out", "--resolution", "0") == (
        2, str(raised.value))


def test_a_bag_reads_and_maps_as_its_log(tmp_path):
    log = truncated_log(SESSION, tmp_path / "short.log", 300)
    bag = tmp_path / "short.mcap"
    cli_json("convert", log, "-o", bag)
    from_log, from_bag = mapmerge.read_log(log), mapmerge.read_log(bag)
    for key in ("odometry", "ranges", "angle_min", "angle_increment", "range_max", "robot_from_sensor"):
        np.testing.assert_array_equal(from_bag[key], from_log[key], err_msg=key)
    np.testing.assert_allclose(from_bag["stamps"], from_log["stamps"], atol=1e-6)
    np.testing.assert_array_equal(
        mapmerge.slam(bag)["trajectory"], mapmerge.slam(log)["trajectory"]
    )
    with pytest.raises(mapmerge.BadInputError) as raised:
        mapmerge.read_log(bag, scan_topic="/no_such_topic")
    assert str(bag) in str(raised.value)
    assert cli_error("slam", bag, "-o", tmp_path / "out", "--scan-topic", "/no_such_topic") == (
        2, str(raised.value))
