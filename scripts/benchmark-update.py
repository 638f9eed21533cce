#!/usr/bin/python3
"""Latency of the intraoperative phase: `biomech update` on a prepared model bundle.

Makes the README demo's 10 mm ground truth once (`biomech demo --truth-only`),
prepares Colin27 as a model bundle for 5 mm hexahedra, 7 mm ANP tetrahedra
and the 5 mm meshless cloud (`biomech prepare`, its time reported), then
runs `biomech update` from the truth's tracked points several times per
bundle, and once more on the hexahedra with the gravity fit (5 sizes, the
intraoperative image). The warm start (issue 60 item 2): the truth's
tracked displacements times 1.5 (a 15 mm measurement of the same pattern;
the demo's own 15 mm truth folds a cell of its hexahedral truth model),
updated on the hexahedral and tetrahedral bundles cold and warm-started
from the 10 mm update (`--previous`); its steps against the cold solve's, and the two results'
difference. Each update's time is the process's wall time, from
its start (reading the bundle) to its last file written; the stages come
from its report. The error of each update against the ground truth (inside
the intraoperative brain, on the preoperative grid) is measured with the
module's own metric (Python binding, build/python). Writes the
update-latency section of docs/benchmarks.md (scripts/docsection.py).

    /usr/bin/python3 scripts/benchmark-update.py [--rounds 3] [--build build]
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
TEMPLATES = "/usr/share/mricron/templates"
GRIDS = [("hexahedra", 5.0, 1.5), ("tetrahedra", 7.0, 4.0), ("meshless", 5.0, 5.0)]  # kind, mm, target s
GRAVITY_TARGET = 8.0
WARM_TARGET = 0.6  # warm-started steps / cold steps


def run(command, environment):
    start = time.time()
    subprocess.run([str(part) for part in command], check=True, env=environment)
    return time.time() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--build", default=os.path.join(ROOT, "build"))
    parser.add_argument("--output", default=os.path.join(ROOT, "out", "benchmark-update"))
    parser.add_argument("--benchmarks", default=os.path.join(ROOT, "docs", "benchmarks.md"))
    arguments = parser.parse_args()
    biomech = os.path.join(arguments.build, "apps", "biomech")
    sys.path.insert(0, os.path.join(arguments.build, "python"))
    import biomechanical_registration as bmr  # noqa: E402

    # A bounded spin on a quiet machine (docs/wait-policy.md), unless the caller chose.
    environment = dict(os.environ, GOMP_SPINCOUNT=os.environ.get("GOMP_SPINCOUNT", "1000"))
    out = arguments.output
    truth = os.path.join(out, "truth")
    run([biomech, "demo", "-o", truth, "--truth-only", "--quiet"], environment)
    with open(os.path.join(truth, "demo-report.json")) as handle:
        demo = json.load(handle)
    # 1 g along the head's down, the largest size tried (as the README demo's --registration-gravity 1).
    gravity = [9810.0 * component for component in demo["ground_truth"]["down"]]
    tracked = os.path.join(truth, "tracked-points.csv")
    deeper_tracked = os.path.join(out, "tracked-points-x1.5.csv")
    with open(tracked) as source, open(deeper_tracked, "w") as target:
        target.write(source.readline())
        for line in source:
            values = [float(value) for value in line.split(",")]
            target.write(",".join(repr(value) for value in values[:3] + [1.5 * value for value in values[3:]]) + "\n")
    truth_transform = bmr.read_transform(os.path.join(truth, "ground-truth-transform.h5"))
    region = bmr.imread(os.path.join(truth, "intraoperative-brain-on-preoperative-grid.nii.gz"))
    patient = [os.path.join(TEMPLATES, "ch2.nii.gz"), "--mask", os.path.join(TEMPLATES, "ch2bet.nii.gz"),
               "--craniotomy-centre", "-11", "43", "84", "--craniotomy-radius", "30"]

    def error_of(folder):
        error = bmr.measure_displacement_error(bmr.read_transform(os.path.join(folder, "transform.h5")),
                                               truth_transform, region)
        return error

    load_before = os.getloadavg()[0]
    rows = []
    for kind, size, target in GRIDS:
        plan = os.path.join(out, "plan-%s" % kind)
        prepare_wall = run([biomech, "prepare"] + patient + ["--grid", kind, "--element-size", size, "-q", "-o", plan],
                           environment)
        with open(os.path.join(plan, "manifest.json")) as handle:
            manifest = json.load(handle)
        rounds = []
        for index in range(arguments.rounds):
            folder = os.path.join(out, "update-%s-%d" % (kind, index))
            wall = run([biomech, "update", plan, "--sparse-displacements", tracked, "--overlays", "0", "-q",
                        "-o", folder], environment)
            with open(os.path.join(folder, "registration-report.json")) as handle:
                report = json.load(handle)
            rounds.append({"wall": wall, "report": report})
        rows.append({"name": "%s %g mm" % (kind, size), "target": target, "prepare": prepare_wall,
                     "prepare_stages": manifest["prepare"]["seconds"], "manifest": manifest, "rounds": rounds,
                     "error": error_of(os.path.join(out, "update-%s-0" % kind))})
        # The second update of the surgery: the 15 mm shift, cold and from the 10 mm update.
        # Not the meshless cloud: its cold update of this measurement ran 16 min without
        # finishing on 2026-12-02 (not investigated yet: see the issue 60 note).
        if kind == "meshless":
            continue
        second = {}
        for start in ("cold", "warm"):
            second[start] = []
            for index in range(arguments.rounds):
                folder = os.path.join(out, "second-%s-%s-%d" % (kind, start, index))
                previous = ["--previous", os.path.join(out, "update-%s-0" % kind)] if start == "warm" else []
                wall = run([biomech, "update", plan, "--sparse-displacements", deeper_tracked] + previous +
                           ["--overlays", "0", "-q", "-o", folder], environment)
                with open(os.path.join(folder, "registration-report.json")) as handle:
                    second[start].append({"wall": wall, "report": json.load(handle)})
        cold_transform = bmr.read_transform(os.path.join(out, "second-%s-cold-0" % kind, "transform.h5"))
        warm_transform = bmr.read_transform(os.path.join(out, "second-%s-warm-0" % kind, "transform.h5"))
        rows[-1]["second"] = second
        rows[-1]["warm_versus_cold"] = bmr.measure_displacement_error(warm_transform, cold_transform, region)

    # The gravity fit: drained CSF (weightless), 5 sizes from 0 to 1 g along the truth's gravity.
    plan = os.path.join(out, "plan-gravity")
    prepare_wall = run([biomech, "prepare"] + patient + ["--csf-density", "1", "-q", "-o", plan], environment)
    with open(os.path.join(plan, "manifest.json")) as handle:
        manifest = json.load(handle)
    rounds = []
    for index in range(arguments.rounds):
        folder = os.path.join(out, "update-gravity-%d" % index)
        wall = run([biomech, "update", plan, "--sparse-displacements", tracked, "--gravity"] + list(gravity) +
                   ["--gravity-fit-candidates", "5", "--intraoperative-image", os.path.join(truth, "intraoperative.nii.gz"),
                    "--intraoperative-mask", os.path.join(truth, "intraoperative-brain-mask.nii.gz"), "--overlays", "0",
                    "-q", "-o", folder], environment)
        with open(os.path.join(folder, "registration-report.json")) as handle:
            rounds.append({"wall": wall, "report": json.load(handle)})
    rows.append({"name": "hexahedra 5 mm, gravity fit (5 sizes)", "target": GRAVITY_TARGET, "prepare": prepare_wall,
                 "prepare_stages": manifest["prepare"]["seconds"], "manifest": manifest, "rounds": rounds,
                 "error": error_of(os.path.join(out, "update-gravity-0"))})
    load_after = os.getloadavg()[0]

    machine = ("Machine: %s, %d cores, load average %.2f before and %.2f after; median of %d updates per bundle; "
               "GOMP_SPINCOUNT=%s, OMP_WAIT_POLICY=%s; measured %s." % (
                   platform.processor() or platform.machine(), os.cpu_count(), load_before, load_after,
                   arguments.rounds, environment["GOMP_SPINCOUNT"], environment.get("OMP_WAIT_POLICY", "unset"),
                   time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())))
    write_section(arguments.benchmarks, "update-latency", section(rows, machine))
    print("wrote the update-latency section of", arguments.benchmarks)


def section(rows, machine):
    lines = [
        "## Update latency: the intraoperative phase on a prepared bundle (`scripts/benchmark-update.py`)", "",
        "`biomech update` of Colin27's README-demo scene (10 mm shift, 30 mm superior craniotomy) from the ground "
        "truth's tracked points, on a bundle that `biomech prepare` made; the time is the process's, from reading "
        "the bundle to the last file written (warped image, transform, model result, report). Targets: issue 60. "
        "The error is of the same update against the ground truth inside the brain. " + machine, "",
        "| model | prepare (s) | of it precompute (s) | precomputation.bin (MB) | update (s) | target | read bundle | "
        "loads | solve (steps) | fit | warp | write | error p95 / max (mm) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        walls = [entry["wall"] for entry in row["rounds"]]
        update = statistics.median(walls)

        def stage(name):
            return statistics.median(entry["report"]["seconds"].get(name, 0.0) for entry in row["rounds"])

        solve = stage("solve") + stage("gravity fit")
        steps = row["rounds"][0]["report"]["solve"]["steps"]
        verdict = "met" if update <= row["target"] else "**missed** by %.2f s" % (update - row["target"])
        precomputation = [f["bytes"] for f in row["manifest"]["files"] if f["name"] == "precomputation.bin"]
        lines.append("| %s (%s DOF) | %.1f | %.2f | %.1f | **%.2f** (%.2f-%.2f) | <= %g s: %s | %.2f | %.2f | %.2f (%s%d) "
                     "| %.2f | %.2f | %.2f | %.2f / %.2f |" % (
                         row["name"], format(row["manifest"]["model"]["dofs"], ","), row["prepare"],
                         row["prepare_stages"].get("precompute", 0.0), precomputation[0] / 1e6 if precomputation else 0.0,
                         update, min(walls),
                         max(walls), row["target"], verdict, stage("read-bundle"), stage("loads"), solve,
                         "gravity fit and solve, " if stage("gravity fit") > 0 else "", steps, stage("fit"),
                         stage("warp"), stage("write"), row["error"]["p95_mm"], row["error"]["max_mm"]))
    lines += [
        "",
        "The second update of a surgery (issue 60 item 2): the tracked points' displacements times 1.5 (a 15 mm "
        "measurement of the same pattern; `biomech demo --shift 15` folds a cell of its own hexahedral truth, so "
        "there is no 15 mm truth to measure an error against), updated cold and warm-started from the 10 mm "
        "update above (`--previous`). Target: the warm start in at most %d %% of the cold steps. `warm - cold`: "
        "the two transforms' difference inside the brain (the solver tolerance is 0.01 mm; the skull contact "
        "admits neighbouring equilibria, docs/registration.md)." % round(100 * WARM_TARGET), "",
        "| model | cold steps | warm steps | warm / cold | target | cold update (s) | warm update (s) | "
        "warm - cold p95 / max (mm) |",
        "|---|---|---|---|---|---|---|---|"]
    for row in rows:
        if "second" not in row:
            continue
        cold = row["second"]["cold"][0]["report"]["solve"]["steps"]
        warm = row["second"]["warm"][0]["report"]["solve"]["steps"]
        fraction = warm / cold
        verdict = "met" if fraction <= WARM_TARGET else "**missed** by %d points" % round(100 * (fraction - WARM_TARGET))
        lines.append("| %s | %d | %d | %.0f %% | <= %d %%: %s | %.2f | %.2f | %.3f / %.3f |" % (
            row["name"], cold, warm, 100 * fraction, round(100 * WARM_TARGET), verdict,
            statistics.median(entry["wall"] for entry in row["second"]["cold"]),
            statistics.median(entry["wall"] for entry in row["second"]["warm"]),
            row["warm_versus_cold"]["p95_mm"], row["warm_versus_cold"]["max_mm"]))
    lines += [
        "",
        "Where an update's second goes beyond the stages: the process's start (loading ITK, VTK and CGAL) and "
        "the bundle's checksums are in the wall time and in `read bundle` (which reads the precomputation too). "
        "The solve includes building the solver from the bundle's Total Lagrangian precomputation (a copy of its "
        "tables; the masses and the contact search trees, which the bundle does not store: docs/registration.md, "
        "The model bundle); `prepare`'s `precompute` stage is what each update would otherwise spend making it.",
    ]
    return lines


if __name__ == "__main__":
    sys.exit(main())
