#!/usr/bin/env bash
# Issue 7, part 7: AutoMerge-style assembly on segments cut from the 13 public corrected logs.
# Per log: `mapmerge split LOG --segments N --overlap F --odometry-noise default --seed S -o DIR`
# (ground truth kept apart in DIR/truth), then `mapmerge eval assemble --split DIR --orders 20
# --json`: loop-edge precision, pair recall and coverage, groups against the truth's, ATE per
# group, order invariance over 20 random arrival orders.
# Usage: scripts/bench_assemble.sh [--segments N] [--overlap F] [--seed S] [--only NAME]...
# Writes bench-out/assemble.md (+ bench-out/assemble/*): one row per log, then the totals of the
# tuning and the held-out logs (scripts/log_split.sh). The pooled run of all 13 logs in one
# assembly is scripts/bench_assemble_pool.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/log_split.sh
source scripts/bench_common.sh
segments=8; overlap=0.1; seed=0; only=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --segments) segments="$2"; shift 2 ;;
    --overlap) overlap="$2"; shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    --only) only+=("$2"); shift 2 ;;
    *) echo "usage: $0 [--segments N] [--overlap F] [--seed S] [--only NAME]..." >&2; exit 2 ;;
  esac
done
data="${MAPMERGE_DATA:-../shared/data}"
out="$(realpath -m "${OUT_DIR:-bench-out}")"
work="$out/assemble"
mkdir -p "$work"
bin="$(mapmerge_bin)"
logs=("${ALL_LOGS[@]}")
[[ ${#only[@]} -gt 0 ]] && logs=("${only[@]}")
: > "$work/scores.jsonl"
for log in "${logs[@]}"; do
  dir="$work/$log"
  rm -rf "$dir"
  "$bin" split "$data/carmen/$log-corrected.log.xz" --segments "$segments" --overlap "$overlap" \
    --odometry-noise default --seed "$seed" -o "$dir" --json > "$work/$log.split.json"
  echo "assemble $log …" >&2
  started=$(date +%s.%N)
  "$bin" eval assemble --split "$dir" --orders 20 --json \
    --edges "$work/$log.edges.jsonl" --pairs "$work/$log.pairs.jsonl" > "$work/$log.score.json"
  python3 - "$work/$log.score.json" "$log" "$started" "$(log_set "$log")" >> "$work/scores.jsonl" <<'PY'
import json, sys, time
score = json.load(open(sys.argv[1]))
score["log"] = sys.argv[2]
score["set"] = sys.argv[4]
score["wall_secs"] = time.time() - float(sys.argv[3])
print(json.dumps(score))
PY
done
python3 - "$work/scores.jsonl" "$segments" "$overlap" "$seed" > "$out/assemble.md" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
pct = lambda x: "–" if x is None else f"{100 * x:.1f} %"
print(f"Segments per log: {sys.argv[2]}, overlap {sys.argv[3]}, odometry noise `default`, seed {sys.argv[4]}.\n")
print("| log | set | scans | loop edges (true) | precision | overlapping pairs (found) | pair recall | coverage | false pairs | groups (truth) | groups correct | ATE per group (m) | orders same | s (traj. / assoc. / opt.) |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
def total(rs):
    t = dict(edges=0, true=0, pairs=0, found=0, correct=0, orders=0, tested=0, logs=len(rs))
    for r in rs:
        t["edges"] += r["loop_edges"]; t["true"] += r["true_edges"]
        t["pairs"] += r["overlapping_pairs"]; t["found"] += r["pairs_found"]
        t["correct"] += r["groups_correct"]; t["orders"] += r["orders_same"]; t["tested"] += r["orders_tested"]
    return t
for r in rows:
    ate = ", ".join(f"{a:.2f}" for a in r["group_ate_m"]) or "–"
    print(f"| {r['log']} | {r.get('set', '–')} | {r['scans']} | {r['loop_edges']} ({r['true_edges']}) | {pct(r['precision'])} | "
          f"{r['overlapping_pairs']} ({r['pairs_found']}) | {pct(r['pair_recall'])} | {pct(r['edge_coverage'])} | {r['false_pairs']} | "
          f"{len(r['groups'])} ({len(r['truth_groups'])}) | {'yes' if r['groups_correct'] else 'no'} | {ate} | "
          f"{r['orders_same']}/{r['orders_tested']} | {r['trajectory_secs']:.1f} / {r['association_secs']:.1f} / {r['optimisation_secs']:.1f} |")
for label, rs in [("**held-out**", [r for r in rows if r.get("set") == "held-out"]),
                  ("**tuning**", [r for r in rows if r.get("set") == "tuning"]),
                  ("**all**", rows)]:
    if not rs:
        continue
    t = total(rs)
    prec = t["true"] / t["edges"] if t["edges"] else None
    rec = t["found"] / t["pairs"] if t["pairs"] else None
    print(f"| {label} | | | {t['edges']} ({t['true']}) | {pct(prec)} | {t['pairs']} ({t['found']}) | {pct(rec)} | | | | {t['correct']}/{t['logs']} | | {t['orders']}/{t['tested']} | |")
PY
cat "$out/assemble.md"
