#!/usr/bin/python3
"""The uncertainty map's cost: `biomech update --uncertainty 16` against one update (issue 63 item 4).

Runs `biomech update` on the 5 mm hexahedral Colin27 bundle that
scripts/benchmark-update.py prepared (the README demo's tracked points),
plainly and with `--uncertainty 16` (the defaults: 0.5 mm measurement noise,
one log-normal factor on the moduli with sd 0.3, the parenchyma's Poisson's
ratio in 0.45-0.499), alternating, `--rounds` times each. Each time is the
process's wall time. Target: the ensemble's update within 4 times the plain
update. Writes the uncertainty-cost section of docs/benchmarks.md.

    /usr/bin/python3 scripts/benchmark-uncertainty.py [--rounds 3] [--build build]
"""
import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from docsection import write_section  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MEMBERS = 16
TARGET_RATIO = 4.0


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--build", default=os.path.join(ROOT, "build"))
    parser.add_argument("--updates", default=os.path.join(ROOT, "out", "benchmark-update"),
                        help="scripts/benchmark-update.py's output folder (its bundles and tracked points)")
    parser.add_argument("--benchmarks", default=os.path.join(ROOT, "docs", "benchmarks.md"))
    arguments = parser.parse_args()
    biomech = os.path.join(arguments.build, "apps", "biomech")
    plan = os.path.join(arguments.updates, "plan-hexahedra")
    tracked = os.path.join(arguments.updates, "truth", "tracked-points.csv")
    if not os.path.isfile(os.path.join(plan, "manifest.json")) or not os.path.isfile(tracked):
        sys.exit("benchmark-uncertainty: %s or %s is missing; run scripts/benchmark-update.py first" % (plan, tracked))
    environment = dict(os.environ, GOMP_SPINCOUNT=os.environ.get("GOMP_SPINCOUNT", "1000"))
    load_before = os.getloadavg()[0]
    runs = {"plain": [], "ensemble": []}
    for index in range(arguments.rounds):
        for kind, extra in (("plain", []), ("ensemble", ["--uncertainty", str(MEMBERS)])):
            folder = os.path.join(arguments.updates, "uncertainty-%s-%d" % (kind, index))
            start = time.time()
            subprocess.run([biomech, "update", plan, "--sparse-displacements", tracked, "--overlays", "0", "-q",
                            "-o", folder] + extra, check=True, env=environment)
            wall = time.time() - start
            with open(os.path.join(folder, "registration-report.json")) as handle:
                runs[kind].append({"wall": wall, "report": json.load(handle)})
    load_after = os.getloadavg()[0]

    plain = statistics.median(r["wall"] for r in runs["plain"])
    ensemble = statistics.median(r["wall"] for r in runs["ensemble"])
    ratio = ensemble / plain
    first = runs["ensemble"][0]["report"]
    uncertainty = first["uncertainty"]
    steps = [m["steps"] for m in uncertainty["member_results"]]
    cold = runs["plain"][0]["report"]["solve"]["steps"]
    verdict = "**met**" if ratio <= TARGET_RATIO else "**missed** by %.2f" % (ratio - TARGET_RATIO)
    lines = [
        "## The uncertainty map's cost (`scripts/benchmark-uncertainty.py`)", "",
        "`biomech update` of the update-latency section's 5 mm hexahedral bundle (%s DOF), plainly and with "
        "`--uncertainty %d` (the defaults: docs/registration.md, Uncertainty), the process's wall time. Machine: "
        "%s, %d cores, load average %.2f before and %.2f after; median of %d rounds, alternating; GOMP_SPINCOUNT=%s, "
        "OMP_WAIT_POLICY=%s; measured %s UTC." % (
            format(first["model"]["dofs"], ","), MEMBERS, platform.machine(), os.cpu_count(), load_before,
            load_after, arguments.rounds, environment["GOMP_SPINCOUNT"], os.environ.get("OMP_WAIT_POLICY", "unset"),
            time.strftime("%Y-%m-%d %H:%M", time.gmtime())), "",
        "| update | wall s (range) | of it the ensemble s | members converged | member steps (min-median-max) | "
        "map in the brain p50 / p95 / max mm | exposed nodes' median mm |",
        "|---|---|---|---|---|---|---|",
        "| plain | %.2f (%.2f-%.2f) | | | %d (the cold solve) | | |" % (
            plain, min(r["wall"] for r in runs["plain"]), max(r["wall"] for r in runs["plain"]), cold),
        "| `--uncertainty %d` | %.2f (%.2f-%.2f) | %.2f | %d of %d | %d-%d-%d | %.3f / %.3f / %.3f | %.3f |" % (
            MEMBERS, ensemble, min(r["wall"] for r in runs["ensemble"]), max(r["wall"] for r in runs["ensemble"]),
            statistics.median(r["report"]["seconds"]["uncertainty"] for r in runs["ensemble"]),
            uncertainty["used_members"], MEMBERS, min(steps), statistics.median(steps), max(steps),
            uncertainty["map_mm"]["brain_p50"], uncertainty["map_mm"]["brain_p95"], uncertainty["map_mm"]["brain_max"],
            uncertainty["nodes_mm"]["exposed_median"]), "",
        "| Target (issue 63) | Target | Measured | |",
        "|---|---|---|---|",
        "| `--uncertainty %d` / one update | <= %.0f | %.2f | %s |" % (MEMBERS, TARGET_RATIO, ratio, verdict),
    ]
    write_section(arguments.benchmarks, "uncertainty-cost", lines)
    print("\n".join(lines))


if __name__ == "__main__":
    sys.exit(main())
