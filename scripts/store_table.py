#!/usr/bin/env python3
"""The per-session table of scripts/bench_store.sh: density of nodes, edges, views
(keyframes) and local maps per m² of mapped area, store bytes, time, session ATE, merges;
then flatness from session 20 on (issue 17's targets).

    scripts/store_table.py OUT [--every 10] [--json]
"""
import json
import pathlib
import statistics
import sys


def load(out):
    rows = []
    for path in sorted((pathlib.Path(out) / "sessions").glob("*.json"), key=lambda p: int(p.stem)):
        report = json.load(open(path))
        committed = report["store"]["committed"][0]
        # Densities of the site map (the largest graph: where the sessions join); the store's
        # totals include fragments not joined yet, each in its own frame.
        site = committed.get("site") or committed
        area = site["mapped_area_m2"] or float("nan")
        rows.append({
            "session": int(path.stem),
            "nodes": site["nodes"],
            "edges": site["edges"],
            "keyframes": site["keyframes"],
            "local_maps": site["local_maps"],
            "area_m2": area,
            "graphs": committed.get("graphs", 0),
            "all_nodes": committed["nodes"],
            "nodes_m2": site["nodes"] / area,
            "edges_m2": site["edges"] / area,
            "keyframes_m2": site["keyframes"] / area,
            "local_maps_m2": site["local_maps"] / area,
            "bytes": committed["bytes"],
            "wall_s": report["wall_s"],
            "open_s": report["store"]["open_secs"],
            "commit_s": committed["commit_secs"],
            "maintain_s": committed["maintenance"]["seconds"],
            # The store's own cost: opening (with the place index rebuilt) and committing,
            # without the session's maintenance (part of processing the session).
            "store_s": report["store"]["open_secs"] + committed["commit_secs"] - committed["maintenance"]["seconds"],
            "ate_m": committed["session_ate_m"],
            "map_ate_m": committed["map_ate_m"],
            "correct": report.get("correct_merges") or 0,
            "wrong": report.get("wrong_merges") or 0,
            "correct_undone": report.get("correct_undone") or 0,
            "wrong_undone": report.get("wrong_undone_within_10m") or 0,
            "epochs": report["epochs_with_a_map"],
            "merged_epochs": report.get("epochs_merged_correctly") or 0,
            "rejoins_ok": report.get("correct_rejoins") or 0,
            "rejoins_wrong": report.get("wrong_rejoins") or 0,
        })
    return rows


def mean(rows, key):
    values = [r[key] for r in rows if r[key] is not None]
    return statistics.fmean(values) if values else float("nan")


def flatness(rows, first=20, window=20):
    """Mean of the first and last `window` sessions from `first` on, their ratio, and the
    largest deviation of a 10-session moving mean from the mean over the span."""
    span = [r for r in rows if r["session"] >= first]
    result = {}
    if len(span) < 2 * window:
        return result
    for key in ["nodes_m2", "edges_m2", "keyframes_m2", "local_maps_m2", "area_m2", "all_nodes", "bytes",
                "wall_s", "ate_m", "open_s", "commit_s", "maintain_s", "store_s"]:
        head, tail = mean(span[:window], key), mean(span[-window:], key)
        overall = mean(span, key)
        moving = [mean(span[i:i + 10], key) for i in range(0, len(span) - 9)]
        deviation = max(abs(m - overall) / overall for m in moving) if overall else float("nan")
        result[key] = {"first": head, "last": tail, "change": tail / head - 1 if head else float("nan"),
                       "max_moving_deviation": deviation}
    return result


def main():
    out = sys.argv[1]
    every = int(sys.argv[sys.argv.index("--every") + 1]) if "--every" in sys.argv else 10
    rows = load(out)
    flat = flatness(rows)
    if "--json" in sys.argv:
        json.dump({"rows": rows, "flatness": flat}, sys.stdout, indent=1)
        return
    print(f"# {out}: {len(rows)} sessions\n")
    print("Densities are of the site map (the largest graph); `graphs` counts every graph, `all nodes` every vertex.\n")
    print("| session | nodes/m² | edges/m² | views/m² | local maps/m² | site area m² | graphs | all nodes | store MB | wall s | open s | commit s | session ATE m | merges ok/wrong |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        if r["session"] % every == 0 or r is rows[-1]:
            ate = f"{r['ate_m']:.3f}" if r["ate_m"] is not None else "-"
            print(f"| {r['session']} | {r['nodes_m2']:.3f} | {r['edges_m2']:.3f} | {r['keyframes_m2']:.3f} | "
                  f"{r['local_maps_m2']:.4f} | {r['area_m2']:.0f} | {r['graphs']} | {r['all_nodes']} | {r['bytes'] / 1e6:.2f} | {r['wall_s']:.2f} | "
                  f"{r['open_s']:.3f} | {r['commit_s']:.3f} | {ate} | {r['correct']}/{r['wrong']} |")
    if flat:
        print("\nFrom session 20 on: mean of the first 20 sessions, of the last 20, their change, and the largest deviation of a 10-session moving mean from the span's mean.\n")
        print("| quantity | first 20 | last 20 | change | max moving deviation |")
        print("|---|---|---|---|---|")
        for key, f in flat.items():
            print(f"| {key} | {f['first']:.4g} | {f['last']:.4g} | {100 * f['change']:+.1f} % | {100 * f['max_moving_deviation']:.1f} % |")
    totals = {k: sum(r[k] for r in rows) for k in ["correct", "wrong", "correct_undone", "wrong_undone", "epochs", "merged_epochs", "rejoins_ok", "rejoins_wrong"]}
    store = [r["store_s"] for r in rows]
    print(f"\nStore overhead (open + commit, maintenance excluded): mean {statistics.fmean(store):.3f} s, "
          f"max {max(store):.3f} s; at the last session {rows[-1]['store_s']:.3f} s "
          f"(with maintenance {rows[-1]['open_s'] + rows[-1]['commit_s']:.3f} s).")
    print(f"\nMerges over all sessions: {totals['correct']} correct ({totals['correct_undone']} undone), "
          f"{totals['wrong']} wrong ({totals['wrong_undone']} undone within 10 m); "
          f"{totals['merged_epochs']} of {totals['epochs']} epochs with a map end merged correctly; "
          f"fragments rejoined {totals['rejoins_ok']} correctly, {totals['rejoins_wrong']} wrongly.")


if __name__ == "__main__":
    main()
