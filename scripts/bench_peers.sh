#!/usr/bin/env bash
# Benchmark mapmerge against its peers (GTSAM, factrs, apex-solver) side by side in one run.
#
# usage: scripts/bench_peers.sh [--global | --outliers [--seeds S,S,...]] [--repeats N] [--timeout S]
#                               [--only SUBSTRING ...] [--out-dir DIR]
#
#   (default)   pose-graph table: every graph optimised by mapmerge, GTSAM, factrs and apex,
#               median of 3 wall times; GTSAM scores mapmerge's result  -> bench-out/peers.md
#   --global    mapmerge --init global on torus3D, cubicle, ais2klinik next to GTSAM from the
#               file's initial guess                                      -> bench-out/global.md
#   --outliers  vertigo-style false loop closures (fractions 0.1, 0.5; --seeds S,S,... default 42) on M3500 and
#               city10000, mapmerge --robust gnc: precision/recall of the rejected edges, share of
#               true loop closures kept, RMS against the outlier-free optimum -> bench-out/outliers.md
#
# Environment: MAPMERGE_BIN (default: cargo build --release -p mapmerge-cli and use
# target/release/mapmerge), MAPMERGE_DATA (default: ../shared/data next to the repository),
# MAPMERGE_PEERS (default: ../shared/peers). The peers' Python environment comes from
# "$MAPMERGE_PEERS/setup.sh" (built once, cached in ~/.cache/mapmerge-peers).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
export MAPMERGE_DATA=${MAPMERGE_DATA:-$root/../shared/data}
export MAPMERGE_PEERS=${MAPMERGE_PEERS:-$root/../shared/peers}

if [ -z "${MAPMERGE_BIN:-}" ]; then
  (cd "$root" && cargo build --release -p mapmerge-cli >&2)
  MAPMERGE_BIN=$root/target/release/mapmerge
fi
export MAPMERGE_BIN
[ -x "$MAPMERGE_BIN" ] || { echo "bench_peers.sh: $MAPMERGE_BIN is not executable" >&2; exit 2; }

# shellcheck disable=SC1090
source "$("$MAPMERGE_PEERS/setup.sh")"
cd "$root"
exec python3 "$root/scripts/bench_peers.py" "$@"
