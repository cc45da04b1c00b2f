#!/usr/bin/env python3
"""Replays place recognition's acceptance rule over `place_benchmark --dump` files (issue 16,
part 3): every verified candidate's evidence is re-scored as `Evidence::score_with` does
(whole-map agreement at the lower end of its Wilson interval, flip, overlap and constraint
terms), with an optional limit on DM (`Evidence::distance_m`, `EvidenceParams::max_distance_m`),
and the best candidate is accepted from a score threshold and a confidence against the best
rival more than `--gap` keyframes away. The rival rule is simpler than the benchmark's, so
recall reads lower than `place_benchmark`'s; the replay compares rules with each other.

Usage: scripts/replay_place_dump.py DUMP.jsonl... [--z 3] [--confidence 0.1] [--gap 10]
Prints one Markdown row per (score threshold, DM limit) and DM's percentiles over the
candidates scoring >= 0.85, true and false apart. Python 3 standard library only.
"""
import argparse
import json
import math


def wilson_lower_bound(p, n, z):
    if z <= 0:
        return p
    if n == 0:
        return 0.0
    n, z2 = float(n), z * z
    centre = p + z2 / (2 * n)
    spread = z * math.sqrt(max(0.0, p * (1 - p) / n + z2 / (4 * n * n)))
    return min(1.0, max(0.0, (centre - spread) / (1 + z2 / n)))


def score(ev, z, max_distance_m=None):
    """`Evidence::score_with` for whole-map evidence with the default weights."""
    if max_distance_m is not None and ev.get("distance_m", 0.0) > max_distance_m:
        return 0.0
    flip = 2.0 * max(0.0, ev["flip_ratio"] - 0.5)
    agreement = wilson_lower_bound(ev["agreement"], ev["overlap_points"], z)
    support = max(0.0, agreement - flip) * min(1.0, ev["overlap_fraction"] / 0.5)
    return max(0.0, min(1.0, support * min(1.0, ev["constraint_m"] / 3.0)))


def is_true(candidate):
    error = candidate["error"]
    return error is not None and error[0] <= 0.5 and error[1] <= math.radians(10)


def replay(queries, threshold, max_distance_m, args):
    accepted = true = recalled = 0
    for query in queries:
        scored = [(score(c["evidence"], args.z, max_distance_m), c)
                  for c in query["candidates"] if c["evidence"]]
        if not scored:
            continue
        best_score, best = max(scored, key=lambda sc: (sc[0], -sc[1]["ordinal"]))
        if best_score <= 0 or best_score < threshold:
            continue
        rival = max((s for s, c in scored if abs(c["ordinal"] - best["ordinal"]) > args.gap),
                    default=0.0)
        if (best_score - rival) / best_score < args.confidence:
            continue
        accepted += 1
        true += is_true(best)
        recalled += is_true(best) and query["has_revisit"]
    return accepted, true, recalled


def percentiles(values, ps=(0.1, 0.5, 0.9)):
    values = sorted(values)
    return [values[int(p * (len(values) - 1))] if values else float("nan") for p in ps]


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dumps", nargs="+")
    parser.add_argument("--z", type=float, default=3.0)
    parser.add_argument("--confidence", type=float, default=0.1)
    parser.add_argument("--gap", type=int, default=10)
    args = parser.parse_args()
    queries = []
    for path in args.dumps:
        with open(path) as f:
            queries.extend(r for r in map(json.loads, f) if "candidates" in r)
    revisits = sum(1 for q in queries if q["has_revisit"])
    print(f"{len(queries)} queries, {revisits} revisits\n")
    print("| score threshold | DM limit | accepted | true | precision | recall |")
    print("|---|---|---|---|---|---|")
    for threshold in (0.95, 0.93, 0.9, 0.85, 0.8):
        for limit in (None, 0.3, 0.25, 0.2, 0.15):
            a, t, r = replay(queries, threshold, limit, args)
            shown = "none" if limit is None else f"{limit} m"
            print(f"| {threshold} | {shown} | {a} | {t} | {t / max(a, 1):.3f} | "
                  f"{r / max(revisits, 1):.3f} |")
    true_dm, false_dm = [], []
    for q in queries:
        for c in q["candidates"]:
            if c["evidence"] and c["evidence"]["score"] >= 0.85:
                (true_dm if is_true(c) else false_dm).append(c["evidence"].get("distance_m", 0.0))
    print(f"\nDM of candidates scoring >= 0.85 (10th / 50th / 90th percentile, m): "
          f"true ({len(true_dm)}) {percentiles(true_dm)}, false ({len(false_dm)}) "
          f"{percentiles(false_dm)}")


if __name__ == "__main__":
    main()
