"""Atlas: two simulated sessions of the look-alike office fed scan by scan merge as the CLI's
`atlas` merges them, with the same events."""

import json

import numpy as np
import pytest

import mapmerge
from common import in_testdata, run_cli, truncated_log

# Session 2 re-enters session 0's map early: the CLI merges it conditionally at scan 1424 and
# fully at 1444 (scans 223 and 243 of session 2); its kidnap comes at scan 519.
SCANS_OF_SESSION_2 = 350


def feed(atlas, log):
    """Feeds a session as `mapmerge atlas` does (a scan without odometry reuses the last)."""
    previous = np.zeros(3)
    for k in range(len(log["stamps"])):
        odometry = log["odometry"][k]
        odometry = previous if np.isnan(odometry).any() else odometry
        previous = odometry
        atlas.add_scan(
            odometry,
            log["ranges"][k],
            angle_min=log["angle_min"][k],
            angle_increment=log["angle_increment"][k],
            range_min=log["range_min"][k],
            range_max=log["range_max"][k],
            robot_from_sensor=log["robot_from_sensor"][k],
            stamp=log["stamps"][k],
        )


def test_two_sessions_merge_as_the_cli_merges_them(tmp_path):
    first = in_testdata("sim/office-aliased/session_0.log.xz")
    second = truncated_log(
        in_testdata("sim/office-aliased/session_2.log.xz"), tmp_path / "s2.log", SCANS_OF_SESSION_2
    )
    atlas = mapmerge.Atlas()
    assert atlas.robot_pose is None and atlas.epoch == 0
    feed(atlas, mapmerge.read_log(first))
    assert atlas.epoch == 0 and atlas.merges == [] and atlas.scans == 1201
    ended = atlas.end_epoch("restart")
    # The epoch ends and the next starts; hypotheses still open are dropped with it.
    epochs = [e for e in ended if e["event"].startswith("epoch_")]
    assert [(e["event"], e["epoch"], e["scan"]) for e in epochs] == [
        ("epoch_ended", 0, 1201),
        ("epoch_started", 1, 1201),
    ]
    assert all(e["event"] == "dropped" and e["scan"] == 1201 for e in ended if e not in epochs)
    assert epochs[0]["reason"] == "restart" and atlas.epoch == 1
    feed(atlas, mapmerge.read_log(second))
    merges = atlas.merges
    assert [m["state"] for m in merges] == ["full"]
    merge = merges[0]
    assert (merge["epoch"], merge["map"]) == (1, 0)
    assert merge["conditional_at_scan"] < merge["full_at_scan"] <= atlas.scans
    # Merged: the robot's graph holds both epochs.
    graph = atlas.graph
    assert graph.num_vertices > 300 and atlas.travel_m > 50
    graphs = atlas.graphs  # the active graph first: the one the robot is in, once merged fully
    np.testing.assert_array_equal(graphs[0].ids, graph.ids)
    assert sum(g.num_vertices for g in graphs) >= graph.num_vertices
    assert atlas.robot_pose.shape == (3,)
    assert atlas.hypotheses["full"] == 1

    code, out, err = run_cli("atlas", first, second, "-o", tmp_path / "cli", "--no-pictures", "--json")
    assert code == 0, err
    expected = json.loads(out)
    assert [(m["state"], m["epoch"], m["map"], m["conditional_at_scan"], m["full_at_scan"])
            for m in expected["merges"]] == [
        (m["state"], m["epoch"], m["map"], m["conditional_at_scan"], m["full_at_scan"])
        for m in merges
    ]
    assert expected["hypotheses"] == atlas.hypotheses
    # After the last scan (the CLI's `finish`: the epoch's agreement with the merged one is
    # judged), every event is the CLI's line of events.jsonl.
    atlas.finish()
    lines = [json.loads(l) for l in open(tmp_path / "cli" / "events.jsonl")]
    assert atlas.events == lines
    assert [e["event"] for e in lines][-1] == "epoch_agreement"
    assert [e["scan"] for e in lines if e["event"] == "merged"] == [merge["full_at_scan"]]
    # Every map's scans as the CLI writes them to maps/<map>/trajectory.tum.
    listed = {m["map"]: m for m in expected["maps"]}
    for trajectory in atlas.trajectories():
        entry = listed.pop(trajectory["map"])
        assert sorted(e["epoch"] for e in entry["epochs"]) == trajectory["epochs"]
        assert entry["scans"] == len(trajectory["scans"])
        if entry["scans"] == 0:
            continue
        written = np.loadtxt(entry["trajectory"], ndmin=2)
        poses = trajectory["poses"]
        np.testing.assert_allclose(written[:, 1:3], poses[:, :2], atol=1e-9)
        yaw = 2 * np.arctan2(written[:, 6], written[:, 7])
        np.testing.assert_allclose(np.angle(np.exp(1j * (yaw - poses[:, 2]))), 0, atol=1e-9)
        np.testing.assert_array_equal(written[:, 0], trajectory["stamps"])
    assert listed == {}
    # The whole run as one call: the CLI's job without its judging.
    report = mapmerge.run_atlas([first, second], tmp_path / "py", pictures=False)
    for key in ("sessions", "scans", "epochs", "merges", "unmerges", "hypotheses",
                "epoch_outcomes"):
        assert report[key] == expected[key], key
    assert [json.loads(l) for l in open(tmp_path / "py" / "events.jsonl")] == lines


def test_bad_scans_and_reasons_are_bad_input():
    atlas = mapmerge.Atlas()
    with pytest.raises(mapmerge.BadInputError, match="odometry must be three finite numbers"):
        atlas.add_scan([0.0, 0.0], np.ones(10), angle_min=-1.0, angle_increment=0.2, range_max=30)
    with pytest.raises(mapmerge.BadInputError, match="invalid value 'lost' for reason"):
        atlas.end_epoch("lost")
    report = atlas.add_scan(
        [0.0, 0.0, 0.0], np.full(360, 3.0), angle_min=-np.pi, angle_increment=np.pi / 180,
        range_max=30.0,
    )
    assert report["keyframe"] == 0 and report["anchor"] == 0 and atlas.scans == 1
    np.testing.assert_array_equal(atlas.robot_pose, [0.0, 0.0, 0.0])



def test_a_whole_run_commits_each_session_to_a_store(tmp_path):
    """`run_atlas` with a store: one version per session, and bad input is refused."""
    logs = [
        truncated_log(in_testdata(f"sim/office-aliased/session_{k}.log.xz"), tmp_path / f"s{k}.log", 150)
        for k in (0, 1)
    ]
    report = mapmerge.run_atlas(logs, tmp_path / "out", pictures=False, store=tmp_path / "a.db")
    assert report["sessions"] == 2 and report["scans"] == 300
    assert report["store"]["resumed_from"] is None
    assert [c["version"] for c in report["store"]["committed"]] == [1, 2]
    again = mapmerge.run_atlas(logs[:1], tmp_path / "again", pictures=False, store=tmp_path / "a.db")
    assert again["store"]["resumed_from"] == 2
    with pytest.raises(mapmerge.BadInputError, match="give one or more logs"):
        mapmerge.run_atlas([], tmp_path / "none")
