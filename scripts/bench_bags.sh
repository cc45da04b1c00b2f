#!/usr/bin/env bash
# Issue 19, target "Bags": every public log as a bag (ours: `mapmerge convert` to .mcap and .db3;
# and, with MAPMERGE_BAG_PYTHON set to a Python with rosbags + mcap-ros2-support, rewritten by
# those tools: scripts/bag_interop.py) through `mapmerge slam`, against `slam` on the CARMEN log:
# largest and RMS distance between the two trajectories, scan by scan, and the reading time.
# Usage: scripts/bench_bags.sh [LOG_NAME ...]. Writes bench-out/bags.md.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/log_split.sh
source scripts/bench_common.sh
logs=("$@")
[[ ${#logs[@]} -eq 0 ]] && logs=("${ALL_LOGS[@]}")
data="${MAPMERGE_DATA:-../shared/data}"
out="$(realpath -m "${OUT_DIR:-bench-out}")/bags"
mkdir -p "$out"
bin="$(realpath "$(mapmerge_bin)")"
: > "$out/runs.jsonl"
for name in "${logs[@]}"; do
  log="$data/carmen/$name-corrected.log.xz"
  dir="$out/$name"; rm -rf "$dir"; mkdir -p "$dir"
  xz -dc "$log" > "$dir/$name.log"
  bags=("$dir/$name.mcap" "$dir/$name.db3")
  "$bin" convert "$log" -o "$dir/$name.mcap" --json > "$dir/convert.json"
  "$bin" convert "$log" -o "$dir/$name.db3" --json > /dev/null
  if [[ -n "${MAPMERGE_BAG_PYTHON:-}" ]]; then
    "$MAPMERGE_BAG_PYTHON" scripts/bag_interop.py "$dir/$name.mcap" "$dir/interop" > /dev/null
    bags+=("$dir/interop/rosbags-mcap" "$dir/interop/rosbags-db3" "$dir/interop/mcap-ros2.mcap")
  fi
  "$bin" slam "$log" -o "$dir/slam-carmen" --json > "$dir/slam-carmen.json"
  for source in "$dir/$name.log" "${bags[@]}"; do
    label="$(basename "$source")"
    # Reading alone, best of 15 (convert to a CARMEN log in /dev/shm reports the read time).
    read_secs=$(for _ in $(seq 15); do "$bin" convert "$source" -o "/dev/shm/mapmerge-bench-$$.log" --json; done \
      | python3 -c "import json,sys; r=[json.loads(l) for l in sys.stdin]; print(min(x['read_secs'] for x in r), r[0]['input_bytes'])")
    "$bin" slam "$source" -o "$dir/slam-$label" --json > /dev/null
    python3 - "$name" "$label" "$dir/slam-carmen/trajectory.tum" "$dir/slam-$label/trajectory.tum" $read_secs "$dir/convert.json" "$(log_set "$name")" >> "$out/runs.jsonl" <<'PY'
import json, math, sys
name, label, a, b, read_secs, size, convert, split = sys.argv[1:9]
def xy(path):
    return [tuple(map(float, l.split()[1:3])) for l in open(path) if l.strip() and not l.startswith('#')]
pa, pb = xy(a), xy(b)
assert len(pa) == len(pb), (len(pa), len(pb))
d = [math.hypot(p[0] - q[0], p[1] - q[1]) for p, q in zip(pa, pb)]
print(json.dumps(dict(log=name, split=split, source=label, scans=len(pa), max_m=max(d), rms_m=math.sqrt(sum(x * x for x in d) / len(d)),
                      read_secs=float(read_secs), bytes=int(size),
                      stamps_rewritten=json.load(open(convert))["stamps_rewritten"] is not None)))
PY
  done
  rm -f "/dev/shm/mapmerge-bench-$$.log"
done
# Simulated sessions nobody looked at while writing the reader (seeds 101-110 of every world):
# `sim --bag mcap`, then slam on the CARMEN log and on the bag.
: > "$out/sim.jsonl"
for world in office office-aliased corridor-loop warehouse symmetric-hall; do
  for seed in $(seq 101 110); do
    dir="$out/sim-$world-$seed"; rm -rf "$dir"
    "$bin" sim --world "$world" --seed "$seed" --sessions 1 --bag mcap --no-pictures -o "$dir" --json > /dev/null
    for source in log mcap; do
      "$bin" slam "$dir/session_0.$source" -o "$dir/slam-$source" --json > /dev/null
    done
    python3 - "$world" "$seed" "$dir/slam-log/trajectory.tum" "$dir/slam-mcap/trajectory.tum" >> "$out/sim.jsonl" <<'PY'
import json, math, sys
world, seed, a, b = sys.argv[1:5]
xy = lambda path: [tuple(map(float, l.split()[1:3])) for l in open(path) if l.strip()]
d = [math.hypot(p[0] - q[0], p[1] - q[1]) for p, q in zip(xy(a), xy(b))]
print(json.dumps(dict(world=world, seed=int(seed), scans=len(d), max_m=max(d))))
PY
  done
done
python3 - "$out/runs.jsonl" "$out/sim.jsonl" > "$out/../bags.md" <<'PY'
import json, sys
runs = [json.loads(l) for l in open(sys.argv[1])]
print("| log | set | source | scans | stamps | trajectory gap to the CARMEN run: max / RMS (m) | read (ms) | MB/s | read vs plain CARMEN |")
print("|---|---|---|---|---|---|---|---|---|")
plain = {r["log"]: r["read_secs"] for r in runs if r["source"].endswith(".log")}
for r in runs:
    kind = "CARMEN (plain text)" if r["source"].endswith(".log") else r["source"].replace(r["log"] + ".", "ours .")
    print(f"| {r['log']} | {r['split']} | {kind} | {r['scans']} | {'rewritten' if r['stamps_rewritten'] else 'kept'} | {r['max_m']:.4f} / {r['rms_m']:.4f} "
          f"| {1e3 * r['read_secs']:.1f} | {r['bytes'] / 1e6 / r['read_secs']:.0f} | {plain[r['log']] / r['read_secs']:.1f}× |")
bags = [r for r in runs if not r["source"].endswith(".log")]
within = sum(r["max_m"] <= 0.01 for r in bags)
faster = sum(plain[r["log"]] >= r["read_secs"] for r in bags)
print(f"\n{within} of {len(bags)} bag runs within 1 cm of the CARMEN run at every scan; {faster} of {len(bags)} read at least as fast as the plain CARMEN log.")
sims = [json.loads(l) for l in open(sys.argv[2])]
print("\n| simulated world (seeds 101–110) | sessions | scans | largest gap, bag run to log run (m) |")
print("|---|---|---|---|")
for world in dict.fromkeys(r["world"] for r in sims):
    rs = [r for r in sims if r["world"] == world]
    print(f"| {world} | {len(rs)} | {sum(r['scans'] for r in rs)} | {max(r['max_m'] for r in rs):.4f} |")
PY
cat "$out/../bags.md"
