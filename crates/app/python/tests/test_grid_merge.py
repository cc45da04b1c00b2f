"""grid_merge against the CLI: the same report, the merged grid, refusals and errors."""

import json

import numpy as np
import pytest

import mapmerge
from common import cli_error, cli_json, run_cli, shared_data, without_timings

FILES = ("merged", "png")


def read_pgm(path):
    """The pixels of a binary PGM (P5, 8 bits), top row first."""
    with open(path, "rb") as pgm:
        tokens = []
        while len(tokens) < 4:
            line = pgm.readline()
            if not line.startswith(b"#"):
                tokens += line.split()
        width, height = int(tokens[1]), int(tokens[2])
        return np.frombuffer(pgm.read(width * height), dtype=np.uint8).reshape(height, width)


def test_a_map_and_its_north_wing_merge_as_the_cli_merges_them(tmp_path):
    a = shared_data("gridmaps/utexas-gdc-1/1.yaml")
    b = shared_data("gridmaps/utexas-gdc-1n/1n.yaml")
    merged = mapmerge.grid_merge(a, b, output=tmp_path / "python.yaml")
    expected = cli_json("grid-merge", a, b, "-o", tmp_path / "cli.yaml")
    assert merged["accepted"] is True and merged["transform"] is not None
    report = {k: v for k, v in merged.items() if not k.startswith("grid") and k not in FILES}
    assert without_timings(report) == without_timings(
        {k: v for k, v in expected.items() if k not in FILES}
    )
    # The merged grid: A's resolution, the written map's size, probabilities with unknown 0.5.
    grid = merged["grid"]
    assert grid.dtype == np.float32 and merged["grid_resolution_m"] == merged["resolution_a_m"]
    # Its classes (0.65 / 0.35) are the pixels of the map the CLI wrote (map_saver's
    # trinary values: occupied 0, free 254, unknown 205; the image's top row is the grid's last).
    pixels = read_pgm(tmp_path / "cli.pgm")[::-1]
    assert grid.shape == pixels.shape
    classes = np.where(grid >= 0.65, 0, np.where(grid <= 0.35, 254, 205))
    np.testing.assert_array_equal(classes, pixels)
    assert (pixels == 0).sum() > 1000 and (pixels == 254).sum() > 1000
    # The written files are the CLI's.
    assert (tmp_path / "python.pgm").read_bytes() == (tmp_path / "cli.pgm").read_bytes()
    assert (tmp_path / "python.png").read_bytes() == (tmp_path / "cli.png").read_bytes()
    # Without `output` nothing is written and the grid is the same.
    alone = mapmerge.grid_merge(a, b)
    assert alone["merged"] is None and alone["png"] is None
    np.testing.assert_array_equal(alone["grid"], grid)


def test_two_floors_are_not_merged_and_say_why(tmp_path):
    a = shared_data("gridmaps/utexas-gdc-1n/1n.yaml")
    b = shared_data("gridmaps/utexas-gdc-1s/1s.yaml")
    merged = mapmerge.grid_merge(a, b, hypotheses=2)
    assert merged["accepted"] is False and merged["grid"] is None
    assert merged["reason"].startswith("not accepted")
    assert len(merged["hypotheses"]) <= 2
    code, out, _ = run_cli("grid-merge", a, b, "-o", tmp_path / "m.yaml", "--json", "--hypotheses", "2")
    assert code == 3
    expected = json.loads(out)
    assert merged["reason"] == expected["reason"]
    assert merged["transform"] == expected["transform"]


def test_a_missing_map_raises_the_clis_message(tmp_path):
    good = shared_data("gridmaps/utexas-gdc-1/1.yaml")
    missing = tmp_path / "missing.yaml"
    with pytest.raises(mapmerge.BadInputError) as raised:
        mapmerge.grid_merge(good, missing)
    assert str(raised.value) == f"{missing}: cannot read or write the file: No such file or directory (os error 2)"
    assert cli_error("grid-merge", good, missing, "-o", tmp_path / "m.yaml") == (2, str(raised.value))
