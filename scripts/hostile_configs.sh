#!/usr/bin/env bash
# Issue 67's hostile configs, each through the command that reads it: exit code, wall time and
# peak memory (GNU time), and the first line of the message. A Markdown table on stdout.
#
#   scripts/hostile_configs.sh [--out-dir bench-out/hostile]
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/bench_common.sh
out=bench-out/hostile
[[ ${1:-} == --out-dir ]] && out=$2
bin=$(mapmerge_bin)
rm -rf "$out" && mkdir -p "$out"
"$bin" sim --sessions 1 --duration 15 --no-pictures -o "$out/sim" > /dev/null
log="$out/sim/session_0.log"
cases=(
  'slam|{"tracker": {"matcher": {"correlative": {"max_grid_cells": 18446744073709551615, "resolution_m": 0.001}}}}'
  'slam|{"atlas": {"loops": {"matcher": {"icp": {"max_iterations": 4294967295}}}}}'
  'atlas|{"atlas": {"loops": {"place_gate": [-1, 0.1, 0.1, 0.001]}}}'
  'atlas|{"atlas": {"recognition": {"place": {"min_score": -0.5}}}}'
  'slam|{"tracker": {"keyframes": {"min_translation_m": -0.25}}}'
  'slam|{"tracker": {"max_match_range_m": -20}}'
  'slam|{"tracker": {"min_edge_sigma": [-0.01, 0.003]}}'
  'atlas|{"atlas": {"optimizer": {"robust": {"kind": "dcs", "phi": -1}}}}'
  'atlas|{"atlas": {"loops": {"optimize_every_keyframes": 0}}}'
  'slam|{"decisions": {"probation_m": -5}}'
  'atlas|{"decisions": {"probation_m": -5}}'
  'areas|{"tracking": {"base_radius_m": -1}}'
)
echo "| command | config | exit | s | MB | message |"
echo "|---|---|---|---|---|---|"
k=0
for entry in "${cases[@]}"; do
  k=$((k + 1))
  command=${entry%%|*}
  printf '%s\n' "${entry#*|}" > "$out/c$k.json"
  args=("$command" "$log" -o "$out/o$k")
  [[ $command == atlas ]] && args+=(--no-pictures)
  set +e
  /usr/bin/time -f '%e %M' -o "$out/t$k" "$bin" "${args[@]}" --config "$out/c$k.json" \
    > /dev/null 2> "$out/e$k"
  code=$?
  set -e
  read -r seconds kb < <(tail -1 "$out/t$k")
  message=$(head -1 "$out/e$k" | sed "s|$out/||; s/|/\\\\|/g")
  echo "| $command | \`$(cat "$out/c$k.json")\` | $code | $seconds | $((kb / 1024)) | $message |"
done
