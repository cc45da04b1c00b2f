#!/usr/bin/env bash
# The SLAM front-end (issue 4) beside MRPT 2.5 icp-slam, in the same run, on the same noisy logs:
# for every public corrected log, `mapmerge eval add-noise` (profile, seed), then both tools on
# the noisy log, both scored against the corrected poses with `mapmerge eval ate`.
# Usage: scripts/bench_slam.sh [--profile default|harsh] [--seed S] [--only NAME]...
# Writes bench-out/slam.md (+ bench-out/slam/*). MRPT is installed by its script on first use.
set -euo pipefail
cd "$(dirname "$0")/.."
profile=default; seed=0; only=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --profile) profile="$2"; shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    --only) only+=("$2"); shift 2 ;;
    *) echo "usage: $0 [--profile P] [--seed S] [--only NAME]..." >&2; exit 2 ;;
  esac
done
data="${MAPMERGE_DATA:-../shared/data}"
peers="${MAPMERGE_PEERS:-../shared/peers}"
out="$(realpath -m "${OUT_DIR:-bench-out}")/slam"
mkdir -p "$out"
cargo build --release -q -p mapmerge-cli -p mapmerge-slam --example front_end_log
bin=target/release/mapmerge
logs=(acapulco aces belgioioso csail edmonton fhw freiburg-079 freiburg-101 freiburg-campus infinite-corridor intel orebro seattle)
[[ ${#only[@]} -gt 0 ]] && logs=("${only[@]}")
results="$out/runs.jsonl"; : > "$results"
for log in "${logs[@]}"; do
  corrected="$data/carmen/$log-corrected.log.xz"
  noisy="$out/$log.noisy.log"
  odo=$("$bin" eval add-noise "$corrected" -o "$noisy" --profile "$profile" --seed "$seed" --json)
  ours=$(target/release/examples/front_end_log "$noisy" "$out/$log.mapmerge.tum")
  ours_ate=$("$bin" eval ate --trajectory "$out/$log.mapmerge.tum" --reference "$corrected" --json)
  mrpt_ate=null; mrpt_secs=null
  if MRPT_PEER_TMP="$out/mrpt-tmp" "$peers/mrpt_icp_slam.sh" "$noisy" "$out/$log.mrpt" > /dev/null 2> "$out/$log.mrpt.err"; then
    mrpt_ate=$("$bin" eval ate --trajectory "$out/$log.mrpt/trajectory.tum" --reference "$corrected" --json)
    mrpt_secs=$(cat "$out/$log.mrpt/seconds.txt")
  fi
  echo "{\"log\":\"$log\",\"odometry\":$odo,\"mapmerge\":$ours,\"mapmerge_ate\":$ours_ate,\"mrpt_ate\":$mrpt_ate,\"mrpt_seconds\":$mrpt_secs}" >> "$results"
  echo "done $log" >&2
done
python3 - "$results" "$profile" "$seed" > "$out/../slam.md" <<'PY'
import json, sys
runs = [json.loads(l) for l in open(sys.argv[1])]
def ate(report):
    for key in ("ate",):
        if isinstance(report, dict) and key in report:
            v = report[key]
            return v["rms_m"] if isinstance(v, dict) else v
    return None
print(f"Profile `{sys.argv[2]}`, seed {sys.argv[3]}; ATE RMSE (m) after rigid alignment against the corrected poses.\n")
print("| log | scans | odometry ATE | mapmerge ATE | MRPT icp-slam ATE | ATE ratio mapmerge/MRPT | mapmerge ms/scan | MRPT ms/scan | time ratio |")
print("|---|---|---|---|---|---|---|---|---|")
for r in runs:
    scans = r["mapmerge"]["scans"]
    o, m = ate(r["odometry"]["odometry"]), ate(r["mapmerge_ate"])
    p = ate(r["mrpt_ate"]) if r["mrpt_ate"] else None
    ms = 1e3 * r["mapmerge"]["seconds"] / scans
    pms = 1e3 * r["mrpt_seconds"] / scans if r["mrpt_seconds"] else None
    f = lambda v, d=3: "failed" if v is None else f"{v:.{d}f}"
    print(f"| {r['log']} | {scans} | {f(o)} | {f(m)} | {f(p)} | {f(m / p if p else None, 2)} | {ms:.1f} | {f(pms, 1)} | {f(ms / pms if pms else None, 2)} |")
PY
cat "$out/../slam.md"
