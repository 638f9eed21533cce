#!/usr/bin/python3
"""Validation study: brain-shift registration against a known answer on Colin27.

Runs `biomech demo` (ground truth from a finer model, registration from the
tracked exposed-surface points, B-spline intensity baseline) for a set of
scenes, and a stability matrix (every scene with nu = 0.499 and with a 25 mm
shift), then writes docs/validation.md with a table and an
error-against-run-time plot (docs/validation-error-vs-time.png).

    /usr/bin/python3 examples/validation_study.py            # full study (about 30 min on 2 cores)
    /usr/bin/python3 examples/validation_study.py --reduced  # 1 scene, coarse, checked (a CTest case)
"""
import argparse
import json
import os
import platform
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIOMECH = os.path.join(ROOT, "build", "apps", "biomech")  # --biomech overrides

# Craniotomies on the Colin27 brain surface, in ITK's LPS mm (+y posterior, +x left):
# superior parietal (the README demo's), right frontal, left temporal.
PARIETAL = ["-11", "43", "84"]
FRONTAL = ["-25", "-40", "55"]
TEMPORAL = ["65", "15", "-10"]

SCENES = [
    ("parietal-10mm", PARIETAL, ["--shift", "10"]),
    ("parietal-5mm", PARIETAL, ["--shift", "5"]),
    ("parietal-20mm", PARIETAL, ["--shift", "20"]),
    ("frontal-10mm", FRONTAL, ["--shift", "10"]),
    ("temporal-10mm", TEMPORAL, ["--shift", "10"]),
    ("parietal-10mm-tumour-2x", PARIETAL, ["--shift", "10", "--tumour-centre", "-11", "40", "55", "--tumour-radius",
                                          "12", "--tumour-stiffness", "2"]),
    ("parietal-10mm-tumour-10x", PARIETAL, ["--shift", "10", "--tumour-centre", "-11", "40", "55", "--tumour-radius",
                                           "12", "--tumour-stiffness", "10"]),
    ("parietal-10mm-soft-ventricles", PARIETAL, ["--shift", "10", "--csf-modulus", "1"]),
]
# Meshless is left out: the meshless Colin27 registration converges but takes about 5.6 minutes a scene
# (docs/model-building.md).
VARIANTS = ["hexahedra:5", "hexahedra:7", "mixed:5", "tetrahedra:7"]


def run(name, centre, extra, variants, baseline, output_root, quiet=True):
    folder = os.path.join(output_root, name)
    command = [BIOMECH, "demo", "-o", folder, "--craniotomy-centre", *centre, *extra, "--overlays", "1"]
    for variant in variants:
        command += ["--variant", variant]
    if not baseline:
        command.append("--no-baseline")
    if quiet:
        command.append("--quiet")
    start = time.time()
    result = subprocess.run(command, capture_output=True, text=True,
                            env=dict(os.environ, OMP_WAIT_POLICY=os.environ.get("OMP_WAIT_POLICY", "PASSIVE")))
    seconds = time.time() - start
    report = None
    path = os.path.join(folder, "demo-report.json")
    if result.returncode == 0 and os.path.exists(path):
        with open(path) as handle:
            report = json.load(handle)
    error = result.stderr.strip().splitlines()[-1] if result.returncode != 0 and result.stderr.strip() else ""
    error = error.replace("biomech: error: ", "").split(". Likely cause")[0]
    return {"name": name, "status": result.returncode, "error": error, "seconds": seconds, "report": report}


def plot(runs, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    figure, axis = plt.subplots(figsize=(7, 4.5))
    markers = {}
    for entry in runs:
        if not entry["report"]:
            continue
        for method in entry["report"]["methods"]:
            if method["name"] == "no registration":
                continue
            kind = method["name"]
            index = markers.setdefault(kind, len(markers))
            axis.scatter(method["seconds"], method["displacement_error_mm"]["p95"], marker="os^vD<>p*"[index % 9],
                         color="C%d" % (index % 10),
                         label=kind if kind not in axis.get_legend_handles_labels()[1] else None)
    axis.set_xscale("log")
    axis.set_xlabel("registration time (s, log scale)")
    axis.set_ylabel("95th percentile displacement error (mm)")
    axis.axhline(1.0, color="grey", linestyle=":", linewidth=1)
    axis.set_title("Colin27 scenes: error against run time")
    axis.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=110)


def Short(error):
    """The first sentence of an error message, for a table cell."""
    return error.replace("biomech: error: ", "").split(". Likely cause")[0].replace("|", "/")


READING = """
## Reading the results

* **Registration time** is everything but the evaluation (model, solve, fit,
  warp of the 181 x 217 x 181 volume); the B-spline time is its
  registration. The study ran on the project's 2-core machine while other
  work (builds, tests) ran beside it, so times are upper bounds; quiet-machine
  end-to-end times are in [registration-benchmark.md](registration-benchmark.md).
* **Meshless** is not in the study: the meshless Colin27 registration
  converges with skull contact but takes about 5.6 minutes a scene
  (docs/model-building.md).
* **Target: 95th percentile under 1 mm for a 10 mm shift: missed** by
  0.4-0.9 mm (1.37-1.85 mm with 5 mm hexahedra). The ground truth's gravity
  (0.3 g on the whole brain) moves tissue that the exposed surface does not
  show; with a ground truth without gravity the same registration gives
  0.72 mm, and with gravity also in the registration's model
  (`--registration-gravity 0.3`) 0.97 mm (docs/registration.md).
* **Target: more edges within 1.7 mm than B-spline registration on every
  scene: missed** (83-93 % against 95 %). The synthetic pair is B-spline
  registration's ideal case: the intraoperative image is the preoperative
  image warped, with 2 % noise, so intensities match exactly, and no tissue
  is removed; the published comparison (Miller et al., 33 clinical cases)
  is on intraoperative MRI with other contrast, field of view and artefacts.
  The biomechanical registration is given only the exposed surface.
* **Discretizations agree**: hexahedra 5 and 7 mm, mixed 5 mm and ANP
  tetrahedra 7 mm are within 0.3 mm of each other at the 95th percentile on
  every scene; the registration error is set by what the surface data leave
  out, not by the element.
* **Stability**: with nu = 0.499 every scene converges with the same error
  (within 0.1 mm). Shifts of 20 and 25 mm could not be made: the ground
  truth's own 4 mm hexahedral solve stops with a folded element (the message
  is in the table), so the registration was not run on them; the
  registration itself has not been tested beyond 10 mm shifts.
"""


def markdown(runs, stability, machine, reduced):
    lines = ["# Validation study: brain-shift registration against a known answer", "",
             "Written by `examples/validation_study.py`" + (" (reduced)" if reduced else "") + ". "
             "Each scene: `biomech demo` on Colin27 (`ch2.nii.gz`, `ch2bet.nii.gz`). Ground truth: hexahedra of 4 mm "
             "(a grid not nested in the registration's), the exposed surface sunk by a smooth sag of the given "
             "size towards the brain's centroid, gravity 0.3 g on the rest, skull contact, CSF drained (weightless), "
             "dynamic relaxation to 0.01 mm. The registration is given only the displacements of tracked points of the "
             "exposed surface (one per 5 mm cube within the 30 mm craniotomy); the intraoperative image is Colin27 "
             "warped by the ground truth on a 0.86 x 0.86 x 2.5 mm grid with 2% noise. Displacement error: "
             "|T(x) - T_truth(x)| of the backward maps on every second voxel of the intraoperative brain. Edges: "
             "edge-based Hausdorff (Canny, axial slices) inside the intraoperative brain; fraction of edges within 1.7 mm.",
             "", "Machine: " + machine, "",
             "| scene | method | time s | error mean mm | error p95 mm | error max mm | Hausdorff p95 mm | edges < 1.7 mm |",
             "|---|---|---|---|---|---|---|---|"]
    for entry in runs:
        if not entry["report"]:
            lines.append("| %s | failed: %s | | | | | | |" % (entry["name"], Short(entry["error"])))
            continue
        for method in entry["report"]["methods"]:
            error = method["displacement_error_mm"]
            hausdorff = method["hausdorff_mm"] or {}
            fraction = method.get("fraction_within_1_7_mm")
            lines.append("| %s | %s | %.2f | %.2f | %.2f | %.2f | %s | %s |" % (
                entry["name"], method["name"], method["seconds"], error["mean"], error["p95"], error["max"],
                "%.2f" % hausdorff["p95"] if hausdorff else "-",
                "%.1f%%" % (100 * fraction) if fraction is not None else "-"))
    lines += ["", "![error against run time](validation-error-vs-time.png)", READING,
              "## Stability matrix", "",
              "Every scene again with Poisson's ratio 0.499 (parenchyma and tumour, both models) and with a 25 mm "
              "shift; registration with 5 mm hexahedra. Outcome: converged (with its error), or the clear error message.",
              "", "| scene | variant | outcome | error p95 mm | edges < 1.7 mm |", "|---|---|---|---|---|"]
    for entry in stability:
        if entry["report"]:
            method = entry["report"]["methods"][1]
            converged = method["details"]["solve"]["converged"]
            lines.append("| %s | %s | %s | %.2f | %.1f%% |" % (
                entry["scene"], entry["variant"], "converged" if converged else "NOT CONVERGED",
                method["displacement_error_mm"]["p95"], 100 * (method.get("fraction_within_1_7_mm") or 0)))
        else:
            lines.append("| %s | %s | error: %s | | |" % (entry["scene"], entry["variant"], Short(entry["error"])))
    return "\n".join(lines) + "\n"


def main():
    global BIOMECH
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--reduced", action="store_true", help="one scene, coarse, no baseline (CI)")
    parser.add_argument("--output", default=os.path.join(ROOT, "out", "validation"))
    parser.add_argument("--docs", default=os.path.join(ROOT, "docs"))
    parser.add_argument("--biomech", default=BIOMECH, help="the biomech executable")
    parser.add_argument("--from-json", help="rewrite the docs from an earlier run's validation.json, run nothing")
    arguments = parser.parse_args()
    BIOMECH = arguments.biomech
    if not os.path.exists(BIOMECH):
        sys.exit("validation_study: build/apps/biomech is missing; run bash scripts/run-tests.sh first")

    if arguments.from_json:
        with open(arguments.from_json) as handle:
            earlier = json.load(handle)
        machine = earlier.get("machine", "")
        plot(earlier["runs"], os.path.join(arguments.docs, "validation-error-vs-time.png"))
        with open(os.path.join(arguments.docs, "validation.md"), "w") as handle:
            handle.write(markdown(earlier["runs"], earlier["stability"], machine, False))
        return
    scenes = SCENES[:1] if arguments.reduced else SCENES
    variants = ["hexahedra:7"] if arguments.reduced else VARIANTS
    runs = []
    for name, centre, extra in scenes:
        print("scene", name, flush=True)
        # Reduced: a coarser ground truth (6 mm) and registration (7 mm), no baseline.
        extra = extra + ["--truth-element-size", "6"] if arguments.reduced else extra
        runs.append(run(name, centre, extra, variants, not arguments.reduced, arguments.output))
    stability = []
    if not arguments.reduced:
        for name, centre, extra in scenes:
            for variant, change in (("nu 0.499", ["--poisson-ratio", "0.499"]), ("25 mm shift", None)):
                changed = list(extra)
                if change is None:
                    changed[changed.index("--shift") + 1] = "25"
                else:
                    changed += change
                print("stability", name, variant, flush=True)
                entry = run(name + "-" + variant.replace(" ", "-"), centre, changed, ["hexahedra:5"], False,
                            arguments.output)
                entry.update({"scene": name, "variant": variant})
                stability.append(entry)

    machine = "%s, %d cores, %s" % (platform.processor() or platform.machine(), os.cpu_count(), time.strftime("%Y-%m-%d"))
    os.makedirs(arguments.docs, exist_ok=True)
    os.makedirs(arguments.output, exist_ok=True)
    with open(os.path.join(arguments.output, "validation.json"), "w") as handle:
        json.dump({"runs": runs, "stability": stability, "machine": machine}, handle, indent=1)
    if not arguments.reduced:
        plot(runs, os.path.join(arguments.docs, "validation-error-vs-time.png"))
        with open(os.path.join(arguments.docs, "validation.md"), "w") as handle:
            handle.write(markdown(runs, stability, machine, arguments.reduced))
    failed = [entry["name"] for entry in runs if entry["status"] != 0]
    if failed:
        sys.exit("validation_study: scenes failed: " + ", ".join(failed))
    if arguments.reduced:
        # The reduced study is a check: registration must beat no registration
        # by stated margins (measured on the reduced scene: p95 1.9 against 4.1 mm,
        # edges 84 % against 60 %).
        methods = runs[0]["report"]["methods"]
        none, registered = methods[0], methods[1]
        problems = []
        if not registered["details"]["solve"]["converged"]:
            problems.append("the registration's solve did not converge")
        if registered["displacement_error_mm"]["p95"] > 0.6 * none["displacement_error_mm"]["p95"]:
            problems.append("95th percentile error %.2f mm is not below 0.6 x no registration's %.2f mm" % (
                registered["displacement_error_mm"]["p95"], none["displacement_error_mm"]["p95"]))
        if registered["fraction_within_1_7_mm"] < none["fraction_within_1_7_mm"] + 0.1:
            problems.append("edges within 1.7 mm %.3f do not exceed no registration's %.3f by 0.1" % (
                registered["fraction_within_1_7_mm"], none["fraction_within_1_7_mm"]))
        if problems:
            sys.exit("validation_study --reduced: " + "; ".join(problems))
        print("validation_study --reduced: registered p95 %.2f mm (none %.2f), edges %.1f %% (none %.1f %%)" % (
            registered["displacement_error_mm"]["p95"], none["displacement_error_mm"]["p95"],
            100 * registered["fraction_within_1_7_mm"], 100 * none["fraction_within_1_7_mm"]))


if __name__ == "__main__":
    main()
