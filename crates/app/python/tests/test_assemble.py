"""assemble: three segments of the look-alike office group, loop and place as the CLI's."""

import json

import numpy as np
import pytest

import mapmerge
from common import cli_error, cli_json, in_testdata, truncated_log, without_timings


def segments(folder):
    """Session 0, and sessions 1 and 2 up to their kidnaps (scans 806 and 519)."""
    office = "sim/office-aliased/session_{}.log.xz"
    return [
        truncated_log(in_testdata(office.format(0)), folder / "a.log", 10**9),
        truncated_log(in_testdata(office.format(1)), folder / "b.log", 800),
        truncated_log(in_testdata(office.format(2)), folder / "c.log", 500),
    ]


def read_tum_xy(path):
    rows = np.loadtxt(path)
    return rows[:, 1:3]


def test_segments_assemble_as_the_cli_assembles_them(tmp_path):
    paths = segments(tmp_path)
    result = mapmerge.assemble(paths, order="random", seed=3, trajectory="odometry")
    expected = cli_json(
        "assemble", *paths, "-o", tmp_path / "cli", "--no-pictures", "--order", "random",
        "--seed", "3", "--trajectory", "odometry",
    )
    # a and c see the same rooms; b does not (before its kidnap).
    assert [g["segments"] for g in result["groups"]] == [["a", "c"], ["b"]]
    assert result["loops"] == len(result["loop_edges"]) > 5
    for group in expected["groups"]:
        del group["picture"]
    for key in ("segments", "order", "seed", "trajectory", "arrivals", "groups", "loops",
                "pairs_associated"):
        assert without_timings(result[key]) == without_timings(expected[key]), key
    lines = [json.loads(l) for l in open(tmp_path / "cli" / "loops.jsonl")]
    assert result["loop_edges"] == lines
    assert {e["from"]["segment"] + e["to"]["segment"] for e in lines} == {"ac"}
    for name, count in (("a", 1201), ("b", 800), ("c", 500)):
        assert result["poses"][name].shape == (count, 3)
        assert result["stamps"][name].shape == (count,)
        np.testing.assert_allclose(
            result["poses"][name][:, :2], read_tum_xy(tmp_path / "cli" / "poses" / f"{name}.tum"),
            atol=1e-9,
        )


def test_two_segments_of_one_name_are_bad_input(tmp_path):
    (tmp_path / "x").mkdir()
    first = truncated_log(in_testdata("sim/office-aliased/session_0.log.xz"), tmp_path / "a.log", 50)
    second = truncated_log(first, tmp_path / "x" / "a.log", 50)
    with pytest.raises(mapmerge.BadInputError) as raised:
        mapmerge.assemble([first, second])
    assert str(raised.value) == f"{first} and {second} have the same name `a`"
    assert cli_error("assemble", first, second, "-o", tmp_path / "out") == (2, str(raised.value))
    with pytest.raises(mapmerge.BadInputError, match="invalid value 'sorted' for order"):
        mapmerge.assemble([first], order="sorted")
