#!/usr/bin/env bash
# Issue 19, target "evo": `mapmerge slam --odometry-noise default --seed 1` on every public log,
# then the ATE of its trajectory.tum against reference.tum by `mapmerge eval ate` and by evo
# (`evo_ape tum --align`, SE(3) Umeyama). EVO_APE names evo_ape (default: the one on PATH).
# Usage: scripts/bench_evo.sh [LOG_NAME ...]. Writes bench-out/evo.md.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/log_split.sh
source scripts/bench_common.sh
logs=("$@")
[[ ${#logs[@]} -eq 0 ]] && logs=("${ALL_LOGS[@]}")
data="${MAPMERGE_DATA:-../shared/data}"
evo="${EVO_APE:-evo_ape}"
out="$(realpath -m "${OUT_DIR:-bench-out}")/evo"
mkdir -p "$out"
bin="$(realpath "$(mapmerge_bin)")"
{
  echo "| log | scans | TUM stamps | mapmerge eval ate RMS (m) | evo_ape RMSE (m) | difference (m) |"
  echo "|---|---|---|---|---|---|"
  for name in "${logs[@]}"; do
    dir="$out/$name"
    slam=$("$bin" slam "$data/carmen/$name-corrected.log.xz" --odometry-noise default --seed 1 -o "$dir" --json)
    ours=$("$bin" eval ate --trajectory "$dir/trajectory.tum" --reference "$dir/reference.tum" --json \
      | python3 -c "import json,sys; print(repr(json.load(sys.stdin)['ate']['rms_m']))")
    theirs=$("$evo" tum "$dir/reference.tum" "$dir/trajectory.tum" --align --no_warnings | awk '$1=="rmse"{print $2}')
    echo "$slam" | python3 -c "
import json, sys
d = json.load(sys.stdin)
ours, theirs = float('$ours'), float('$theirs')
stamps = 'clock (log stamps do not increase)' if d['tum_stamps_rewritten'] else 'the log\'s'
print(f\"| $name | {d['scans']} | {stamps} | {ours:.6f} | {theirs:.6f} | {abs(ours - theirs):.1e} |\")"
  done
} > "$out/../evo.md"
cat "$out/../evo.md"
