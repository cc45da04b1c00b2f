#!/usr/bin/env bash
# Issue 5: Andersone's grid-merge experiment (Tables 1–4, ROC/AUC of SM and DM, update times)
# on every public corrected log, and the matching success rate on crops of the real building
# maps. Usage: scripts/bench_grid_merge.sh [--merges N] [--seed S] [--only NAME]...
# Writes bench-out/grid-merge.md (experiment) and bench-out/grid-match.md (crops).
set -euo pipefail
cd "$(dirname "$0")/.."
merges=20; seed=0; only=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --merges) merges="$2"; shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    --only) only+=("$2"); shift 2 ;;
    *) echo "usage: $0 [--merges N] [--seed S] [--only NAME]..." >&2; exit 2 ;;
  esac
done
data="${MAPMERGE_DATA:-../shared/data}"
out="$(realpath -m "${OUT_DIR:-bench-out}")"
mkdir -p "$out"
cargo build --release -q -p mapmerge-cli
logs=(intel acapulco aces belgioioso csail edmonton fhw freiburg-079 freiburg-101 freiburg-campus infinite-corridor orebro seattle)
[[ ${#only[@]} -gt 0 ]] && logs=("${only[@]}")
paths=()
for log in "${logs[@]}"; do paths+=("$data/carmen/$log-corrected.log.xz"); done
target/release/mapmerge eval grid-merge "${paths[@]}" --merges "$merges" --seed "$seed" \
  -o "$out/grid-merge.md" --json > "$out/grid-merge.json"
echo "wrote $out/grid-merge.md"
MAPMERGE_DATA="$data" cargo run --release -q -p mapmerge-lab --example match_benchmark -- \
  --pairs 30 --seed 1 | tee "$out/grid-match.md"
