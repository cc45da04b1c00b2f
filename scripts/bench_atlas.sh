#!/usr/bin/env bash
# Issue 6, target 4: the lifelong pipeline (`mapmerge atlas --sim office-aliased`) on 20 seeds of
# the simulator's aliased world with kidnaps; every merge judged against the ground truth.
# Usage: scripts/bench_atlas.sh [--seeds N] [--world PRESET]. Writes bench-out/atlas.md.
set -euo pipefail
cd "$(dirname "$0")/.."
seeds=20; world=office-aliased
while [[ $# -gt 0 ]]; do
  case "$1" in
    --seeds) seeds="$2"; shift 2 ;;
    --world) world="$2"; shift 2 ;;
    *) echo "usage: $0 [--seeds N] [--world PRESET]" >&2; exit 2 ;;
  esac
done
out="$(realpath -m "${OUT_DIR:-bench-out}")/atlas"
mkdir -p "$out"
if [[ -z "${MAPMERGE_BIN:-}" ]]; then cargo build --release -q -p mapmerge-cli; fi
bin="$(realpath "${MAPMERGE_BIN:-target/release/mapmerge}")"
: > "$out/runs.jsonl"
for seed in $(seq 1 "$seeds"); do
  "$bin" atlas --sim "$world" --seed "$seed" --no-pictures -o "$out/seed-$seed" --json \
    | python3 -c "import json,sys; d=json.load(sys.stdin); d['seed']=$seed; print(json.dumps(d))" >> "$out/runs.jsonl"
done
python3 - "$out/runs.jsonl" "$world" > "$out/../atlas.md" <<'PY'
import json, sys
runs = [json.loads(l) for l in open(sys.argv[1])]
print(f"| seed | scans | epochs | merges | correct | wrong | wrong undone ≤ 10 m (travel to undo) | correct undone | seconds |")
print("|---|---|---|---|---|---|---|---|---|")
tot = dict(m=0, c=0, w=0, wu=0, cu=0)
for r in runs:
    wrong = [m for m in r["merges"] if m["correct"] is False]
    travel = ", ".join(f"{m['undone_after_m']:.1f} m" if m["undone_after_m"] is not None else "kept" for m in wrong)
    print(f"| {r['seed']} | {r['scans']} | {r['epochs']} | {len(r['merges'])} | {r['correct_merges']} | {r['wrong_merges']} | {r['wrong_undone_within_10m']}{' (' + travel + ')' if travel else ''} | {r['correct_undone']} | {r['seconds']:.1f} |")
    tot["m"] += len(r["merges"]); tot["c"] += r["correct_merges"]; tot["w"] += r["wrong_merges"]
    tot["wu"] += r["wrong_undone_within_10m"]; tot["cu"] += r["correct_undone"]
print(f"| **all {len(runs)}** | | | {tot['m']} | {tot['c']} | {tot['w']} | {tot['wu']} of {tot['w']} | {tot['cu']} of {tot['c']} | |")
PY
cat "$out/../atlas.md"
