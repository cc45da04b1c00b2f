#!/usr/bin/env bash
# Issue 19 part 2: the Python `optimize` beside `mapmerge optimize`, side by side in one run, on
# city10000 with the same settings (the CLI's defaults, then --robust gnc --init global).
# Both do the same work: read the xz file, initialise, optimise, write the result.
#   CLI s         the whole `mapmerge optimize GRAPH -o OUT --json` process (wall);
#   Python s      the call `mapmerge.optimize(GRAPH, ..., output=OUT)` in a running interpreter
#                 (wall; `import mapmerge` excluded: Python's start-up is not the optimizer's);
#   ratio         Python s / CLI s (the target: within 10 %);
#   job s         the reports' own `seconds` (read to write, inside each), CLI / Python;
#   Python proc s a whole `python -c "import mapmerge; mapmerge.optimize(...)"` process, for
#                 reference (interpreter, numpy and module start-up included).
# Runs alternate (CLI, Python call, Python process) and the medians are reported.
# Usage: scripts/bench_python.sh [--repeats N] [--graph FILE]
# Environment: MAPMERGE_BIN (default: a release build of mapmerge-cli), MAPMERGE_PYTHON (a
# Python with the module installed, default python3; `pip install ./crates/app/python`),
# MAPMERGE_DATA (default ../shared/data).
set -euo pipefail
cd "$(dirname "$0")/.."
repeats=11
graph="${MAPMERGE_DATA:-../shared/data}/g2o/se-sync/city10000.g2o.xz"
while [[ $# -gt 0 ]]; do
  case "$1" in
    --repeats) repeats="$2"; shift 2 ;;
    --graph) graph="$2"; shift 2 ;;
    *) echo "usage: $0 [--repeats N] [--graph FILE]" >&2; exit 2 ;;
  esac
done
source scripts/bench_common.sh
bin="$(mapmerge_bin)"
python="${MAPMERGE_PYTHON:-python3}"
if ! "$python" -c "import mapmerge" 2>/dev/null; then
  echo "$python cannot import mapmerge: pip install ./crates/app/python (or set MAPMERGE_PYTHON)" >&2
  exit 1
fi
[[ -f "$graph" ]] || { echo "$graph not found (set MAPMERGE_DATA or --graph)" >&2; exit 1; }
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
"$python" - "$bin" "$graph" "$repeats" "$work" <<'EOF'
import json, statistics, subprocess, sys, time
import mapmerge

binary, graph, repeats, work = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
settings = [("none", "auto"), ("gnc", "global")]
print(f"{graph}: {mapmerge.read_graph(graph)!r}; {repeats} runs each, alternating, medians")
print()
print("| settings | CLI s | Python s | ratio | job s CLI / Python | Python proc s | final chi2 CLI / Python |")
print("|---|---|---|---|---|---|---|")
for robust, init in settings:
    cli, call, proc, cli_job, py_job = [], [], [], [], []
    for _ in range(repeats):
        started = time.perf_counter()
        out = subprocess.run(
            [binary, "optimize", graph, "-o", f"{work}/cli.g2o", "--json", "--robust", robust, "--init", init],
            check=True, capture_output=True, text=True,
        ).stdout
        cli.append(time.perf_counter() - started)
        cli_report = json.loads(out)
        cli_job.append(cli_report["seconds"])

        started = time.perf_counter()
        _, report = mapmerge.optimize(graph, robust=robust, init=init, output=f"{work}/python.g2o")
        call.append(time.perf_counter() - started)
        py_job.append(report["seconds"])

        started = time.perf_counter()
        subprocess.run(
            [sys.executable, "-c",
             f"import mapmerge; mapmerge.optimize({graph!r}, robust={robust!r}, init={init!r}, output={work + '/proc.g2o'!r})"],
            check=True,
        )
        proc.append(time.perf_counter() - started)
    same = open(f"{work}/cli.g2o").read() == open(f"{work}/python.g2o").read()
    m = statistics.median
    print(
        f"| --robust {robust} --init {init} | {m(cli):.3f} | {m(call):.3f} | {m(call) / m(cli):.2f} | "
        f"{m(cli_job):.3f} / {m(py_job):.3f} | {m(proc):.3f} | "
        f"{cli_report['final_chi2']:.6f} / {report['final_chi2']:.6f}{'' if same else ' (outputs differ!)'} |"
    )
EOF
