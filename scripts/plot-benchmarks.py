#!/usr/bin/python3
"""Error against run time (log-log) for the CalculiX-referenced block indentation.

Reads the CSV written by bmrBenchmark (docs/benchmark-error-vs-time.csv) and
writes docs/benchmark-error-vs-time.png. Uses Debian's python3-matplotlib:

    /usr/bin/python3 scripts/plot-benchmarks.py [CSV] [PNG]
"""
import csv
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

here = os.path.dirname(os.path.abspath(__file__))
root = os.path.dirname(here)
source = sys.argv[1] if len(sys.argv) > 1 else os.path.join(root, "docs", "benchmark-error-vs-time.csv")
target = sys.argv[2] if len(sys.argv) > 2 else os.path.join(root, "docs", "benchmark-error-vs-time.png")

with open(source, newline="") as stream:
    rows = list(csv.DictReader(stream))
if not rows:
    sys.exit(f"plot-benchmarks: {source} has no rows; run bmrBenchmark first")

labels = {"hex": "hexahedra (hourglass control)", "tet": "ANP tetrahedra",
          "mtled": "meshless (MTLED, linear MLS)"}
styles = {"hex": ("tab:blue", "o", "-"), "tet": ("tab:red", "s", "-"), "mtled": ("tab:green", "v", "-")}
reference_h = float("nan")
figure, axes = plt.subplots(1, 2, figsize=(11, 4.5))
# Series in file order: "hex", "tet", and variants such as "hex-k0.4" (another
# hourglass coefficient) drawn as separate, dashed series.
keys = []
for r in rows:
    if r["cells"] not in keys:
        keys.append(r["cells"])
for key in keys:
    # Joined in refinement order (coarse to fine).
    series = sorted((r for r in rows if r["cells"] == key), key=lambda r: -float(r["h_mm"]))
    base = key.split("-")[0]
    colour, marker, line = styles.get(base, ("tab:gray", "^", "-"))
    label = labels.get(key)
    if label is None:
        variant = key[len(base) + 1:]
        label = labels.get(base, base) + (", hourglass k = " + variant[1:] if variant.startswith("k") else ", " + variant)
        marker, line = "D", "--"
    times = [float(r["total_s"]) for r in series]
    for axis, column, title in ((axes[0], "rms_error_pct", "RMS displacement error"),
                                (axes[1], "force_error_pct", "reaction-force error")):
        values = [max(float(r[column]), 1e-6) for r in series]
        axis.loglog(times, values, marker=marker, linestyle=line, color=colour, label=label)
        for t, v, r in zip(times, values, series):
            axis.annotate(f"h={float(r['h_mm']):g}", (t, v), textcoords="offset points", xytext=(5, 4), fontsize=8)
        axis.set_title(title)
    if series and series[0].get("reference_h_mm"):
        reference_h = float(series[0]["reference_h_mm"])

for axis, ylabel in ((axes[0], "RMS |u - u_ref| at nodes, % of 2 mm depth"),
                     (axes[1], "|F - F_ref| / |F_ref|, %")):
    axis.set_xlabel("run time (setup incl. meshless precomputation + dynamic relaxation), s")
    axis.set_ylabel(ylabel)
    axis.grid(True, which="both", alpha=0.3)
    axis.legend(loc="lower left", fontsize=8)
figure.suptitle("Block indentation: TLED against CalculiX C3D10 (h = %g mm, quarter model)" % reference_h)
figure.tight_layout()
figure.savefig(target, dpi=120)
print(f"plot-benchmarks: wrote {target}")
