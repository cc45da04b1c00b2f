#!/usr/bin/env bash
# Issue 16, part 1: the pooled run. Segments of all 13 public corrected logs in ONE assembly:
# per log `mapmerge split LOG --segments N --overlap F --odometry-noise default --seed S`, then
# `mapmerge eval assemble --split DIR_1 ... --split DIR_13 --arrival-seed 1 --orders 20 --json`.
# Any loop edge between segments of two logs is false by construction, and so is any group that
# mixes logs; pair recall is over each log's own overlapping pairs. Reports the association time
# (target ≤ 60 s on 2 cores) and the held-out and tuning logs' shares (scripts/log_split.sh).
# Usage: scripts/bench_assemble_pool.sh [--segments N] [--overlap F] [--seed S] [--orders N]
# Writes bench-out/assemble-pool.md (+ bench-out/assemble-pool/*).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/log_split.sh
source scripts/bench_common.sh
segments=8; overlap=0.1; seed=0; orders=20
while [[ $# -gt 0 ]]; do
  case "$1" in
    --segments) segments="$2"; shift 2 ;;
    --overlap) overlap="$2"; shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    --orders) orders="$2"; shift 2 ;;
    *) echo "usage: $0 [--segments N] [--overlap F] [--seed S] [--orders N]" >&2; exit 2 ;;
  esac
done
data="${MAPMERGE_DATA:-../shared/data}"
out="$(realpath -m "${OUT_DIR:-bench-out}")"
work="$out/assemble-pool"
mkdir -p "$work"
bin="$(mapmerge_bin)"
splits=()
for log in "${ALL_LOGS[@]}"; do
  dir="$work/$log"
  rm -rf "$dir"
  "$bin" split "$data/carmen/$log-corrected.log.xz" --segments "$segments" --overlap "$overlap" \
    --odometry-noise default --seed "$seed" -o "$dir" --json > "$work/$log.split.json"
  splits+=(--split "$dir")
done
echo "assembling $(( ${#ALL_LOGS[@]} * segments )) segments of ${#ALL_LOGS[@]} logs in one run …" >&2
started=$(date +%s.%N)
"$bin" eval assemble "${splits[@]}" --arrival-seed 1 --orders "$orders" --json \
  --edges "$work/edges.jsonl" --pairs "$work/pairs.jsonl" > "$work/score.json"
ended=$(date +%s.%N)
held_out="${HELD_OUT_LOGS[*]}"
python3 - "$work/score.json" "$segments" "$overlap" "$seed" "$held_out" "$started" "$ended" > "$out/assemble-pool.md" <<'PY'
import json, os, sys
score = json.load(open(sys.argv[1]))
held_out = set(sys.argv[5].split())
pct = lambda n, d: "–" if not d else f"{100 * n / d:.1f} %"
log_of = lambda split: os.path.basename(split.rstrip("/"))
print(f"{score['segments']} segments of {len(score['splits'])} logs in one assembly ({sys.argv[2]} per log, overlap "
      f"{sys.argv[3]}, odometry noise `default`, seed {sys.argv[4]}, arrival seed 1); "
      f"wall {float(sys.argv[7]) - float(sys.argv[6]):.0f} s in all.\n")
print("| log | set | segments | loop edges (true) | precision | edges to other logs | overlapping pairs (found) | pair recall |")
print("|---|---|---|---|---|---|---|---|")
sets = {}
for s in score["per_split"]:
    log = log_of(s["split"])
    label = "held-out" if log in held_out else "tuning"
    print(f"| {log} | {label} | {s['segments']} | {s['loop_edges']} ({s['true_edges']}) | {pct(s['true_edges'], s['loop_edges'])} | "
          f"{s['cross_log_edges']} | {s['overlapping_pairs']} ({s['pairs_found']}) | {pct(s['pairs_found'], s['overlapping_pairs'])} |")
    t = sets.setdefault(label, dict(edges=0, true=0, pairs=0, found=0))
    t["edges"] += s["loop_edges"]; t["true"] += s["true_edges"]
    t["pairs"] += s["overlapping_pairs"]; t["found"] += s["pairs_found"]
for label in ["held-out", "tuning"]:
    t = sets.get(label)
    if t:
        print(f"| **{label}** | | | {t['edges']} ({t['true']}) | {pct(t['true'], t['edges'])} | | {t['pairs']} ({t['found']}) | {pct(t['found'], t['pairs'])} |")
print(f"| **pool** | | {score['segments']} | {score['loop_edges']} ({score['true_edges']}) | {pct(score['true_edges'], score['loop_edges'])} | "
      f"{score['cross_log_edges']} | {score['overlapping_pairs']} ({score['pairs_found']}) | {pct(score['pairs_found'], score['overlapping_pairs'])} |")
mixed = score["mixed_groups"]
print(f"\nGroups: {len(score['groups'])} assembled, {len(score['truth_groups'])} in the truth, "
      f"{'equal' if score['groups_correct'] else 'NOT equal'}; groups mixing logs: {mixed}. "
      f"Orders giving the same groups: {score['orders_same']}/{score['orders_tested']}.")
print(f"Seconds: trajectories {score['trajectory_secs']:.1f}, association with grouping {score['association_secs']:.1f} "
      f"(target ≤ 60), per-group graphs {score['optimisation_secs']:.1f}.")
PY
cat "$out/assemble-pool.md"
