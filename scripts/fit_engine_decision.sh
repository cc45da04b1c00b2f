#!/usr/bin/env bash
# Issue 15, part 4: the engine's decision fitted on the engine's own merges.
# 1. `mapmerge atlas --sim WORLD --seed S` on the fitting seeds 1-20 of every world preset
#    (none of them held out: the lifelong benchmark holds out 101-110), with detector
#    `learned` that never acts (thresholds above 1), so every merge is judged over its whole
#    conditional phase and probation; `--merge-results` writes each merge's readings,
#    labelled by the simulator's truth.
# 2. `mapmerge eval calibrate` on them, leaving one world out at a time (L2 weight nested),
#    and the model on all of them (`-o`).
# 3. An `atlas --config` for it: threshold 0.5 (equal priors), or with --false-alarm-budget F
#    (`eval calibrate --false-alarm-budget`) the lowest probability that at most a share F of
#    the correct merges exceed (in sample), as both engine thresholds (unmerge, conditional
#    reject); and how many merges no calibration of the detectors can separate.
# Usage: scripts/fit_engine_decision.sh [--jobs N] [--false-alarm-budget F]. Writes $OUT_DIR
# (default bench-out/engine-fit): runs/, model.json, calibrate.md, engine-config.json.
# MAPMERGE_BIN=PATH runs another build.
set -euo pipefail
cd "$(dirname "$0")/.."
jobs=2; budget=""
while [[ $# -gt 0 ]]; do
  case "$1" in
    --jobs) jobs="$2"; shift 2 ;;
    --false-alarm-budget) budget="$2"; shift 2 ;;
    *) echo "usage: $0 [--jobs N] [--false-alarm-budget F]" >&2; exit 2 ;;
  esac
done
if [[ -z "${MAPMERGE_BIN:-}" ]]; then cargo build --release -q -p mapmerge-cli; fi
bin="$(realpath "${MAPMERGE_BIN:-target/release/mapmerge}")"
out="$(realpath -m "${OUT_DIR:-bench-out/engine-fit}")"
mkdir -p "$out/runs"
shadow="$out/shadow.json"
# The shadow model only reads: six components (the default model has two and better
# hypothesis), weights 0, so every merge's readings hold each detector eval calibrate fits on.
cat > "$shadow" <<'JSON'
{"detector": "learned", "unmerge_threshold": 2.0, "decisions": {"conditional_reject_threshold": 2.0},
 "learned_model": {"methods": ["change_detection", "gridmap", "histogram", "sm", "dm", "better_hypothesis"],
  "ratio_weights": [0, 0, 0, 0, 0, 0], "unsupported_weights": [0, 0, 0, 0, 0, 0], "intercept": 0,
  "threshold": 0.5, "fitted_on": "scripts/fit_engine_decision.sh: reads only"}}
JSON
for world in office office-aliased corridor-loop warehouse symmetric-hall; do
  for seed in $(seq 1 20); do
    name="$world-$seed"
    [[ -s "$out/runs/$name.json" ]] && continue # kept from an earlier run of this build
    "$bin" atlas --sim "$world" --seed "$seed" --config "$shadow" --no-pictures \
      -o "$out/runs/$name" --merge-results "$out/runs/$name.merges.jsonl" --json \
      > "$out/runs/$name.json" 2> "$out/runs/$name.err" &
    while (( $(jobs -rp | wc -l) >= jobs )); do wait -n; done
  done
done
wait
budget_args=(); [[ -n "$budget" ]] && budget_args=(--false-alarm-budget "$budget")
"$bin" eval calibrate --results "$out"/runs/*.merges.jsonl -o "$out/model.json" \
  --report "$out/calibrate.md" --min-cases 3 "${budget_args[@]}" > /dev/null
cat "$out/calibrate.md"
python3 - "$out" <<'PY'
import glob, json, os, sys
out = sys.argv[1]
model = json.load(open(os.path.join(out, "model.json")))
threshold = model["threshold"]
config = {"detector": "learned", "learned_model": model, "unmerge_threshold": threshold,
          "decisions": {"conditional_reject_threshold": threshold}}
json.dump(config, open(os.path.join(out, "engine-config.json"), "w"), indent=1)
print(f"engine-config.json: threshold {threshold}")
# Merges that read like most correct ones in every strong detector over their whole judging
# (change detection < 0.1, gridmap < 0.05, better hypothesis < 0.5): no calibration of these
# detectors separates them.
quiet = {True: [0, 0], False: [0, 0]}
for f in glob.glob(os.path.join(out, "runs", "*.json")):
    for m in json.load(open(f))["merges"]:
        peaks = {r["method"]: r["peak_ratio"] for r in m["readings"]}
        if m["correct"] is None or "better_hypothesis" not in peaks:
            continue
        quiet[m["correct"]][1] += 1
        if peaks["change_detection"] < 0.1 and peaks["gridmap"] < 0.05 and peaks["better_hypothesis"] < 0.5:
            quiet[m["correct"]][0] += 1
print(f"reading like correct merges in every strong detector: {quiet[False][0]} of {quiet[False][1]} wrong, {quiet[True][0]} of {quiet[True][1]} correct")
PY
