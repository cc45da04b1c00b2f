"""Helpers of the Python tests: the public data sets, the repository's testdata, the CLI.

As the Rust tests (mapmerge-testkit): the data folder is $MAPMERGE_DATA, else ../shared/data
beside the checkout; without it a test skips with the reason, except under CI=true, where it
fails. The `mapmerge` binary the tests compare against is $MAPMERGE_BIN, else
$CARGO_TARGET_DIR/release/mapmerge, else target/release/mapmerge (what `cargo test --release`
builds); the same rule applies when it is missing.
"""

import json
import lzma
import os
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[4]


def _missing(why):
    if os.environ.get("CI") == "true":
        pytest.fail(f"{why}; under CI=true the data tests must run")
    pytest.skip(why)


def shared_data(relative):
    """A file below the data folder (skips without the folder, fails under CI)."""
    folder = Path(os.environ.get("MAPMERGE_DATA", REPO.parent / "shared" / "data"))
    if not folder.is_dir():
        _missing(f"data folder {folder} not found (set MAPMERGE_DATA)")
    path = folder / relative
    assert path.exists(), f"{path} is missing from the data folder"
    return path


def in_testdata(relative):
    """A file of the repository's testdata/."""
    return REPO / "testdata" / relative


def cli_binary():
    """The `mapmerge` binary (skips without it, fails under CI)."""
    candidates = []
    if os.environ.get("MAPMERGE_BIN"):
        candidates.append(Path(os.environ["MAPMERGE_BIN"]))
    if os.environ.get("CARGO_TARGET_DIR"):
        candidates.append(Path(os.environ["CARGO_TARGET_DIR"]) / "release" / "mapmerge")
    candidates.append(REPO / "target" / "release" / "mapmerge")
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    _missing(f"no mapmerge binary at {', '.join(map(str, candidates))} (set MAPMERGE_BIN)")


def run_cli(*args):
    """Runs the CLI: (exit code, stdout, stderr)."""
    done = subprocess.run(
        [str(cli_binary()), *map(str, args)], capture_output=True, text=True, check=False
    )
    return done.returncode, done.stdout, done.stderr


def cli_json(*args):
    """Runs the CLI with --json, asserts success, returns its report."""
    code, out, err = run_cli(*args, "--json")
    assert code == 0, f"mapmerge {args} failed: {err}"
    return json.loads(out)


def cli_error(*args):
    """Runs the CLI expecting a failure: (exit code, the message after `mapmerge: error: `)."""
    code, _, err = run_cli(*args)
    assert code != 0, f"mapmerge {args} did not fail"
    line = [l for l in err.splitlines() if l.startswith("mapmerge: error: ")][-1]
    return code, line[len("mapmerge: error: "):]


TIMINGS = {
    "seconds",
    "load_seconds",
    "init_seconds",
    "optimize_seconds",
    "match_seconds",
    "elapsed_secs",
    "trajectory_secs",
    "association_secs",
    "optimisation_secs",
    "prepare_secs",
    "grouping_secs",
}


def without_timings(value):
    """A report with every wall time set to None (they differ from run to run)."""
    if isinstance(value, dict):
        return {k: None if k in TIMINGS else without_timings(v) for k, v in value.items()}
    if isinstance(value, list):
        return [without_timings(v) for v in value]
    return value


def truncated_log(source, target, scans):
    """Writes the first `scans` scans of a CARMEN log (plain or xz) to `target`."""
    opener = lzma.open if str(source).endswith(".xz") else open
    kept, seen = [], 0
    with opener(source, "rt") as lines:
        for line in lines:
            if line.startswith(("ROBOTLASER1", "FLASER", "RLASER", "RAWLASER")):
                if seen == scans:
                    break
                seen += 1
            kept.append(line)
    Path(target).write_text("".join(kept))
    return Path(target)
