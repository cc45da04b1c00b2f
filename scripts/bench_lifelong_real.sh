#!/usr/bin/env bash
# Issue 64: the lifelong engine under real conditions, judged from its per-map trajectories
# (`mapmerge eval lifelong`). Each corrected log runs once per seed as a kidnapped robot
# recorded it (seeded noisy odometry, 1-4 carries by travel, odometry going on as if not
# moved); each simulated world once per seed with its kidnaps.
# Split: tuning logs intel, aces, freiburg-079, freiburg-101, fhw, seattle, belgioioso,
# infinite-corridor; held-out logs csail, acapulco, freiburg-campus, edmonton, orebro (run
# once, when the issue ends). Simulator: tuning seeds 1-10, held-out seeds 101-110.
# Usage: scripts/bench_lifelong_real.sh [--set tuning|held-out|sim-tuning|sim-held-out]...
#        [--seeds 1-3] [--jobs N] [--config ENGINE.json] [--hide-kidnaps] [--no-kidnaps]
#        [--noise default|harsh]
# Issue 65: --hide-kidnaps withholds the kidnaps (the tracker must find them); --no-kidnaps
# carries the logs nowhere (every break is false). Each set also reports the kidnaps found
# within 10 scans and the false breaks per 500 m.
# Writes bench-out/lifelong-real/<set>.md and one JSON per run group. MAPMERGE_BIN=PATH runs
# another build. Every run is on one core (RAYON_NUM_THREADS=1) for the time per scan.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/bench_common.sh
sets=(); seeds="1-3"; jobs=2; config=(); extra=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --set) sets+=("$2"); shift 2 ;;
    --seeds) seeds="$2"; shift 2 ;;
    --jobs) jobs="$2"; shift 2 ;;
    --config) config=(--config "$(realpath "$2")"); shift 2 ;;
    --hide-kidnaps|--no-kidnaps) extra+=("$1"); shift ;;
    --noise) extra+=(--noise "$2"); shift 2 ;;
    *) echo "usage: $0 [--set tuning|held-out|sim-tuning|sim-held-out]... [--seeds A-B] [--jobs N] [--config F] [--hide-kidnaps] [--no-kidnaps] [--noise P]" >&2; exit 2 ;;
  esac
done
(( ${#sets[@]} )) || sets=(tuning sim-tuning)
bin="$(mapmerge_bin)"
data="${MAPMERGE_DATA:-../shared/data}"
out="$(realpath -m "${OUT_DIR:-bench-out}")/lifelong-real"
mkdir -p "$out"
worlds=(office office-aliased corridor-loop warehouse symmetric-hall)
run() { # group name, eval arguments...
  local name="$1"; shift
  RAYON_NUM_THREADS=1 "$bin" eval lifelong "$@" "${config[@]}" "${extra[@]}" -o "$out/runs" --json \
    > "$out/$name.json" 2> "$out/$name.err"
}
for set in "${sets[@]}"; do
  case "$set" in
    tuning) logs=(intel aces freiburg-079 freiburg-101 fhw seattle belgioioso infinite-corridor) ;;
    held-out) logs=(csail acapulco freiburg-campus edmonton orebro) ;;
    sim-tuning|sim-held-out) logs=() ;;
    *) echo "unknown set $set" >&2; exit 2 ;;
  esac
  for log in "${logs[@]}"; do
    run "$set-$log" "$data/carmen/$log-corrected.log.xz" --seeds "$seeds" &
    while (( $(jobs -rp | wc -l) >= jobs )); do wait -n; done
  done
  if [[ "$set" == sim-* ]]; then
    range=101-110; [[ "$set" == sim-tuning ]] && range=1-10
    for world in "${worlds[@]}"; do
      run "$set-$world" --sim "$world" --sim-seeds "$range" &
      while (( $(jobs -rp | wc -l) >= jobs )); do wait -n; done
    done
  fi
done
wait
python3 - "$out" "${sets[@]}" <<'PY'
import json, sys, glob, os, math
out, sets = sys.argv[1], sys.argv[2:]
def q(values, p):
    if not values: return "—"
    v = sorted(values); return f"{v[max(0, math.ceil(p * len(v)) - 1)]:.1f}"  # nearest rank
for s in sets:
    runs = []
    for f in sorted(glob.glob(os.path.join(out, f"{s}-*.json"))):
        runs.extend(json.load(open(f))["runs"])
    lines = ["| run | scans | revisiting segments | merged and placed | misplaced | lost: no match / hypothesis / conditional / undone / misplaced | to conditional m | to full m | ms/scan |",
             "|---|---|---|---|---|---|---|---|---|"]
    tot = dict(rev=0, ok=0, mis=0, scans=0, ms=0.0)
    lost = [0] * 5; cond = []; full = []
    for r in runs:
        l = r["lost"]; ls = [l["no_match"], l["hypothesis"], l["conditional"], l["undone"], l["misplaced"]]
        lost = [a + b for a, b in zip(lost, ls)]
        cond += r["to_conditional_m"]; full += r["to_full_m"]
        tot["rev"] += r["revisiting"]; tot["ok"] += r["merged"]; tot["mis"] += r["misplaced"]
        tot["scans"] += r["scans"]; tot["ms"] += r["ms_per_scan"] * r["scans"]
        lines.append(f"| {r['run']} | {r['scans']} | {r['revisiting']} | {r['merged']} | {r['misplaced']} | {' / '.join(map(str, ls))} | {', '.join(f'{d:.1f}' for d in r['to_conditional_m'])} | {', '.join(f'{d:.1f}' for d in r['to_full_m'])} | {r['ms_per_scan']:.2f} |")
    share = f"{tot['ok'] / tot['rev']:.0%}" if tot["rev"] else "—"
    lines.append(f"| **{s}** | {tot['scans']} | {tot['rev']} | **{tot['ok']} ({share})** | {tot['mis']} | {' / '.join(map(str, lost))} | median {q(cond, .5)}, p90 {q(cond, .9)} | median {q(full, .5)}, p90 {q(full, .9)} | {tot['ms'] / max(tot['scans'], 1):.2f} |")
    b = dict(kidnaps=0, detected=0, late=0, false_breaks=0, travel_m=0.0)
    for r in runs:
        for k in b: b[k] += r["breaks"][k]
    per500 = f"{500 * b['false_breaks'] / b['travel_m']:.2f}" if b["travel_m"] else "—"
    lines.append(f"\nkidnaps found within 10 scans: {b['detected']} of {b['kidnaps']} ({b['late']} later); false breaks {b['false_breaks']} over {b['travel_m'] / 1000:.1f} km ({per500} per 500 m)")
    text = "\n".join(lines)
    open(os.path.join(out, f"{s}.md"), "w").write(text + "\n")
    print(f"## {s}\n\n{text}\n")
PY
