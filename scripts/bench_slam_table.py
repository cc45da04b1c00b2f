"""Formats scripts/bench_slam.sh's runs.jsonl as the markdown tables of docs/benchmarks.md."""
import json
import sys

runs = [json.loads(line) for line in open(sys.argv[1])]
profile, seed = sys.argv[2], sys.argv[3]


def fmt(value, digits=3):
    return "—" if value is None else f"{value:.{digits}f}"


def relations(report):
    """Relations error of a trajectory report (nested) or of `eval relations` (flat)."""
    r = None
    if report:
        r = report.get("relations") if "relations" in report else None
        if r is None and "translation_mean_m" in report:
            r = report
    if not r:
        return "—"
    return (f"{r['translation_mean_m']:.3f} ± {r['translation_std_m']:.3f} m, "
            f"{r['rotation_mean_deg']:.2f} ± {r['rotation_std_deg']:.2f}°")


def rpe(report, index):
    try:
        e = report["rpe"][index]
        return f"{e['translation_rmse_m']:.3f} / {e['rotation_rmse_deg']:.2f}"
    except (KeyError, IndexError, TypeError):
        return "—"


print(f"Profile `{profile}`, seed {seed}; errors against the corrected poses; mapmerge on one core.\n")
print("| log | scans | odometry ATE (m) | mapmerge ATE (m) | MRPT ATE (m) | ATE ratio mapmerge/MRPT "
      "| ATE ≤ 5 cm | ≥ 10× below odometry | mapmerge ms/scan | MRPT ms/scan | time ratio mapmerge/MRPT |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
for r in runs:
    m = r["mapmerge"]
    ours, odo = m["score"]["ate"]["rms_m"], m["odometry_score"]["ate"]["rms_m"]
    peer = r["mrpt"]["ate"]["rms_m"] if r["mrpt"] else None
    scans = m["scans"]
    peer_ms = 1e3 * r["mrpt_seconds"] / scans if r["mrpt_seconds"] else None
    print(f"| {r['log']} | {scans} | {fmt(odo)} | {fmt(ours)} | {fmt(peer)} | "
          f"{fmt(ours / peer if peer else None, 2)} | {'yes' if ours <= 0.05 else 'no'} | "
          f"{'yes' if ours * 10 <= odo else 'no'} | {m['ms_per_scan']:.1f} | {fmt(peer_ms, 1)} | "
          f"{fmt(m['ms_per_scan'] / peer_ms if peer_ms else None, 2)} |")
print()
print("Local accuracy: RPE (RMS, m / °) over 1 scan and 5 m of path, and the Kümmerle et al. "
      "2009 relations metric (mean ± std) over relations made from the corrected poses.\n")
print("| log | mapmerge RPE 1 scan | mapmerge RPE 5 m | mapmerge relations | MRPT relations | odometry relations |")
print("|---|---|---|---|---|---|")
for r in runs:
    m = r["mapmerge"]
    print(f"| {r['log']} | {rpe(m['score'], 0)} | {rpe(m['score'], 1)} | {relations(m['score'])} | "
          f"{relations(r['mrpt_relations'])} | {relations(m['odometry_score'])} |")
print()
print("Accepted loop edges, judged against the corrected poses (true: within 0.5 m and 10°).\n")
print("| log | keyframes | submaps | loops local (true) | loops by place recognition (true) | precision | worst error (m / °) | optimisations |")
print("|---|---|---|---|---|---|---|---|")
for r in runs:
    m = r["mapmerge"]
    f, lp = m["front_end"], m["loops"]
    print(f"| {r['log']} | {f['keyframes']} | {f['submaps']} | {lp['accepted_local']} ({lp['true_local']}) | "
          f"{lp['accepted_place']} ({lp['true_place']}) | {fmt(lp['precision'], 4)} | "
          f"{lp['worst_translation_error_m']:.2f} / {lp['worst_rotation_error_deg']:.1f} | {f['optimizations']} |")
