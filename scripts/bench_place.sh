#!/usr/bin/env bash
# Place recognition (issue 4, part 5): precision and recall of verified loops, one default
# configuration, on the 13 public corrected logs (intra-log, no pose guess) and on the
# simulator's look-alike office (sessions 1 and 2 against session 0).
# Definitions: crates/lab/lab/examples/support/place_eval.rs.
# Usage: scripts/bench_place.sh [--only NAME]... (NAME = a log, or `sim`)
# Writes bench-out/place.md (+ bench-out/place/runs.jsonl).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/log_split.sh
only=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --only) only+=("$2"); shift 2 ;;
    *) echo "usage: $0 [--only NAME]..." >&2; exit 2 ;;
  esac
done
data="${MAPMERGE_DATA:-../shared/data}"
out="${OUT_DIR:-bench-out}"
mkdir -p "$out/place"
if [[ -z "${PLACE_BENCH_BIN:-}" ]]; then
  cargo build --release -q -p mapmerge-lab --example place_benchmark
  bin=target/release/examples/place_benchmark
else
  bin="$PLACE_BENCH_BIN"   # a copy, so that builds during the run do not replace it
fi
names=("${ALL_LOGS[@]}" sim)
[[ ${#only[@]} -gt 0 ]] && names=("${only[@]}")
results="$out/place/runs.jsonl"; : > "$results"
for name in "${names[@]}"; do
  if [[ "$name" == sim ]]; then
    "$bin" --sim testdata/sim/office-aliased >> "$results"
  else
    "$bin" "$data/carmen/$name-corrected.log.xz" >> "$results"
  fi
  echo "done $name" >&2
done
python3 - "$results" "$*" "${HELD_OUT_LOGS[*]}" "${TUNING_LOGS[*]}" > "$out/place.md" <<'PY'
import json, sys
runs = [json.loads(l) for l in open(sys.argv[1])]
print("Place recognition with the default configuration (`BenchConfig::default()` in")
print("crates/lab/lab/examples/support/place_eval.rs), measured by")
print("`scripts/bench_place.sh" + (" " + sys.argv[2] if sys.argv[2] else "") + "`.\n")
print("Public logs: intra-log, each keyframe against the keyframes ≥ 10 m of travel earlier, no pose")
print("guess. sim: sessions 1 and 2 of testdata/sim/office-aliased against session 0. A loop is true")
print("within 0.5 m and 10° of the reference relative pose; a revisit is an indexed keyframe within")
print("1 m and 30° (sim: any heading, 360° lidar). *retrieved*: revisits with a keyframe within 1 m and")
print("30° among the retrieved candidates, descriptor yaw within 20°; *verified*: revisits with a")
print("candidate verified to the true pose (the ceiling of any acceptance rule). *refused*: queries whose")
print("best verified candidate missed the score or the confidence threshold, how many of those were")
print("wrong, and how many of the wrong ones put the query into a look-alike room (sim). *Uniqueness*:")
print("refusals because a distinct placement fits nearly as well, the query turned by 180° (refused by")
print("score, would have passed without the turned fit) and a rival place (refused by confidence), each")
print("with how many of them were wrong.\n")
held_out, tuning = set(sys.argv[3].split()), set(sys.argv[4].split())
set_of = lambda name: "held-out" if name in held_out else "tuning" if name in tuning else "–"
print("| log | set | keyframes | queries | revisits | accepted | true | precision | recall | retrieved | verified | refused by score: all / wrong / look-alike | refused by confidence: all / wrong / look-alike | uniqueness: turned / rival place (wrong) | ms per query (median) |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
keys = ["revisits", "accepted", "true", "recalled", "retrieved", "verified", "refused_by_flip", "refused_by_flip_wrong", "refused_by_confidence", "refused_by_confidence_wrong"]
for r in runs:
    by_score = f"{r['refused_by_score']} / {r['refused_by_score_wrong']} / {r['refused_by_score_look_alike']}"
    refused = f"{by_score} | {r['refused_by_confidence']} / {r['refused_by_confidence_wrong']} / {r['refused_by_confidence_look_alike']}"
    median = f" ({r['ms_per_query_median']:.0f})" if 'ms_per_query_median' in r else ""
    unique = f"{r['refused_by_flip']} ({r['refused_by_flip_wrong']}) / {r['refused_by_confidence']} ({r['refused_by_confidence_wrong']})"
    print(f"| {r['name']} | {set_of(r['name'])} | {r['keyframes']} | {r['queries']} | {r['revisits']} | {r['accepted']} | {r['true']} "
          f"| {r['precision']:.3f} | {r['recall']:.3f} | {r['retrieved']} | {r['verified']} | {refused} | {unique} | {r['ms_per_query']:.0f}{median} |")
for label, names in [("**held-out logs**", held_out), ("**tuning logs**", tuning), ("**all public logs**", held_out | tuning)]:
    tot = {k: sum(r[k] for r in runs if r['name'] in names) for k in keys}
    if not tot['revisits']:
        continue
    p = tot['true'] / tot['accepted'] if tot['accepted'] else 1.0
    share = lambda k: f"{tot[k]} ({100 * tot[k] / tot['revisits']:.1f} %)"
    print(f"| {label} | | | | {tot['revisits']} | {tot['accepted']} | {tot['true']} | {p:.3f} | "
          f"{tot['recalled'] / tot['revisits']:.3f} | {share('retrieved')} | {share('verified')} | | | {tot['refused_by_flip']} ({tot['refused_by_flip_wrong']}) / {tot['refused_by_confidence']} ({tot['refused_by_confidence_wrong']}) | |")
sims = [r for r in runs if r['name'].startswith('sim')]
for r in sims:
    print(f"\n{r['name']}: {r['revisits_in_look_alike_rooms']} of the {r['revisits']} revisits are in rooms with "
          f"look-alikes ({r['recalled_in_look_alike_rooms']} recalled).")
PY
cat "$out/place.md"
