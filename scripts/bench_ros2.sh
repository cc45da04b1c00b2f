#!/usr/bin/env bash
# Issue 69: `mapmerge ros2 slam` live beside an independent DDS. For each log (tuning logs by
# default), seeded noisy odometry (`split --odometry-noise default --seed S`) is written as a
# bag and played at --rate by Cyclone DDS's Python binding (scripts/ros2_peer.py, core 1),
# while the node runs on core 0 alone (taskset + RAYON_NUM_THREADS=1) with a store; once the
# peer has played everything the node gets SIGINT, commits and leaves. Kept: the node's
# --json report (pose latency from scan in to map → odom out, map publication time) and the
# peer's (end-to-end latency, the last /map). --resolution R makes the maps finer (0.0175 m
# gives intel a map of over 2000 × 2000 cells, issue 69's publication target).
# Usage: scripts/bench_ros2.sh [--log NAME]... [--rate R | --scan-hz H] [--seed S]
# [--resolution R] [--config ENGINE.json]. --rate plays at R times real time (1 by default); --scan-hz H at the
# rate that makes the scans come H times a second on average (the public logs are thinned
# to 0.3–5 s per scan; a laser gives 10–40).
# Needs a Python with cyclonedds and mcap-ros2-support: $MAPMERGE_ROS2_PYTHON, else
# target/bag-venv (made by .ci/run). Writes bench-out/ros2/*.json and bench-out/ros2.md.
# `--config` gives the node engine parameters (`scripts/ros2_as_slam.json`: the engine as
# `slam` runs it, one epoch, for a like-for-like map). MAPMERGE_BIN=PATH runs another build (it must have the `ros2` feature).
set -euo pipefail
cd "$(dirname "$0")/.."
logs=(); pace=(--rate 1); seed=7; resolution=0.05; config=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --log) logs+=("$2"); shift 2 ;;
    --rate) pace=(--rate "$2"); shift 2 ;;
    --scan-hz) pace=(--scan-hz "$2"); shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    --resolution) resolution="$2"; shift 2 ;;
    --config) config=(--config "$(realpath "$2")"); shift 2 ;;
    *) echo "usage: $0 [--log NAME]... [--rate R | --scan-hz H] [--seed S] [--resolution R] [--config F]" >&2; exit 2 ;;
  esac
done
[[ ${#logs[@]} -gt 0 ]] || logs=(intel freiburg-079)
data="${MAPMERGE_DATA:-../shared/data}"
python="${MAPMERGE_ROS2_PYTHON:-target/bag-venv/bin/python}"
out="$(realpath -m "${OUT_DIR:-bench-out}")/ros2"
mkdir -p "$out"
if [[ -z "${MAPMERGE_BIN:-}" ]]; then cargo build --release -q -p mapmerge-cli --features ros2; fi
bin="$(realpath "${MAPMERGE_BIN:-target/release/mapmerge}")"
node_core=(env RAYON_NUM_THREADS=1); peer_core=()
if command -v taskset >/dev/null; then node_core+=(taskset -c 0); peer_core=(taskset -c 1); fi
domain=$(( 40 + RANDOM % 60 ))
for log in "${logs[@]}"; do
  work="$out/$log"; rm -rf "$work"; mkdir -p "$work"
  "$bin" split "$data/carmen/$log-corrected.log.xz" --segments 1 --odometry-noise default \
    --seed "$seed" -o "$work/split" > /dev/null
  "$bin" convert "$work/split/${log}_00.log" -o "$work/$log.mcap" > /dev/null
  ROS_DOMAIN_ID=$domain "${node_core[@]}" "$bin" ros2 slam --qos reliable --map-period 5 \
    --resolution "$resolution" "${config[@]}" --store "$work/site.db" --session "$log" --json \
    > "$work/node.json" 2> "$work/node.log" &
  node=$!
  "${peer_core[@]}" "$python" scripts/ros2_peer.py --domain "$domain" play "$work/$log.mcap" \
    "${pace[@]}" --linger 120 --played "$work/played" --map-out "$work/live.yaml" \
    --report "$work/peer.json" 2> "$work/peer.log" &
  peer=$!
  # Once every message is out (and the node had 2 s for the last), SIGINT: the node commits,
  # publishes its last map and leaves; the peer, lingering for that map, then ends too.
  while [[ ! -f "$work/played" ]] && kill -0 "$peer" 2>/dev/null; do sleep 1; done
  sleep 2
  kill -INT "$node"; wait "$node" || echo "$log: node exit code $?" >&2
  wait "$peer" || echo "$log: peer exit code $?" >&2
  # The same bag offline (`slam`, one epoch), judged against the live /map the peer saved.
  "${node_core[@]}" "$bin" slam "$work/$log.mcap" --resolution "$resolution" -o "$work/offline" \
    > /dev/null
  "$bin" eval map-agreement "$work/live.yaml" "$work/offline/map.yaml" --json \
    > "$work/agreement.json"
done
"$python" - "$out" "${logs[@]}" > "$out.md" <<'PY'
import json, pathlib, sys
out = pathlib.Path(sys.argv[1])
print("| log | played at | scans heard / mapped | epochs started / merges | pose out p50 / p99 / max (ms, node) | scan → pose p99 (ms, peer) | maps | largest map (cells) | publication p50 / max (ms) | live /map agrees with `slam`'s |")
print("|---|---|---|---|---|---|---|---|---|---|")
for log in sys.argv[2:]:
    node = json.loads((out / log / "node.json").read_text())
    peer = json.loads((out / log / "peer.json").read_text())
    lat = sorted(peer["latency_ms"])
    p99 = lat[max(0, -(-len(lat) * 99 // 100) - 1)] if lat else float("nan")
    pl, mp = node["pose_latency"], node["map_publish"]
    agreement = json.loads((out / log / "agreement.json").read_text())
    print(f"| {log} | {peer['rate']:.2f}× | {node['scans_heard']} / {node['scans_mapped']} | {node['epochs_started']} / {node['merges']} | {pl['median_ms']:.1f} / {pl['p99_ms']:.1f} / {pl['max_ms']:.1f} | {p99:.1f} | {node['maps_published']} | {node['largest_map_cells']} | {mp['median_ms']:.1f} / {mp['max_ms']:.1f} | {100 * agreement['fraction']:.2f} % of {agreement['cells']} |")
PY
cat "$out.md"
