#!/usr/bin/env bash
# Issue 4: `mapmerge slam` beside MRPT 2.5 icp-slam, in the same run, on the same noisy logs.
# For every public corrected log: `mapmerge slam LOG --odometry-noise PROFILE --seed S --json`
# (one core: taskset + RAYON_NUM_THREADS=1), the same noisy log written by `mapmerge eval
# add-noise` for MRPT, both scored against the corrected poses (ATE, RPE, Kümmerle relations
# made by `mapmerge eval make-relations`), and mapmerge's accepted loop edges judged against
# them. Usage: scripts/bench_slam.sh [--profile default|harsh] [--seed S] [--only NAME]...
# [--no-mrpt]. Writes bench-out/slam.md (+ bench-out/slam/*). MRPT installs on first use.
# MAPMERGE_BIN=PATH runs another build (e.g. the previous commit's, for a before/after table).
set -euo pipefail
cd "$(dirname "$0")/.."
profile=default; seed=0; only=(); mrpt=1
while [[ $# -gt 0 ]]; do
  case "$1" in
    --profile) profile="$2"; shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    --only) only+=("$2"); shift 2 ;;
    --no-mrpt) mrpt=0; shift ;;
    *) echo "usage: $0 [--profile P] [--seed S] [--only NAME]... [--no-mrpt]" >&2; exit 2 ;;
  esac
done
data="${MAPMERGE_DATA:-../shared/data}"
peers="${MAPMERGE_PEERS:-../shared/peers}"
out="$(realpath -m "${OUT_DIR:-bench-out}")/slam"
mkdir -p "$out"
if [[ -z "${MAPMERGE_BIN:-}" ]]; then cargo build --release -q -p mapmerge-cli; fi
bin="$(realpath "${MAPMERGE_BIN:-target/release/mapmerge}")"
one_core=(env RAYON_NUM_THREADS=1)
command -v taskset >/dev/null && one_core+=(taskset -c 0)
logs=(acapulco aces belgioioso csail edmonton fhw freiburg-079 freiburg-101 freiburg-campus infinite-corridor intel orebro seattle)
[[ ${#only[@]} -gt 0 ]] && logs=("${only[@]}")
results="$out/runs.jsonl"; : > "$results"
for log in "${logs[@]}"; do
  corrected="$data/carmen/$log-corrected.log.xz"
  ours=$("${one_core[@]}" "$bin" slam "$corrected" -o "$out/$log" --odometry-noise "$profile" --seed "$seed" --json)
  mrpt_report=null; mrpt_relations=null; mrpt_secs=null
  if [[ $mrpt == 1 ]]; then
    noisy="$out/$log.noisy.log"
    "$bin" eval add-noise "$corrected" -o "$noisy" --profile "$profile" --seed "$seed" --json > /dev/null
    "$bin" eval make-relations "$corrected" -o "$out/$log.relations" --index-keyed --json > /dev/null
    if MRPT_PEER_TMP="$out/mrpt-tmp" "${one_core[@]}" "$peers/mrpt_icp_slam.sh" "$noisy" "$out/$log.mrpt" > /dev/null 2> "$out/$log.mrpt.err"; then
      mrpt_report=$("$bin" eval ate --trajectory "$out/$log.mrpt/trajectory.tum" --reference "$corrected" --json)
      mrpt_relations=$("$bin" eval relations --trajectory "$out/$log.mrpt/trajectory.tum" --relations "$out/$log.relations" --json)
      mrpt_secs=$(cat "$out/$log.mrpt/seconds.txt")
    fi
  fi
  echo "{\"log\":\"$log\",\"mapmerge\":$ours,\"mrpt\":$mrpt_report,\"mrpt_relations\":$mrpt_relations,\"mrpt_seconds\":$mrpt_secs}" >> "$results"
  echo "done $log" >&2
done
python3 scripts/bench_slam_table.py "$results" "$profile" "$seed" > "$out/../slam.md"
cat "$out/../slam.md"
