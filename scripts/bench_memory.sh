#!/usr/bin/env bash
# Issue 68, part 1: peak memory (maximum resident set, `/usr/bin/time -f %M`) of `mapmerge slam`
# and `mapmerge atlas` on every public log, each with seeded noisy odometry (`--odometry-noise
# default --seed 3`; atlas also draws its kidnaps with it), one process at a time; then the
# same on two logs run twice over (slam on the log written twice in a row, atlas given the log
# twice), which shows whether memory follows the mapped area or the time spent in it.
#
#   scripts/bench_memory.sh [--out-dir bench-out/memory] [--logs "intel aces …"]
#
# MAPMERGE_BIN=PATH measures that build; MAPMERGE_BASE_BIN=PATH measures a second build beside
# it (the "before" column). Writes OUT/memory.md.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/bench_common.sh
out=bench-out/memory
logs=""
while [[ $# -gt 0 ]]; do
  case "$1" in
    --out-dir) out=$2; shift 2 ;;
    --logs) logs=$2; shift 2 ;;
    *) echo "usage: $0 [--out-dir DIR] [--logs \"LOG …\"]" >&2; exit 2 ;;
  esac
done
command -v /usr/bin/time >/dev/null || { echo "needs /usr/bin/time (Debian: time)" >&2; exit 2; }
data="${MAPMERGE_DATA:-../shared/data}"
bin=$(mapmerge_bin)
base="${MAPMERGE_BASE_BIN:-}"
mkdir -p "$out"
out=$(realpath "$out")
if [[ -z $logs ]]; then
  logs=$(for f in "$data"/carmen/*-corrected.log.xz; do basename "$f" -corrected.log.xz; done)
fi
noise=(--odometry-noise default --seed 3)
# measure TAG BIN COMMAND INPUT... : one run, its peak RSS (MB) and wall time into OUT/TAG.time
measure() {
  local tag=$1 b=$2 command=$3; shift 3
  /usr/bin/time -f "%M %e" -o "$out/$tag.time" "$b" "$command" "$@" "${noise[@]}" \
    -o "$out/run-$tag" --json > "$out/$tag.json" 2> "$out/$tag.err" || echo "$tag failed" >&2
}
for log in $logs; do
  path="$data/carmen/$log-corrected.log.xz"
  for command in slam atlas; do
    measure "new-$command-$log" "$bin" "$command" "$path"
    [[ -z $base ]] || measure "base-$command-$log" "$base" "$command" "$path"
  done
done
# Twice over: the decompressed log written twice in a row (slam), or given twice (atlas).
for log in intel freiburg-campus; do
  path="$data/carmen/$log-corrected.log.xz"
  [[ -f $path ]] || continue
  xz -dc "$path" > "$out/$log.log"
  cat "$out/$log.log" "$out/$log.log" > "$out/$log-twice.log"
  measure "twice-once-slam-$log" "$bin" slam "$out/$log.log"
  measure "twice-twice-slam-$log" "$bin" slam "$out/$log-twice.log"
  measure "twice-once-atlas-$log" "$bin" atlas "$path"
  measure "twice-twice-atlas-$log" "$bin" atlas "$path" "$path"
  rm -f "$out/$log.log" "$out/$log-twice.log"
done
python3 - "$out" "$logs" > "$out/memory.md" <<'PY'
import json, os, sys
out, logs = sys.argv[1], sys.argv[2].split()
def peak(tag):
    try:
        kb, _ = open(os.path.join(out, tag + ".time")).read().split()[:2]
        return int(kb) / 1024
    except (OSError, ValueError):
        return None
def scans(tag):
    try:
        return json.load(open(os.path.join(out, tag + ".json"))).get("scans")
    except (OSError, ValueError):
        return None
fmt = lambda v: "—" if v is None else f"{v:.0f}"
base = any(os.path.exists(os.path.join(out, f"base-slam-{l}.time")) for l in logs)
head = "| log | scans | slam peak (MB) | atlas peak (MB) |" + (" slam before | atlas before |" if base else "")
print(head)
print("|" + "---|" * (head.count("|") - 1))
worst = {"slam": 0.0, "atlas": 0.0}
for log in logs:
    row = [log, fmt(scans(f"new-slam-{log}"))]
    for command in ("slam", "atlas"):
        p = peak(f"new-{command}-{log}")
        worst[command] = max(worst[command], p or 0.0)
        row.append(fmt(p))
    if base:
        row += [fmt(peak(f"base-{c}-{log}")) for c in ("slam", "atlas")]
    print("| " + " | ".join(row) + " |")
print(f"| **largest** | | {worst['slam']:.0f} | {worst['atlas']:.0f} |" + (" | |" if base else ""))
print()
print("| run twice over | slam once (MB) | slam twice | growth | atlas once | atlas twice | growth |")
print("|---|---|---|---|---|---|---|")
for log in ("intel", "freiburg-campus"):
    cells = []
    for command in ("slam", "atlas"):
        once, twice = peak(f"twice-once-{command}-{log}"), peak(f"twice-twice-{command}-{log}")
        growth = "—" if not (once and twice) else f"{100 * (twice / once - 1):+.1f} %"
        cells += [fmt(once), fmt(twice), growth]
    print(f"| {log} | " + " | ".join(cells) + " |")
PY
cat "$out/memory.md"
