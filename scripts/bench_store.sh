#!/usr/bin/env bash
# The lifelong store over many sessions (issue 17, part 3): one simulated world, one
# `mapmerge atlas --store` process per session, as a robot lives; then the per-session table.
#
#   scripts/bench_store.sh [--world office] [--seed 3] [--sessions 200] [--duration 60]
#                          [--no-prune] [--out-dir bench-out/store/NAME] [--keep-versions 10]
#                          [--config ENGINE.json]
#
# Writes OUT/sessions/K.json (each run's `--json` report, with `wall_s`, the process's wall
# time, added) and OUT/table.md (scripts/store_table.py). A run that stops (a failed
# session) keeps what it measured.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/bench_common.sh
world=office seed=3 sessions=200 duration=60 prune=1 keep=10 out="" config=""
while [[ $# -gt 0 ]]; do
  case "$1" in
    --world) world=$2; shift 2 ;;
    --seed) seed=$2; shift 2 ;;
    --sessions) sessions=$2; shift 2 ;;
    --duration) duration=$2; shift 2 ;;
    --no-prune) prune=0; shift ;;
    --keep-versions) keep=$2; shift 2 ;;
    --out-dir) out=$2; shift 2 ;;
    --config) config=$2; shift 2 ;;
    *) echo "unknown option $1" >&2; exit 2 ;;
  esac
done
name="$world-seed$seed-$([[ $prune == 1 ]] && echo pruned || echo unpruned)"
out=${out:-bench-out/store/$name}
bin=$(mapmerge_bin)
mkdir -p "$out/sessions"
rm -f "$out/site.mapmerge" "$out/site.mapmerge-wal" "$out"/sessions/*.json
extra=()
[[ $prune == 1 ]] || extra+=(--no-prune)
[[ -z $config ]] || extra+=(--config "$config")
for ((k = 0; k < sessions; k++)); do
  start=$(date +%s.%N)
  if ! "$bin" atlas --sim "$world" --seed "$seed" --session-index "$k" --duration "$duration" \
      --no-pictures --store "$out/site.mapmerge" --keep-versions "$keep" "${extra[@]}" \
      -o "$out/run" --json > "$out/sessions/$k.tmp"; then
    echo "session $k failed; stopping" >&2
    break
  fi
  end=$(date +%s.%N)
  python3 - "$out/sessions/$k.tmp" "$out/sessions/$k.json" "$start" "$end" <<'PY'
import json, sys
report = json.load(open(sys.argv[1]))
report["wall_s"] = float(sys.argv[4]) - float(sys.argv[3])
json.dump(report, open(sys.argv[2], "w"))
PY
  rm -f "$out/sessions/$k.tmp"
  if (( k % 10 == 0 )); then echo "session $k done" >&2; fi
done
python3 scripts/store_table.py "$out" > "$out/table.md"
cat "$out/table.md"
