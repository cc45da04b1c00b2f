#!/usr/bin/env bash
# Issue 15, part 4: forced merges cut from the simulator's *tuning* seeds (office-aliased 1-10,
# the seeds the engine's decision parameters are tuned on; 101-110 of every world stay held
# out), scored by every detector, so that `mapmerge eval calibrate` can fit the engine's
# learned decision on the simulator's 360° lidar and look-alike rooms as well as on the public
# logs. Per seed: `mapmerge sim --corrected-log` (3 sessions of 120 s, as `atlas --sim`), then
# issue 15's protocol on its corrected log (segments of 30 m ending at kidnaps and at session
# changes, valid merges exact at the merge place, rotation / shift / careless invalid cases),
# under odometry noise `default` (the engine meets noisy odometry in the simulator; `none` as
# well with --noise "none default", twice the time: ~10 min per seed and setting on one core);
# two seeds at a time, each on one core.
# --place-only: only the `place` kind (make-merge-cases --place-kind: careless place
# recognition over the whole first segment, so wrong places in look-alike rooms, the engine's
# own failure), to add to an earlier run's results; written to place-NOISE/.
# --world "W1 W2 …": one or more worlds (default office-aliased); --methods M1,M2,…: the
# detectors scored (default: every one; SM and DM take most of the time).
# --group-by-world: in the pooled results.jsonl every case's log is its world's, not its seed's,
# so that `eval calibrate` leaves out one world at a time (a world's seeds share its rooms).
# Usage: scripts/bench_sim_merge_cases.sh [--seeds "1 2 …"] [--world "W …"] [--noise "default …"] [--methods M,…] [--group-by-world] [--place-only]
# Writes bench-out/sim-merge-cases/NOISE/*.results.jsonl; OUT_DIR=… elsewhere.
set -euo pipefail
cd "$(dirname "$0")/.."
seeds="$(seq 1 10)"; worlds=office-aliased; noises=default; place_only=0; by_world=0
methods=change_detection,gridmap,entropy,histogram,sm,dm,better_hypothesis,realign,combined
while [[ $# -gt 0 ]]; do
  case "$1" in
    --seeds) seeds="$2"; shift 2 ;;
    --world) worlds="$2"; shift 2 ;;
    --methods) methods="$2"; shift 2 ;;
    --noise) noises="$2"; shift 2 ;;
    --place-only) place_only=1; shift ;;
    --group-by-world) by_world=1; shift ;;
    *) echo "usage: $0 [--seeds \"1 2 …\"] [--world \"W …\"] [--noise \"default …\"] [--methods M,…] [--group-by-world] [--place-only]" >&2; exit 2 ;;
  esac
done
out="$(realpath -m "${OUT_DIR:-bench-out}")/sim-merge-cases"
prefix=""; kind_args=()
(( place_only )) && { prefix=place-; kind_args=(--place-kind); }
for noise in $noises; do mkdir -p "$out/$prefix$noise"; done
cargo build --release -q -p mapmerge-cli
cp target/release/mapmerge "$out/mapmerge"
bin="$out/mapmerge"
one_seed() { # core world seed
  local core="$1" world="$2" seed="$3" name="$2-$3"
  local pin=(env RAYON_NUM_THREADS=1)
  command -v taskset >/dev/null && pin+=(taskset -c "$core")
  "$bin" sim --world "$world" --seed "$seed" --duration 120 --corrected-log --no-pictures \
    -o "$out/$name" --json > "$out/$name.sim.json"
  # The log's name is its file stem without "-corrected": one "log" per seed in calibrate.
  mv "$out/$name/corrected.log" "$out/$name-corrected.log"
  for noise in $noises; do
    local dir="$out/$prefix$noise"
    "$bin" eval make-merge-cases --log "$out/$name-corrected.log" --corrected "$out/$name-corrected.log" \
      -o "$dir/$name.cases.jsonl" --seed 0 --max-pairs 15 --valid-at merge-place \
      --segment-length-m 30 --split-at-jumps-m 1 "${kind_args[@]}" --odometry-noise "$noise" \
      --json > "$dir/$name.made.json"
    if (( place_only )); then
      grep '"kind":"place"' "$dir/$name.cases.jsonl" > "$dir/$name.place.jsonl" || true
      mv "$dir/$name.place.jsonl" "$dir/$name.cases.jsonl"
    fi
    [[ -s "$dir/$name.cases.jsonl" ]] || continue
    "${pin[@]}" "$bin" eval invalid-merge --cases "$dir/$name.cases.jsonl" \
      -o "$dir/$name.results.jsonl" --methods "$methods" \
      --report "$dir/$name.table.md" > /dev/null
  done
  echo "$name done" >&2
}
# Two workers, each on its own core (timings stay one-core timings).
worker() { # core world:seed...
  local core="$1"; shift
  for job in "$@"; do one_seed "$core" "${job%%:*}" "${job##*:}"; done
}
even=(); odd=(); k=0
for world in $worlds; do for seed in $seeds; do
  if (( k % 2 == 0 )); then even+=("$world:$seed"); else odd+=("$world:$seed"); fi
  k=$(( k + 1 ))
done; done
worker 0 "${even[@]}" & first=$!
[[ ${#odd[@]} -gt 0 ]] && { worker 1 "${odd[@]}" & second=$!; wait "$second"; }
wait "$first"
for noise in $noises; do
  dir="$out/$prefix$noise"
  : > "$dir/results.jsonl"
  for world in $worlds; do for seed in $seeds; do
    f="$dir/$world-$seed.results.jsonl"
    if [[ ! -f "$f" ]]; then continue; fi
    if (( by_world )); then
      sed "s#/$world-$seed-corrected\.log\"#/$world-corrected.log\"#" "$f" >> "$dir/results.jsonl"
    else
      cat "$f" >> "$dir/results.jsonl"
    fi
  done; done
  echo "$prefix$noise: $(wc -l < "$dir/results.jsonl") results" >&2
done
