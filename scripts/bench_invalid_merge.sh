#!/usr/bin/env bash
# Issue 6, part 5: Holoch et al.'s invalid-merge evaluation (Sec. V, Table III) on the 13 public
# corrected logs. Per log, `mapmerge eval make-merge-cases` (segments of ~100 s, pairs whose maps
# overlap by ≥ 1.5 m², a valid merge and up to two invalid ones per pair, at most --max-pairs
# pairs; odometry noise `default`, seed S), then `mapmerge eval invalid-merge` per log, two logs
# at a time, each on its own core (taskset + RAYON_NUM_THREADS=1): ROC AUC and mean ms per new
# vertex per log and method. Usage: scripts/bench_invalid_merge.sh [--seed S] [--max-pairs N] [--methods a,b,…]
# [--only NAME]... [--valid-at start-frames|merge-place] [--segment-length-m M] [--odometry-noise P]
# [--engine-config ENGINE.json] (engine parameters for the second segments' runs, e.g. a variant)
# Issue 15's protocol: --valid-at merge-place --segment-length-m 30 --odometry-noise none|default
# (valid merges exact at the merge place; rotation, shift and careless invalid cases; AUC per kind).
# Writes bench-out/invalid-merge.md (+ bench-out/invalid-merge/*, and the machine's memory
# latency in bench-out/memory-latency.md); OUT_DIR=… elsewhere.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/bench_common.sh
seed=0; max_pairs=15; methods=""; only=(); valid_at=start-frames; length_args=(); noise=default
engine_args=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --seed) seed="$2"; shift 2 ;;
    --max-pairs) max_pairs="$2"; shift 2 ;;
    --methods) methods="$2"; shift 2 ;;
    --only) only+=("$2"); shift 2 ;;
    --valid-at) valid_at="$2"; shift 2 ;;
    --segment-length-m) length_args=(--segment-length-m "$2"); shift 2 ;;
    --odometry-noise) noise="$2"; shift 2 ;;
    --engine-config) engine_args=(--engine-config "$(realpath "$2")"); shift 2 ;;
    *) echo "usage: $0 [--seed S] [--max-pairs N] [--methods a,b] [--only NAME]... [--valid-at start-frames|merge-place] [--segment-length-m M] [--odometry-noise P] [--engine-config ENGINE.json]" >&2; exit 2 ;;
  esac
done
data="${MAPMERGE_DATA:-../shared/data}"
out="$(realpath -m "${OUT_DIR:-bench-out}")"
work="$out/invalid-merge"
mkdir -p "$work"
cargo build --release -q -p mapmerge-cli
# A copy, so that a rebuild during the run cannot change the binary under it.
cp target/release/mapmerge "$work/mapmerge"
bin="$work/mapmerge"
logs=(acapulco aces belgioioso csail edmonton fhw freiburg-079 freiburg-101 freiburg-campus infinite-corridor intel orebro seattle)
[[ ${#only[@]} -gt 0 ]] && logs=("${only[@]}")
started=$(date +%s)
cases="$work/cases.jsonl"; : > "$cases"
made="$work/make-merge-cases.jsonl"; : > "$made"
for log in "${logs[@]}"; do
  corrected="$data/carmen/$log-corrected.log.xz"
  echo "make-merge-cases $log …" >&2
  "$bin" eval make-merge-cases --log "$corrected" --corrected "$corrected" \
    -o "$work/$log.cases.jsonl" --seed "$seed" --max-pairs "$max_pairs" --valid-at "$valid_at" \
    --odometry-noise "$noise" "${length_args[@]}" --json >> "$made"
  cat "$work/$log.cases.jsonl" >> "$cases"
done
made_secs=$(( $(date +%s) - started ))
# Every single detector and the hand-made combination; the learned one is fitted afterwards
# on these results (eval calibrate), leave one log out — only with every detector run.
calibrate=0
[[ -z "$methods" ]] && { methods=change_detection,gridmap,entropy,histogram,sm,dm,better_hypothesis,realign,combined; calibrate=1; }
method_args=(--methods "$methods")
# Two workers, each on its own core, each running whole logs (timings stay one-core timings).
worker() {
  local core="$1"; shift
  local pin=(env RAYON_NUM_THREADS=1)
  command -v taskset >/dev/null && pin+=(taskset -c "$core")
  for log in "$@"; do
    echo "invalid-merge $log ($(wc -l < "$work/$log.cases.jsonl") cases) …" >&2
    "${pin[@]}" "$bin" eval invalid-merge --cases "$work/$log.cases.jsonl" \
      -o "$work/$log.results.jsonl" "${method_args[@]}" "${engine_args[@]}" \
      --report "$work/$log.table.md" > /dev/null
  done
}
# The machine's memory latency beside the times (gridmap's update is bound by it, §8).
memory_latency "$out/memory-latency.md"
even=(); odd=()
for k in "${!logs[@]}"; do
  if (( k % 2 == 0 )); then even+=("${logs[$k]}"); else odd+=("${logs[$k]}"); fi
done
worker 0 "${even[@]}" & first=$!
[[ ${#odd[@]} -gt 0 ]] && { worker 1 "${odd[@]}" & second=$!; wait "$second"; }
wait "$first"
total_secs=$(( $(date +%s) - started ))
{
  echo "# Invalid-merge detection on the public logs (Holoch et al., Table III)"
  echo
  echo "Run $(date -u +%Y-%m-%dT%H:%M)Z by \`scripts/bench_invalid_merge.sh --seed $seed --max-pairs $max_pairs${methods:+ --methods $methods} --valid-at $valid_at ${length_args[*]} --odometry-noise $noise${engine_args[*]:+ ${engine_args[*]}}\`"
  echo "($(nproc) cores; cases made in ${made_secs} s, ${total_secs} s in all). Per log:"
  echo "\`mapmerge eval make-merge-cases --log L --corrected L -o L.cases.jsonl --seed $seed --max-pairs $max_pairs --valid-at $valid_at ${length_args[*]} --odometry-noise $noise\`,"
  echo "then \`mapmerge eval invalid-merge --cases L.cases.jsonl -o L.results.jsonl --report L.table.md\` on one core."
  if [[ "$valid_at" == merge-place ]]; then
    echo "Valid merges are the true relative pose at the merge place (the evaluator applies it to its"
    echo "own estimates); per pair one valid and one invalid case of each kind: a 90/180/270° turn,"
    echo "a 2–8 m shift, the best-scoring wrong pose within ±4 m at any heading (careless)."
  else
    echo "Segments of ~100 s (35 scans where stamps are broken); per pair one valid merge (the truth"
    echo "between the start frames) and up to two invalid ones (careless place recognition, a"
    echo "look-alike with SM ≥ 0.9), each ≥ 1 m or 10° off where the robot is."
  fi
  echo
  echo "| log | segments | overlapping pairs | pairs used | valid | invalid (place / look-alike / rotation / shift / careless) |"
  echo "|---|---|---|---|---|---|"
  python3 - "$made" <<'PY'
import json, os, sys
for line in open(sys.argv[1]):
    r = json.loads(line)
    name = os.path.basename(r["log"]).split("-corrected")[0]
    kinds = " / ".join(str(r.get("invalid_" + k, 0)) for k in ("place", "lookalike", "rotation", "shift", "careless"))
    print(f"| {name} | {r['segments']} | {r['pairs_overlapping']} | {r['pairs_used']} | {r['valid']} | {kinds} |")
PY
  echo
  # One table: the first log's header, every log's rows, the first log's footnote.
  header_done=0
  for log in "${logs[@]}"; do
    table="$work/$log.table.md"
    if [[ $header_done == 0 ]]; then head -n 2 "$table"; header_done=1; fi
    grep -E '^\| [a-z0-9-]+ \| ' "$table" | grep -v '^| log |' || true
  done
  echo
  grep -E '^AUC:' "$work/${logs[0]}.table.md" | sed -E 's/ [0-9.]+ s in all\.$//' || true
} > "$out/invalid-merge.md"
for log in "${logs[@]}"; do cat "$work/$log.results.jsonl"; done > "$work/results.jsonl"
echo "wrote $out/invalid-merge.md" >&2
# Issue 15, part 4: every decision fitted on the other logs and scored on each log in turn.
if [[ $calibrate == 1 ]]; then
  "$bin" eval calibrate --results "$work/results.jsonl" --report "$out/calibrate.md" > /dev/null
  # The same with re-registration among the learned model's inputs (docs/benchmarks.md §8,
  # session 2026-11-28 (iii)).
  with_realign=change_detection,gridmap,histogram,sm,dm,better_hypothesis,realign
  "$bin" eval calibrate --results "$work/results.jsonl" --report "$out/calibrate-realign.md" \
    --features "$with_realign" > /dev/null
  # The random forest on the same features (session 2026-12-03; not the default, by its rule).
  "$bin" eval calibrate --results "$work/results.jsonl" --report "$out/calibrate-realign-forest.md" \
    --features "$with_realign" --model forest > /dev/null
  echo "wrote $out/calibrate.md, $out/calibrate-realign.md and $out/calibrate-realign-forest.md" >&2
fi
