#!/usr/bin/env bash
# Issue 14: the lifelong engine with evidence-accumulating merges (`mapmerge atlas`).
# 1. Simulator: tuning seeds 1-10 of office-aliased (the only data the decision parameters
#    were tuned on) and held-out seeds 101-110 of every world preset; every merge judged
#    against the simulator's ground truth.
# 2. Public logs: intel, aces, freiburg-079 with three kidnaps each (at 1/4, 1/2, 3/4 of the
#    scans), merges judged against the corrected poses (--judge-with-log-poses).
#    With --fitting-seeds, also seeds 1-20 of every world (the seeds the engine's learned
#    decision is fitted on, scripts/fit_engine_decision.sh; none of them held out).
# Usage: scripts/bench_lifelong.sh [--jobs N] [--only sim|logs] [--config ENGINE.json]
#        [--fitting-seeds].
# Writes bench-out/lifelong.md (OUT_DIR=… elsewhere). MAPMERGE_BIN=PATH runs another build;
# --config passes engine parameters to every run (e.g. {"detector": "combined"}).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/bench_common.sh
jobs=2; only=""; config=(); fitting=0
while [[ $# -gt 0 ]]; do
  case "$1" in
    --jobs) jobs="$2"; shift 2 ;;
    --only) only="$2"; shift 2 ;;
    --config) config=(--config "$(realpath "$2")"); shift 2 ;;
    --fitting-seeds) fitting=1; shift ;;
    *) echo "usage: $0 [--jobs N] [--only sim|logs] [--config ENGINE.json] [--fitting-seeds]" >&2; exit 2 ;;
  esac
done
if [[ -z "${MAPMERGE_BIN:-}" ]]; then cargo build --release -q -p mapmerge-cli; fi
bin="$(realpath "${MAPMERGE_BIN:-target/release/mapmerge}")"
data="${MAPMERGE_DATA:-../shared/data}"
out="$(realpath -m "${OUT_DIR:-bench-out}")/lifelong"
mkdir -p "$out"
run() { # name, args...
  local name="$1"; shift
  "$bin" atlas "$@" "${config[@]}" --no-pictures -o "$out/$name" --json > "$out/$name.json" 2> "$out/$name.err"
}
if [[ "$only" != logs ]]; then
  for seed in $(seq 1 10); do
    run "tune-office-aliased-$seed" --sim office-aliased --seed "$seed" &
    while (( $(jobs -rp | wc -l) >= jobs )); do wait -n; done
  done
  every_world() { # prefix, first seed, last seed
    for world in office office-aliased corridor-loop warehouse symmetric-hall; do
      for seed in $(seq "$2" "$3"); do
        run "$1-$world-$seed" --sim "$world" --seed "$seed" &
        while (( $(jobs -rp | wc -l) >= jobs )); do wait -n; done
      done
    done
  }
  if (( fitting )); then every_world fit 1 20; fi
  every_world held 101 110
fi
if [[ "$only" != sim ]]; then
  for log in intel aces freiburg-079; do
    path="$data/carmen/$log-corrected.log.xz"
    n=$(python3 -c "import lzma,sys; print(sum(1 for l in lzma.open(sys.argv[1],'rt') if l.startswith(('FLASER','ROBOTLASER1','RAWLASER'))))" "$path")
    # One core for the timing target.
    one_core=(env RAYON_NUM_THREADS=1)
    command -v taskset >/dev/null && one_core+=(taskset -c 0)
    "${one_core[@]}" "$bin" atlas "$path" "${config[@]}" --kidnap-at "$((n / 4)),$((n / 2)),$((3 * n / 4))" \
      --judge-with-log-poses --no-pictures -o "$out/log-$log" --json > "$out/log-$log.json" 2> "$out/log-$log.err"
  done
  # Beside the times: the engine's time is mostly the matcher's grid loads (§10).
  memory_latency "$out/memory-latency.md"
fi
wait
python3 - "$out" > "$out/../lifelong.md" <<'PY'
import json, sys, glob, os
out = sys.argv[1]
def load(pattern):
    runs = []
    for f in sorted(glob.glob(os.path.join(out, pattern))):
        try:
            runs.append((os.path.basename(f)[:-5], json.load(open(f))))
        except Exception as e:
            print(f"<!-- {f}: {e} -->")
    return runs
def row(label, runs):
    epochs = sum(r["epochs"] - 1 for _, r in runs)
    merged = sum(r["epochs_merged_correctly"] or 0 for _, r in runs)
    wrong = sum(r["wrong_merges"] or 0 for _, r in runs)
    wrong_ok = sum(r["wrong_undone_within_10m"] or 0 for _, r in runs)
    correct = sum(r["correct_merges"] or 0 for _, r in runs)
    correct_undone = sum(r["correct_undone"] or 0 for _, r in runs)
    correct_rejected = sum(r["correct_rejected"] or 0 for _, r in runs)
    cond = sum(r["hypotheses"]["conditional"] for _, r in runs)
    rej = sum(r["hypotheses"]["rejected_conditional"] for _, r in runs)
    amb = sum(r["ambiguous_keyframes"] for _, r in runs)
    scans = sum(r["scans"] for _, r in runs); secs = sum(r["seconds"] for _, r in runs)
    share = f"{merged / epochs:.0%}" if epochs else "—"
    rej_share = f"{rej / cond:.1%}" if cond else "—"
    # Epochs that travelled ≥ 5 m where an earlier epoch had been (older builds: "—").
    if all(r.get("epochs_revisiting") is not None for _, r in runs):
        revisiting = sum(r["epochs_revisiting"] for _, r in runs)
        revisit_merged = sum(r["epochs_revisiting_merged_correctly"] for _, r in runs)
        revisits = f"{revisit_merged} of {revisiting}" + (f" ({revisit_merged / revisiting:.0%})" if revisiting else "")
    else:
        revisits = "—"
    print(f"| {label} | {len(runs)} | {epochs} | {merged} ({share}) | {revisits} | {wrong} | {wrong_ok} of {wrong} | {correct} | {correct_undone} | {correct_rejected} | {cond} | {rej} ({rej_share}) | {amb} | {1e3 * secs / max(scans, 1):.1f} |")
print("| runs | count | epochs after the first | ending correctly merged | of those revisiting ≥ 5 m, ending correctly merged | wrong merges | wrong rejected/undone ≤ 10 m | correct merges | correct undone | correct rejected (conditional) | conditional merges | conditional later rejected | ambiguous keyframes | ms/scan |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
tune = load("tune-office-aliased-*.json")
if tune: row("tuning: office-aliased seeds 1–10", tune)
for world in ["office", "office-aliased", "corridor-loop", "warehouse", "symmetric-hall"]:
    fit = load(f"fit-{world}-[0-9]*.json")
    if fit: row(f"fitting: {world} seeds 1–20", fit)
fit_all = load("fit-*.json")
if fit_all: row("**fitting: all worlds**", fit_all)
for world in ["office", "office-aliased", "corridor-loop", "warehouse", "symmetric-hall"]:
    held = load(f"held-{world}-[0-9]*.json")
    if held: row(f"held out: {world} seeds 101–110", held)
held_all = load("held-*.json")
if held_all: row("**held out: all worlds**", held_all)
logs = load("log-*.json")
if logs:
    print()
    print("| log | scans | epochs after the first | ending correctly merged | wrong merges | wrong kept | merge decisions (state, correct) | ms/scan (one core) |")
    print("|---|---|---|---|---|---|---|---|")
    for name, r in logs:
        kept_wrong = sum(1 for m in r["merges"] if m["correct"] is False and m["state"] in ("full", "conditional"))
        decisions = ", ".join(f"{m['state']} {'✓' if m['correct'] else '✗' if m['correct'] is False else '?'}" for m in r["merges"]) or "none"
        print(f"| {name[4:]} | {r['scans']} | {r['epochs'] - 1} | {r['epochs_merged_correctly']} | {r['wrong_merges']} | {kept_wrong} | {decisions} | {r['ms_per_scan']:.1f} |")
    # The time target: the average over every scan of the three runs.
    scans = sum(r["scans"] for _, r in logs)
    seconds = sum(r["seconds"] for _, r in logs)
    print(f"| **all** | {scans} | | | | | | {1e3 * seconds / max(scans, 1):.2f} |")
    latency = os.path.join(out, "memory-latency.md")
    if os.path.exists(latency):
        print()
        print("Memory latency on core 0 right after these runs (`cargo bench -p mapmerge-verify --bench memory_latency`):")
        print()
        print(open(latency).read().strip())
PY
cat "$out/../lifelong.md"
