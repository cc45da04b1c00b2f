#!/usr/bin/env bash
# Issue 16, part 2: retrieval alone, stage one of place recognition. Per public log, how many
# revisits get a true candidate within the top k of Scan Context, of the ring spectrum, and of
# the union of both lists (crates/lab/lab/examples/retrieval_study.rs; keyframes and
# revisits as in scripts/bench_place.sh), with the totals of the tuning and the held-out logs
# (scripts/log_split.sh).
# Usage: scripts/bench_retrieval.sh [--config JSON] [--spectrum JSON]
# Writes bench-out/retrieval.md (+ bench-out/retrieval/runs.jsonl).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/log_split.sh
extra=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --config|--spectrum) extra+=("$1" "$2"); shift 2 ;;
    *) echo "usage: $0 [--config JSON] [--spectrum JSON]" >&2; exit 2 ;;
  esac
done
data="${MAPMERGE_DATA:-../shared/data}"
out="${OUT_DIR:-bench-out}"
mkdir -p "$out/retrieval"
cargo build --release -q -p mapmerge-lab --example retrieval_study
bin=target/release/examples/retrieval_study
results="$out/retrieval/runs.jsonl"; : > "$results"
for log in "${ALL_LOGS[@]}"; do
  "$bin" "$data/carmen/$log-corrected.log.xz" "${extra[@]}" >> "$results"
done
python3 - "$results" "${HELD_OUT_LOGS[*]}" "${TUNING_LOGS[*]}" "${extra[*]}" > "$out/retrieval.md" <<'PY'
import json, sys
runs = [json.loads(l) for l in open(sys.argv[1])]
held_out, tuning = set(sys.argv[2].split()), set(sys.argv[3].split())
ks = [1, 5, 10, 20, 50, 100]
lists = [("scan_context", "Scan Context"), ("spectrum_yaw_by_scan_context", "spectrum"), ("fused", "union")]
print(f"`scripts/bench_retrieval.sh{' ' + sys.argv[4] if sys.argv[4] else ''}`: revisits with a true candidate "
      f"within the top k (k = {', '.join(map(str, ks))}; the union holds up to 2k).\n")
print("| log | set | revisits | " + " | ".join(name for _, name in lists) + " |")
print("|---|---|---|" + "---|" * len(lists))
def row(label, set_label, rs):
    rev = sum(r["revisits"] for r in rs)
    cells = []
    for key, _ in lists:
        counts = [sum(r[key][i] for r in rs) for i in range(len(ks))]
        cells.append(" / ".join(f"{100 * c / rev:.0f}" if rev else "–" for c in counts))
    print(f"| {label} | {set_label} | {rev} | " + " | ".join(cells) + " |")
for r in runs:
    row(r["name"], "held-out" if r["name"] in held_out else "tuning", [r])
row("**held-out logs**", "", [r for r in runs if r["name"] in held_out])
row("**tuning logs**", "", [r for r in runs if r["name"] in tuning])
row("**tuning logs without infinite-corridor**", "", [r for r in runs if r["name"] in tuning and r["name"] != "infinite-corridor"])
describe = sum(r["describe_ms"] for r in runs) / len(runs)
query = sum(r["query_ms"] for r in runs) / len(runs)
print(f"\nCells: per cent of the revisits, k = {' / '.join(map(str, ks))}. Cost per keyframe (mean over "
      f"logs): describing (Scan Context + spectrum) {describe:.2f} ms, both lists (k = 100) {query:.3f} ms.")
PY
cat "$out/retrieval.md"
