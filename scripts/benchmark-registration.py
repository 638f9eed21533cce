#!/usr/bin/python3
"""End-to-end benchmark of `biomech register` on Colin27, with its error.

Makes the README demo's ground truth once (`biomech demo`, 10 mm shift), then
runs `biomech register` from its displaced exposed surface several times and
writes docs/registration-benchmark.md: the median time of every stage
(model = classify + grid + materials + surfaces + loads; solve; fit; warp),
the process's wall time (reading and writing included), and the displacement
error against the ground truth of the same registration (from the demo);
and issue 20's targets for it, with the reasons for the misses, as the
colin27-registration section of docs/benchmarks.md (scripts/docsection.py).

    /usr/bin/python3 scripts/benchmark-registration.py [--rounds 3]
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
BIOMECH = os.path.join(ROOT, "build", "apps", "biomech")
TEMPLATES = "/usr/share/mricron/templates"
MODEL_STAGES = ["classify", "grid", "materials", "surfaces", "loads"]


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--output", default=os.path.join(ROOT, "out", "benchmark-registration"))
    parser.add_argument("--benchmarks", default=os.path.join(ROOT, "docs", "benchmarks.md"),
                        help="the page whose colin27-registration section is rewritten")
    arguments = parser.parse_args()
    # A bounded spin on a quiet machine (docs/wait-policy.md), unless the caller chose.
    environment = dict(os.environ, GOMP_SPINCOUNT=os.environ.get("GOMP_SPINCOUNT", "1000"))
    demo = os.path.join(arguments.output, "demo")
    subprocess.run([BIOMECH, "demo", "-o", demo, "--load", "surface", "--no-baseline", "--quiet"], check=True,
                   env=environment)
    with open(os.path.join(demo, "demo-report.json")) as handle:
        demo_report = json.load(handle)
    registered = demo_report["methods"][1]

    load_before = os.getloadavg()[0]
    rounds = []
    for round_index in range(arguments.rounds):
        folder = os.path.join(arguments.output, "run-%d" % round_index)
        start = time.time()
        subprocess.run([BIOMECH, "register", os.path.join(TEMPLATES, "ch2.nii.gz"), "--mask",
                        os.path.join(TEMPLATES, "ch2bet.nii.gz"), "--craniotomy-centre", "-11", "43", "84",
                        "--craniotomy-radius", "30", "--intraoperative-surface", os.path.join(demo, "exposed-surface.vtp"),
                        "-o", folder, "--quiet", "--overlays", "0"], check=True, env=environment)
        wall = time.time() - start
        with open(os.path.join(folder, "registration-report.json")) as handle:
            report = json.load(handle)
        seconds = report["seconds"]
        rounds.append({"wall": wall, "model": sum(seconds.get(stage, 0.0) for stage in MODEL_STAGES),
                       "solve": seconds["solve"], "fit": seconds["fit"], "warp": seconds["warp"],
                       "total": seconds["total"], "steps": report["solve"]["steps"],
                       "dofs": report["model"]["dofs"], "estimated": report["solve"]["estimated_error_mm"],
                       "residual": report["fit"]["max_residual_mm"],
                       "stages": {stage: seconds.get(stage, 0.0) for stage in MODEL_STAGES}})
    load_after = os.getloadavg()[0]

    def median(key):
        return statistics.median(entry[key] for entry in rounds)

    def verdict(value, target, unit="s"):
        return "met" if value <= target else "**missed** by %s %s" % (("%.2f" if unit == "s" else "%d") % (value - target), unit)

    error = registered["displacement_error_mm"]
    machine = ("Machine: %s, %d cores, load average %.2f before and %.2f after; median of %d rounds; GOMP_SPINCOUNT=%s, "
               "OMP_WAIT_POLICY=%s." % (platform.processor() or platform.machine(), os.cpu_count(), load_before,
                                        load_after, len(rounds), environment["GOMP_SPINCOUNT"],
                                        environment.get("OMP_WAIT_POLICY", "unset")))
    lines = [
        "# Registration benchmark: end to end on Colin27", "",
        "Written by `scripts/benchmark-registration.py` (run by `scripts/run-benchmarks.sh`). `biomech register` "
        "on Colin27 (`ch2.nii.gz`, 181 x 217 x 181 voxels of 1 mm, mask `ch2bet.nii.gz`) with the default settings "
        "(5 mm hexahedra, three tissue classes, skull contact, dynamic relaxation to 0.01 mm, transform fit to "
        "0.1 mm, linear warp of the whole volume), loaded by the displaced exposed surface of the README demo's "
        "ground truth (30 mm superior craniotomy, 10 mm shift, gravity 0.3 g).", "",
        machine, "",
        "Targets: issue 6, model + solve + transform + warp under 10 s and the solve under 2 s; issue 20, the model in 1.5 s, the solve in 1 s and 800 steps, end to end in 4 s.", "",
        "| stage | seconds |", "|---|---|"]
    for stage in MODEL_STAGES:
        lines.append("| model: %s | %.2f |" % (stage, statistics.median(entry["stages"][stage] for entry in rounds)))
    lines += [
        "| **model** | **%.2f** |" % median("model"),
        "| **solve** (%d DOF, %d steps, estimated error %.4f mm) | **%.2f** |" % (rounds[0]["dofs"], rounds[0]["steps"],
                                                                              rounds[0]["estimated"], median("solve")),
        "| fit (largest residual %.3f mm) | %.2f |" % (rounds[0]["residual"], median("fit")),
        "| warp | %.2f |" % median("warp"),
        "| **end to end: model + solve + fit + warp** | **%.2f** |" % median("total"),
        "| process wall time (reading the images and writing the outputs included) | %.2f |" % median("wall"), "",
        "Issue 6: end to end %s (%.2f s against 10 s); solve %s (%.2f s against 2 s)." % (
            verdict(median("total"), 10.0), median("total"), verdict(median("solve"), 2.0), median("solve")),
        "",
        "Issue 20: model %s (%.2f s against 1.5 s); solve time %s (%.2f s against 1 s); solve steps %s (%d against "
        "800; %.1f ms a step of %d DOF on %d threads); end to end %s (%.2f s against 4 s)." % (
            verdict(median("model"), 1.5), median("model"), verdict(median("solve"), 1.0), median("solve"),
            verdict(rounds[0]["steps"], 800, "steps"), rounds[0]["steps"], 1000.0 * median("solve") / rounds[0]["steps"],
            rounds[0]["dofs"], os.cpu_count(), verdict(median("total"), 4.0), median("total")),
        "",
        "Error of the same registration against the ground truth (from `biomech demo`, inside the brain): "
        "displacement mean %.2f mm, 95th percentile %.2f mm, max %.2f mm; edges within 1.7 mm %.1f%% "
        "(no registration: 95th percentile %.2f mm, %.1f%%)."
        % (error["mean"], error["p95"], error["max"], 100 * (registered.get("fraction_within_1_7_mm") or 0),
           demo_report["methods"][0]["displacement_error_mm"]["p95"],
           100 * (demo_report["methods"][0].get("fraction_within_1_7_mm") or 0)), ""]
    path = os.path.join(ROOT, "docs", "registration-benchmark.md")
    with open(path, "w") as handle:
        handle.write("\n".join(lines))
    print("wrote", path)
    write_section(arguments.benchmarks, "colin27-registration", targets_section(rounds, median, verdict, machine))
    print("wrote its section of", arguments.benchmarks)


def targets_section(rounds, median, verdict, machine):
    """Issue 20's targets for the registration of Colin27, for docs/benchmarks.md."""
    steps = rounds[0]["steps"]
    surfaces = statistics.median(entry["stages"]["surfaces"] for entry in rounds)
    return [
        "## Issue 20's targets on Colin27: the registration (`scripts/benchmark-registration.py`)", "",
        "`biomech register` of the README demo's 10 mm shift with the defaults (5 mm hexahedra, %s DOF, skull "
        "contact, 2 threads); the stages and the error: docs/registration-benchmark.md. %s" % (
            format(rounds[0]["dofs"], ","), machine),
        "",
        "| Measure | Target | Measured | |", "|---|---|---|---|",
        "| model (classify, grid, materials, surfaces, loads) | <= 1.5 s | %.2f s, of which surfaces %.2f s | %s |" % (
            median("model"), surfaces, verdict(median("model"), 1.5)),
        "| solve (dynamic relaxation to 0.01 mm) | <= 1 s | %.2f s | %s |" % (median("solve"), verdict(median("solve"), 1.0)),
        "| solve steps | <= 800 | %s (%.2f ms a step) | %s |" % (format(steps, ","), 1000.0 * median("solve") / steps,
                                                            verdict(steps, 800, "steps")),
        "| end to end (model + solve + fit + warp) | <= 4 s | %.2f s | %s |" % (median("total"), verdict(median("total"), 4.0)),
        "",
        "Why the step count stays above 800 (measured by hand; docs/model-building.md, Limits): it is set by the "
        "parenchyma's ratio of dilatational to shear stiffness, (lambda + 2 mu) / mu = 51 at nu = 0.49, which a "
        "diagonal mass cannot take out of the critical time step. The same scene took 2,095 steps at nu = 0.49, "
        "1,264 at 0.45 and 844 at 0.30 (2026-11-26); selective mass scaling's first-order approximate inverse "
        "took it from 1,732 to 1,054 steps but as the default broke seven CTests, and a coarse-space correction "
        "(1.5 times fewer steps without contact) pushed the slaves into the skull at every correction "
        "(2026-11-28).",
        "",
        "Why the model takes longer than 1.5 s (measured by hand, 2026-11-30 00:10, an hour in which the "
        "surfaces stage took 2.2 s): the surfaces stage is about 3 core-seconds of work, the brain and skull at "
        "the image's 1 mm: two distance maps 0.23 s (2 threads), three isosurfaces with their smoothing 0.22, "
        "0.24 and 0.21 s and two AABB trees 0.12 and 0.15 s (serial), the exact distances of the skull's band "
        "0.54 and 0.35 s (2 threads). Made beside the classification and the material mapping, which need about "
        "a core-second, the model took as long (medians of 5 alternating runs: 3.04 s with, 3.10 s without), and "
        "narrowing the band of exact distances from (0, level + 2 voxels] to the level +- 1.5 voxels (a third "
        "fewer queries) moved the skull by up to 0.67 mm: neither was kept (docs/model-building.md, Limits).",
    ]


if __name__ == "__main__":
    sys.exit(main())
