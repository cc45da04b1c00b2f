"""Optimise a g2o pose graph with mapmerge and plot it before and after with matplotlib.

    pip install ./crates/app/python matplotlib
    python examples/python/optimize_g2o.py ../shared/data/g2o/openslam_g2o/manhattanOlson3500.g2o -o manhattan.png

Without a file it optimises the simulated Manhattan graph in testdata/. The file's poses are
drawn grey (its edges thin), the optimised ones blue; the title gives the chi2 (GTSAM's) as read
and optimised. Any g2o or TORO file works, 2D or 3D (3D graphs are drawn from above).
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # draw to a file; no display needed
import matplotlib.pyplot as plt
from matplotlib.collections import LineCollection
import numpy as np

import mapmerge

REPO = Path(__file__).resolve().parents[2]


def draw(axes, graph, colour, label, width):
    """The graph's edges as line segments and its trajectory, seen from above."""
    xy = graph.poses[:, :2]
    rows = np.searchsorted(graph.ids, graph.edges)  # ids are sorted: edge ends -> pose rows
    segments = np.stack([xy[rows[:, 0]], xy[rows[:, 1]]], axis=1)
    axes.add_collection(LineCollection(segments, colors=colour, linewidths=width * 0.3, alpha=0.4))
    axes.plot(xy[:, 0], xy[:, 1], color=colour, linewidth=width, label=label)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("graph", nargs="?", default=REPO / "testdata" / "sim_manhattan_500.g2o")
    parser.add_argument("--robust", default="gnc", help="none, huber, cauchy, dcs, gnc")
    parser.add_argument("--init", default="global", help="auto, none, odometry, global")
    parser.add_argument("-o", "--output", default="optimized.png", help="the picture (PNG)")
    args = parser.parse_args()

    graph = mapmerge.read_graph(args.graph)
    # The file's own chi2: no initialisation, no iteration.
    _, as_read = mapmerge.optimize(graph, init="none", max_iterations=0)
    before = as_read["initial_chi2"]
    optimized, report = mapmerge.optimize(graph, robust=args.robust, init=args.init)
    print(
        f"{graph}: chi2 {before:.1f} as read, {report['final_chi2']:.1f} after {args.init} "
        f"initialisation and {report['iterations']} iterations ({report['termination']}), "
        f"{len(report['rejected_edges'])} edges rejected, {report['seconds']:.2f} s"
    )

    figure, axes = plt.subplots(figsize=(8, 8))
    draw(axes, graph, "0.6", "as read", 0.8)
    draw(axes, optimized, "tab:blue", "optimised", 1.2)
    axes.set_aspect("equal")
    axes.set_xlabel("x (m)")
    axes.set_ylabel("y (m)")
    axes.set_title(
        f"{Path(str(args.graph)).name}: chi2 {before:.4g} -> {report['final_chi2']:.4g}"
    )
    axes.legend(loc="best")
    figure.savefig(args.output, dpi=120, bbox_inches="tight")
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
