#!/usr/bin/python3
"""Plots a `biomech demo` report: displacement error against registration time,
and the edge-based Hausdorff curves, for every method (no registration,
biomechanical, B-spline, elastix).

    /usr/bin/python3 scripts/plot-demo.py out/demo/demo-report.json out/demo/error-vs-time.png
"""
import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    with open(sys.argv[1]) as handle:
        report = json.load(handle)
    figure, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    for method in report["methods"]:
        error = method["displacement_error_mm"]
        # No registration takes no time: drawn at the left edge of the log axis.
        seconds = max(method["seconds"], 0.1)
        left.errorbar([seconds], [error["p95"]], yerr=[[error["p95"] - error["mean"]], [error["max"] - error["p95"]]],
                      fmt="o", capsize=3, label=method["name"])
        curve = method.get("hausdorff_curve_mm")
        if curve:
            right.plot(range(1, len(curve) + 1), curve, label=method["name"])
    truth = report["ground_truth"]
    left.set_xscale("log")
    left.set_xlabel("registration time (s; no registration drawn at 0.1 s)")
    left.set_ylabel("displacement error (mm): 95th percentile,\nbar from mean to max")
    left.set_title("error against run time (%.0f mm shift)" % truth["target_shift_mm"])
    left.axhline(1.0, color="grey", linestyle=":", linewidth=1)
    left.legend(fontsize=7)
    right.set_xlabel("percentile K")
    right.set_ylabel("edge-based Hausdorff distance (mm)")
    right.axhline(1.7, color="grey", linestyle=":", linewidth=1)
    right.set_ylim(0, 10)
    right.set_title("percentile Hausdorff curves")
    right.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(sys.argv[2], dpi=110)
    print("wrote", sys.argv[2])


if __name__ == "__main__":
    main()
