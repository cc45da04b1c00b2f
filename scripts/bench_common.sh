# Shared by the benchmark scripts (sourced).
# The mapmerge binary a benchmark runs: $MAPMERGE_BIN when set (a copy, so that builds during
# a run do not replace it), else a fresh release build of mapmerge-cli. Prints its path.
mapmerge_bin() {
  if [[ -n "${MAPMERGE_BIN:-}" ]]; then
    echo "$MAPMERGE_BIN"
  else
    cargo build --release -q -p mapmerge-cli >&2
    realpath target/release/mapmerge
  fi
}
