#!/usr/bin/env bash
# Issue 15: are the valid merges of `make-merge-cases --valid-at merge-place` (exact by the
# log's corrected poses) true? For every valid case in the given cases files, every scan of
# the second segment is matched against the first segment's points placed by the corrected
# poses (examples/pose_consistency.rs: correlative search and ICP, ±0.5 m, ±5°, starting at
# the corrected pose), and the offsets the matches find are summarised per log. The offsets
# include the matcher's own error on one scan against a point map.
# Usage: scripts/reference_consistency.sh L.cases.jsonl... (e.g. an OUT_DIR of
# scripts/bench_invalid_merge.sh: D/invalid-merge/*.cases.jsonl). Prints a Markdown table.
set -euo pipefail
cd "$(dirname "$0")/.."
(( $# > 0 )) || { echo "usage: $0 L.cases.jsonl..." >&2; exit 2; }
cargo build --release -q -p mapmerge-lab --example pose_consistency
bin=target/release/examples/pose_consistency
lines="$(mktemp)"; trap 'rm -f "$lines"' EXIT
for cases in "$@"; do
  python3 -c '
import json, sys
for line in open(sys.argv[1]):
    case = json.loads(line)
    if case.get("label") == "valid":
        print(case["id"], case["log"], *case["first"], *case["second"])
' "$cases" | while read -r id log a b c d; do
    "$bin" "$log" "$a" "$b" "$c" "$d" | sed "s|^|$id |"
  done >> "$lines"
done
python3 - "$lines" <<'PY'
import collections, statistics, sys
offsets = collections.defaultdict(list); scans = collections.Counter()
for line in open(sys.argv[1]):
    f = line.split()
    log = f[0].split("/")[0]; scans[log] += 1
    if f[2] == "none":
        continue
    dx, dy, dth = float(f[3]), float(f[5]), float(f[7])
    offsets[log].append(((dx * dx + dy * dy) ** 0.5, abs(dth)))
print("| log | second-segment scans | matched | median offset (m) | 90th percentile (m) | median turn (°) | 90th percentile (°) | matched scans > 0.1 m or > 1° |")
print("|---|---|---|---|---|---|---|---|")
for log in sorted(scans):
    v = offsets[log]
    if not v:
        print(f"| {log} | {scans[log]} | 0 | – | – | – | – | – |"); continue
    m = sorted(o for o, _ in v); t = sorted(a for _, a in v)
    far = sum(1 for o, a in v if o > 0.1 or a > 1.0) / len(v)
    print(f"| {log} | {scans[log]} | {len(v)} | {statistics.median(m):.3f} | {m[int(0.9 * len(m))]:.3f} | {statistics.median(t):.2f} | {t[int(0.9 * len(t))]:.2f} | {far:.0%} |")
PY
