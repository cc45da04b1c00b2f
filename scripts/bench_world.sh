#!/usr/bin/env bash
# The 2D world's speed targets (issue 3), measured on this machine:
#   1. grid from a corrected CARMEN log at 5 cm (Intel: < 1 s), whole process and build alone;
#   2. ray casting throughput (>= 20 M cell updates/s on one core), criterion;
#   3. simulator: 30 min of robot time (10 Hz scans, 360 beams) in < 5 s.
# Writes bench-out/world.md. Options: --repeats N (default 5; the median is reported).
set -euo pipefail
cd "$(dirname "$0")/.."
repeats=5
while [[ $# -gt 0 ]]; do
  case "$1" in
    --repeats) repeats="$2"; shift 2 ;;
    *) echo "usage: $0 [--repeats N]" >&2; exit 2 ;;
  esac
done
data="${MAPMERGE_DATA:-../shared/data}"
out="${OUT_DIR:-bench-out}"
mkdir -p "$out/world"
if [[ -z "${MAPMERGE_BIN:-}" ]]; then
  cargo build --release -q -p mapmerge-cli
  MAPMERGE_BIN=target/release/mapmerge
fi
results="$out/world/runs.jsonl"
: > "$results"

# 1. Grids from the public corrected logs at 5 cm.
for log in intel aces freiburg-079 csail freiburg-campus; do
  file="$data/carmen/$log-corrected.log.xz"
  [[ -f "$file" ]] || { echo "skip $log: $file missing" >&2; continue; }
  for ((k = 0; k < repeats; k++)); do
    start=$(date +%s%N)
    report=$("$MAPMERGE_BIN" grid --log "$file" --resolution 0.05 -o "$out/world/$log.yaml" --json)
    end=$(date +%s%N)
    echo "{\"kind\":\"grid\",\"log\":\"$log\",\"wall_ms\":$(( (end - start) / 1000000 )),\"report\":$report}" >> "$results"
  done
done

# 3. The simulator: 30 minutes of robot time, one session, 360 beams at 10 Hz.
for ((k = 0; k < repeats; k++)); do
  start=$(date +%s%N)
  report=$("$MAPMERGE_BIN" sim --world office --sessions 1 --duration 1800 --seed "$k" --no-pictures -o "$out/world/sim" --json)
  end=$(date +%s%N)
  echo "{\"kind\":\"sim\",\"wall_ms\":$(( (end - start) / 1000000 )),\"report\":$report}" >> "$results"
done

# 2. Ray casting (criterion prints Melem/s = million cell updates per second).
cargo bench -q -p mapmerge-grid --bench raycast -- --warm-up-time 1 --measurement-time 5 2>/dev/null \
  | grep -E "^insert|thrpt" > "$out/world/raycast.txt" || true

python3 - "$results" "$out/world/raycast.txt" > "$out/world.md" <<'PY'
import json, statistics, sys, re
runs = [json.loads(l) for l in open(sys.argv[1])]
print("| log | scans | cells visited | grid (w × h) | build s (median) | whole process s (median) | target |")
print("|---|---|---|---|---|---|---|")
for log in dict.fromkeys(r["log"] for r in runs if r["kind"] == "grid"):
    rs = [r for r in runs if r["kind"] == "grid" and r["log"] == log]
    rep = rs[0]["report"]
    build = statistics.median(r["report"]["build_secs"] for r in rs)
    wall = statistics.median(r["wall_ms"] / 1000 for r in rs)
    target = ("met" if wall < 1.0 else "MISSED") + " (< 1 s)" if log == "intel" else ""
    print(f"| {log} | {rep['scans']} | {rep['cells_visited']:,} | {rep['width']} × {rep['height']} | {build:.3f} | {wall:.3f} | {target} |")
sims = [r for r in runs if r["kind"] == "sim"]
if sims:
    rep = sims[0]["report"]
    wall = statistics.median(r["wall_ms"] / 1000 for r in sims)
    gen = statistics.median(r["report"]["simulate_secs"] for r in sims)
    print()
    print("| simulator | robot time s | scans | beams | simulate s (median) | whole process s (median, writing files) | target |")
    print("|---|---|---|---|---|---|---|")
    print(f"| {rep['world']} | {rep['robot_secs']:.0f} | {rep['scans']} | {rep['beams']:,} | {gen:.2f} | {wall:.2f} | {'met' if gen < 5 else 'MISSED'} (< 5 s) |")
text = open(sys.argv[2]).read()
groups = re.findall(r"^(insert\S+)", text, re.M)
thrpts = re.findall(r"thrpt:\s+\[\S+ \S+ (\S+) (\S+)", text)
if thrpts:
    print()
    print("| ray casting | median throughput | target |")
    print("|---|---|---|")
    for name, (value, unit) in zip(groups, thrpts):
        melem = float(value) * (1000 if unit.startswith("Gelem") else 1)
        print(f"| {name} | {melem:.0f} M cell updates/s | {'met' if melem >= 20 else 'MISSED'} (≥ 20 M/s) |")
PY
cat "$out/world.md"
