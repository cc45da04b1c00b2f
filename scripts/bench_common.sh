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
# The machine's memory latency on core 0 (`cargo bench -p mapmerge-verify --bench
# memory_latency`, a Markdown table) into file $1: timings that wait on memory (the matcher,
# gridmap) follow it, and it has varied tenfold between sessions on this machine.
memory_latency() {
  local pin=(); command -v taskset >/dev/null && pin=(taskset -c 0)
  "${pin[@]}" cargo bench -q -p mapmerge-verify --bench memory_latency > "$1"
}
