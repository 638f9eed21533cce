"""The validation study's report: docs/validation.md's table, plots and conclusions computed from the jobs' records
(examples/validation_study.py collects them), and docs/ground-truth-agreement.md."""
import os

# The preoperative image warped by the scene's own ground truth, scored like a method: the edges within 1.7 mm a
# registration that recovers the true motion exactly reaches. A method above it aligns edges that the motion did not
# move (those another contrast, noise or the resection make).
TRUTH_WARP_ROW = "ground truth (its own warp)"


# The intensity peers' rows, as the report names them.
INTENSITY_PEER_ROWS = ("B-spline intensity", "elastix B-spline", "itk-elastix B-spline", "ANTs SyN")
# itk-elastix and the Debian elastix binary, given the same parameter files and seed, must give the same field: the
# 95th percentile of their difference over the brain within this (mm; measured 2026-12-02: 3e-7 mm on the reduced
# scene, single-precision rounding).
ELASTIX_AGREEMENT_MM = 0.01


def near_tumour_table(runs):
    """The displacement error near the tumour (or the resection cavity's walls) of the scenes that have one."""
    rows = []
    for entry in runs:
        near = (entry["report"] or {}).get("near_tumour")
        for method in (entry["report"] or {}).get("methods", []):
            error = method.get("displacement_error_near_tumour_mm")
            surface = method.get("tumour_surface_distance_p95_mm")
            if near and error:
                rows.append("| %s | %s | %s | %.2f | %.2f | %.2f | %s |" % (
                    entry["name"], method["name"], near["structure"], error["mean"], error["p95"], error["max"],
                    "%.2f" % surface if surface is not None else "-"))
    if not rows:
        return []
    distance = next(entry["report"]["near_tumour"]["distance_mm"] for entry in runs
                    if (entry["report"] or {}).get("near_tumour"))
    return ["", "Near the tumour, or the resection cavity's walls: the same displacement error on the intraoperative "
                "brain within %g mm of it (`displacement_error_near_tumour_mm` of `biomech demo`'s report), and the "
                "95th percentile of the symmetric distances between the tumour's (or the planned resection's) surface "
                "moved by the method and by the truth (`tumour_surface_distance_p95_mm`; boundary voxels of the two "
                "warped masks on a 0.5 mm grid)." % distance,
            "", "| scene | method | near | error mean mm | error p95 mm | error max mm | surface distance p95 mm |",
            "|---|---|---|---|---|---|---|", *rows]




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
            if method["name"] in ("no registration", TRUTH_WARP_ROW):
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


def plot_scenes(runs, path):
    """One panel per scene: each method's 95th percentile displacement error (bars), no registration's in the
    title (it would dwarf the bars)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.patches
    import matplotlib.pyplot as plt
    shown = [entry for entry in runs if entry["report"]]
    kinds = []
    for entry in shown:
        for method in entry["report"]["methods"]:
            if method["name"] not in ("no registration", TRUTH_WARP_ROW) and method["name"] not in kinds:
                kinds.append(method["name"])
    columns = 4
    rows = (len(shown) + columns - 1) // columns
    figure, axes = plt.subplots(rows, columns, figsize=(3.2 * columns, 2.4 * rows + 1.2), squeeze=False)
    for axis, entry in zip(axes.flat, shown):
        methods = {method["name"]: method for method in entry["report"]["methods"]}
        for index, kind in enumerate(kinds):
            if kind in methods:
                axis.bar(index, methods[kind]["displacement_error_mm"]["p95"], color="C%d" % (index % 10))
        none = methods.get("no registration")
        axis.set_title("%s\n(no registration %.1f mm)" % (entry["name"], none["displacement_error_mm"]["p95"])
                       if none else entry["name"], fontsize=8)
        axis.axhline(1.0, color="grey", linestyle=":", linewidth=1)
        axis.set_xticks([])
        axis.tick_params(labelsize=7)
        axis.set_ylabel("p95 error (mm)", fontsize=7)
    for axis in list(axes.flat)[len(shown):]:
        axis.axis("off")
    handles = [matplotlib.patches.Patch(color="C%d" % (index % 10), label=kind) for index, kind in enumerate(kinds)]
    figure.legend(handles=handles, loc="lower center", ncol=3, fontsize=7, frameon=False)
    figure.tight_layout(rect=(0, 1.0 / (2.4 * rows + 1.2), 1, 1))
    figure.savefig(path, dpi=90)
    plt.close(figure)


UNCERTAINTY_ROW = "biomechanical hexahedra 5 mm + fitted gravity, uncertainty 16"
# The uncertainty map's 95 % bound is calibrated when this fraction of the voxels' true errors lie within it (issue 63).
CALIBRATION_TARGET = (0.85, 0.99)


def drawn_inputs(distributions):
    """The ensemble's draws in words, from its report's distributions (those it drew)."""
    words = []
    if distributions.get("noise_sigma_mm"):
        words.append("%g mm measurement noise a component" % distributions["noise_sigma_mm"])
    if distributions.get("youngs_modulus_log_sd"):
        words.append("one log-normal factor on every Young's modulus with sd %g" % distributions["youngs_modulus_log_sd"])
    low, high = distributions.get("poisson_ratio", (0, 0))
    if low or high:
        words.append("the parenchyma's Poisson's ratio in %g-%g" % (low, high))
    low, high = distributions.get("gravity_fraction", (1, 1))
    if low != high:
        words.append("gravity's size within %g-%g times the fitted one, or of the smallest size the fit tried when it "
                     "chose none" % (low, high))
    if distributions.get("skull_gap_sd_mm"):
        words.append("the brain-skull gap widened or narrowed by a normal deviate of sd %g mm (the skull's contact "
                     "offset)" % distributions["skull_gap_sd_mm"])
    if distributions.get("exposed_radius_sd_mm"):
        words.append("the craniotomy's radius with sd %g mm" % distributions["exposed_radius_sd_mm"])
    return ", ".join(words)


def calibration_table(runs, other_kind_scenes):
    """The uncertainty map's calibration per scene (the ensemble rows' details), with a summary computed from it."""
    rows, matched, other, outside, inside, draws = [], [], [], [], [], set()
    for entry in runs:
        method = next((m for m in (entry["report"] or {}).get("methods", []) if "uncertainty" in m.get("details", {})), None)
        if method is None:
            continue
        ensemble = method["details"]["uncertainty"]
        calibration = ensemble["calibration"]
        fraction = calibration["transform"]["fraction_within_bound"]
        (other if entry["name"] in other_kind_scenes else matched).append((fraction, entry["name"]))
        fitted = method["details"].get("gravity_fit", {}).get("gravity_g")
        drawn = ensemble["distributions"]["gravity_fraction"]
        draws.add(drawn_inputs(ensemble["distributions"]))
        truth_gravity = entry["report"]["ground_truth"]["gravity_g"]
        if entry["name"] not in other_kind_scenes and fitted:
            (outside if not drawn[0] * fitted <= truth_gravity <= drawn[1] * fitted else inside).append(fraction)
        rows.append("| %s | %s | %.1f (%.1f) | %d of %d | %s | %.3f | %.2f | %.1f %% | %.1f %% |" % (
            entry["name"], "another kind" if entry["name"] in other_kind_scenes else "the model's family",
            method["seconds"], method["stages"].get("uncertainty", float("nan")),
            ensemble["used_members"], ensemble["members"], "%.3f" % fitted if fitted is not None else "-",
            calibration["transform"]["median_bound_mm"], calibration["transform"]["median_error_mm"], 100 * fraction,
            100 * calibration["mean_transform"]["fraction_within_bound"]))
    if not rows:
        return []
    low, high = CALIBRATION_TARGET
    lines = ["", "## Where to trust the update: the uncertainty map's calibration", "",
             "`%s`: the 5 mm hexahedra with fitted gravity again, then an ensemble of 16 solves of the prepared model "
             "with the uncertain inputs drawn (docs/registration.md, Uncertainty: %s); the map is the 95th percentile "
             "of |u_i - u_mean| per voxel. "
             "Calibration: the fraction of the sampled voxels (every second of the intraoperative brain, as the "
             "displacement error) whose true error |T(x) - T_truth(x)| lies within the map there, for the "
             "registration's transform and for the ensemble's mean; target %d-%d %%. The 15-25 mm scenes are left "
             "out (their tetrahedral truths are the study's longest jobs)." % (UNCERTAINTY_ROW, "; in other runs: ".join(
                 sorted(draws)), 100 * low, 100 * high),
             "", "| scene | truth | time s (of it the ensemble) | members used | fitted gravity g | median map mm | "
             "median true error mm | within the map | within the map (mean transform) |",
             "|---|---|---|---|---|---|---|---|---|", *rows, ""]
    for label, values in (("the scenes whose truth is of the registration's model family", matched),
                          ("the truths of another kind", other)):
        if values:
            met = [name for fraction, name in values if low <= fraction <= high]
            lines.append("* **Calibration on %s: %d of %d scenes within %d-%d %%** (%.1f-%.1f %%; lowest on %s)." % (
                label, len(met), len(values), 100 * low, 100 * high, 100 * min(values)[0], 100 * max(values)[0],
                min(values)[1]))
    if outside:
        lines.append("* Gravity drawn around the fit: on %d of %d of the model family's scenes the truth's gravity "
                     "lies outside the drawn sizes (the fit's size times the drawn fractions); there the map covers "
                     "%.1f-%.1f %%%s." % (
                         len(outside), len(outside) + len(inside), 100 * min(outside), 100 * max(outside),
                         ", on the others %.1f-%.1f %%" % (100 * min(inside), 100 * max(inside)) if inside else ""))
    return lines


def Short(error):
    """The first sentence of an error message, for a table cell."""
    return error.replace("biomech: error: ", "").split(". Likely cause")[0].replace("|", "/")


def other_kind_reading(runs, methods, p95, other_kind_scenes):
    """Each method's 95th percentile error on the truths of another kind beside the matched parietal 10 mm scene's."""
    matched = {entry["name"]: methods(entry) for entry in runs}.get("parietal-10mm", {})
    lines = []
    for entry in runs:
        if entry["name"] not in other_kind_scenes:
            continue
        found = methods(entry)
        if not found:
            lines.append("  * %s: %s" % (entry["name"], Short(entry["error"])))
            continue
        described = ["%s %.2f (%s)" % (name.replace("biomechanical ", ""), p95(method),
                                       "%.2f" % p95(matched[name]) if name in matched else "-")
                     for name, method in found.items() if name not in (TRUTH_WARP_ROW, UNCERTAINTY_ROW)]
        lines.append("  * %s: %s." % (entry["name"], "; ".join(described)))
    if not lines:
        return []
    return ["* **Truths of another kind** (physics the registration does not model: partial CSF drainage, a bonded "
            "skull base, grey and white matter of their own moduli, a Mooney-Rivlin law; 95th percentile error in mm, "
            "the matched "
            "parietal-10mm scene's in brackets):", *lines]


def reading(runs, machine, large_scenes, other_kind_scenes=()):
    """The conclusions, computed from the table's numbers (never fixed text beside changing data)."""
    def methods(entry):
        return {method["name"]: method for method in entry["report"]["methods"]} if entry["report"] else {}

    def p95(method):
        return method["displacement_error_mm"]["p95"]

    lines = ["", "## Reading the results", "",
             "* **Time** is the registration's: for the biomechanical rows everything but the evaluation (model, "
             "solve, fit, warp of the 181 x 217 x 181 volume); for the intensity registrations their optimisation "
             "(elastix: the `elastix` process; itk-elastix: `itk.elastix_registration_method` in the Python process; "
             "ANTs SyN: `ants.registration`; the fields and warped images made after them are not counted). "
             "Quiet-machine "
             "end-to-end times are in [registration-benchmark.md](registration-benchmark.md)." + busy(machine)]
    if not any("meshless" in name for entry in runs for name in methods(entry)):
        lines.append("* **Meshless** is not among this run's variants; what it does on Colin27 (its time, and the "
                     "large shifts it does not converge for yet) is in docs/model-building.md, Limits.")
    for row, why in ((PLAIN_ROW, "from the exposed surface's displacements alone: the ground truth's gravity "
                                 "moves tissue that the exposed surface does not show (docs/registration.md)"),
                     (GRAVITY_FIT_ROW, "with gravity along the head's down and its size fitted to the "
                                       "intraoperative image"),
                     (MIXED_GRAVITY_FIT_ROW, "the same on mixed cells")):
        ten = [methods(entry).get(row) for entry in runs
               if "10mm" in entry["name"] and entry["name"] not in other_kind_scenes]
        values = [p95(method) for method in ten if method]
        if not values:
            continue
        verdict = "met" if max(values) < 1.0 else "missed by up to %.2f mm" % (max(values) - 1.0)
        fitted = [fitted_gravity(method) for method in ten if method and fitted_gravity(method) is not None]
        lines.append("* **Target: 95th percentile under 1 mm for a 10 mm shift (%s): %s** (%.2f-%.2f mm over %d "
                     "scenes), %s%s." % (row.replace("biomechanical ", ""), verdict, min(values), max(values),
                                         len(values), why,
                                         (": %.2f-%.2f g fitted (the truths: %s g)" % (
                                             min(fitted), max(fitted), truth_gravities(runs))) if fitted else ""))
    wins, compared, rows = 0, 0, []
    for entry in runs:
        found = methods(entry)
        peers = [found[name] for name in INTENSITY_PEER_ROWS if name in found]
        biomechanical = [method for name, method in found.items() if name.startswith("biomechanical")]
        if not peers or not biomechanical:
            continue
        best = min(biomechanical, key=p95)
        peer = min(peers, key=p95)
        compared += 1
        wins += p95(best) < p95(peer)
        rows.append("%s: %s %.2f mm against %s %.2f mm" % (entry["name"], best["name"], p95(best), peer["name"],
                                                         p95(peer)))
    if compared:
        lines.append("* **Against the intensity registrations** (95th percentile error, the best of each kind): the "
                     "biomechanical registration is better on %d of %d scenes. %s." % (wins, compared, "; ".join(rows)))
        lines.append("  The pairs in the preoperative contrast are the intensity registrations' ideal case (the "
                     "intraoperative image is the preoperative one warped, with noise); the `-t2`, `-resection` and "
                     "`-realistic` scenes add another contrast, a resection cavity, a bias field, Rician noise, "
                     "thicker slices and a partial field of view. The T2-like contrast is a function of the T1 "
                     "intensity, which mutual information is built for; a real T2 is not.")
    lines += other_kind_reading(runs, methods, p95, other_kind_scenes)
    lines += python_peers_reading(runs, methods, p95)
    lines += ventricle_reading(runs, methods)
    lines += image_change_target(runs, methods, p95) + time_budget_target(runs, methods)
    by_name = {entry["name"]: methods(entry) for entry in runs}
    plain, realistic = by_name.get("parietal-10mm-resection"), by_name.get("parietal-10mm-realistic")
    if plain and realistic:
        changes = ["%s %.2f -> %.2f mm" % (name, p95(plain[name]), p95(realistic[name]))
                   for name in realistic if name in plain and name not in ("no registration", TRUTH_WARP_ROW)]
        lines.append("* **What the realistic image costs each method** (`-realistic` against `-resection`: the same "
                     "ground truth, only the intraoperative image differs), 95th percentile: %s." % "; ".join(changes))
    spreads = []
    for entry in runs:
        # Discretizations of the same model: the rows with gravity are another model.
        values = [p95(method) for name, method in methods(entry).items()
                  if name.startswith("biomechanical") and " + " not in name]
        if len(values) > 1:
            spreads.append((max(values) - min(values), entry["name"]))
    if spreads:
        lines.append("* **Discretizations agree** within %.2f mm at the 95th percentile on every scene with several "
                     "(largest on %s)." % max(spreads))
    for entry in runs:
        if entry["name"] not in large_scenes:
            continue
        found = methods(entry)
        if not found:
            lines.append("* **%s**: %s" % (entry["name"], Short(entry["error"])))
            continue
        described = ["%s %.2f mm" % (name, p95(method)) for name, method in found.items() if name != TRUTH_WARP_ROW]
        lines.append("* **%s** (free rim, tetrahedral ground truth): 95th percentile %s." % (
            entry["name"], ", ".join(described)))
    return "\n".join(lines) + "\n"


def python_peers_reading(runs, methods, p95):
    """itk-elastix against the Debian elastix binary (the same parameter files and seed: the same field within
    ELASTIX_AGREEMENT_MM), and ANTs SyN against elastix, over the scenes."""
    lines, differences, times, syn = [], [], {"itk-elastix B-spline": [], "elastix B-spline": []}, []
    for entry in runs:
        found = methods(entry)
        python = found.get("itk-elastix B-spline")
        difference = ((python or {}).get("details") or {}).get("difference_from_debian_elastix_mm")
        if difference:
            differences.append((difference["p95"], difference["max"], entry["name"]))
        for name in times:
            if name in found:
                times[name].append(found[name]["seconds"])
        if "ANTs SyN" in found and "elastix B-spline" in found:
            syn.append((p95(found["ANTs SyN"]), p95(found["elastix B-spline"]), found["ANTs SyN"]["seconds"]))
    if differences:
        worst = max(differences)
        lines.append("* **itk-elastix against Debian's elastix binary** (the same parameter files and random seed): "
                     "their fields differ by %.2g mm at the 95th percentile over the brain at most (%s; largest "
                     "difference %.2g mm) on %d scenes, %s the stated %.2g mm. Run times: itk-elastix %s s, the "
                     "binary %s s." % (
                         worst[0], worst[2], max(value for _, value, _ in differences), len(differences),
                         "within" if worst[0] <= ELASTIX_AGREEMENT_MM else "**not within**", ELASTIX_AGREEMENT_MM,
                         *("%.1f-%.1f" % (min(values), max(values)) if values else "-" for values in times.values())))
    if syn:
        lines.append("* **ANTs SyN** (antspyx's documented defaults, seed 121212): 95th percentile %.2f-%.2f mm in "
                     "%.0f-%.0f s over %d scenes; below elastix's on %d of them." % (
                         min(value for value, _, _ in syn), max(value for value, _, _ in syn),
                         min(seconds for _, _, seconds in syn), max(seconds for _, _, seconds in syn), len(syn),
                         sum(ours < theirs for ours, theirs, _ in syn)))
    return lines


def ventricle_reading(runs, methods):
    """The ventricles' surface distance per method over the scenes, and how many sit at the measure's floor (one
    step of its 0.5 mm grid)."""
    ranges = {}
    for entry in runs:
        for name, method in methods(entry).items():
            value = method.get("ventricle_surface_distance_p95_mm")
            if value is not None:
                ranges.setdefault(name, []).append(value)
    if not ranges:
        return []
    described = ["%s %.2f-%.2f mm" % (name, min(values), max(values)) for name, values in ranges.items()]
    registered = [value for name, values in ranges.items() if name != "no registration" for value in values]
    floor = sum(value <= VENTRICLE_GRID_STEP + 1e-9 for value in registered)
    return ["* **The ventricles' surface** (95th percentile of the symmetric surface distance, over the scenes): %s. "
            "%d of the %d registered method-scene pairs are at one step of the measure's %.1f mm grid or less: "
            "differences below it are not resolved." % ("; ".join(described), floor, len(registered),
                                                       VENTRICLE_GRID_STEP)]


VENTRICLE_GRID_STEP = 0.5  # mm, the grid of bmr::StructureSurfaceDistance as the demo uses it

PLAIN_ROW = "biomechanical hexahedra 5 mm"
GRAVITY_FIT_ROW = "biomechanical hexahedra 5 mm + fitted gravity"
MIXED_GRAVITY_FIT_ROW = "biomechanical mixed 5 mm + fitted gravity"


def fitted_gravity(method):
    """The gravity (g) a registration fitted to the intraoperative image, or None."""
    return ((method.get("details") or {}).get("gravity_fit") or {}).get("gravity_g")


def truth_gravities(runs):
    """The ground truths' gravity (g), as a range when they differ."""
    values = sorted({round(entry["report"]["ground_truth"]["gravity_g"], 3) for entry in runs
                     if entry["report"] and "gravity_g" in entry["report"].get("ground_truth", {})})
    return "%g" % values[0] if len(values) == 1 else "%g-%g" % (values[0], values[-1])


IMAGE_CHANGES = ("-t2", "-resection", "-realistic")
CLINICAL_BUDGET_S = 40.0


def image_change_target(runs, methods, p95):
    """Issue 19's target where the intraoperative image is not the preoperative one: the best biomechanical row's
    95th percentile below each intensity peer's, and at least as many edges within 1.7 mm."""
    def edges(method):
        return method.get("fraction_within_1_7_mm") or 0.0

    verdicts = []
    for entry in runs:
        found = methods(entry)
        biomechanical = [method for name, method in found.items() if name.startswith("biomechanical")]
        peers = [found[name] for name in INTENSITY_PEER_ROWS if name in found]
        if not entry["name"].endswith(IMAGE_CHANGES) or not biomechanical or not peers:
            continue
        best = min(biomechanical, key=p95)
        misses = []
        for peer in peers:
            if p95(best) >= p95(peer):
                misses.append("p95 %.2f mm above %s's %.2f mm by %.2f mm" % (
                    p95(best), peer["name"], p95(peer), p95(best) - p95(peer)))
            if edges(best) < edges(peer):
                misses.append("edges within 1.7 mm %.1f %% below %s's %.1f %%" % (
                    100 * edges(best), peer["name"], 100 * edges(peer)))
        truth = found.get(TRUTH_WARP_ROW)
        above = [peer["name"] for peer in peers if truth and edges(peer) > edges(truth)]
        verdicts.append((entry["name"], best["name"], misses, (truth, above)))
    if not verdicts:
        return []
    met = [name for name, _, misses, _ in verdicts if not misses]

    def described(misses, truth, above):
        text = "; ".join(misses) if misses else "met"
        if truth:
            text += " (the truth's own warp: %.1f %% of edges within 1.7 mm%s)" % (
                100 * edges(truth), ", below %s's" % " and ".join(above) if above else "")
        return text
    # Where a peer registers more edges than the exact motion does, it aligns edges the motion did not move.
    beyond_truth = [name for name, _, _, (_, above) in verdicts if above]
    details = ["%s (%s): %s" % (name, best, described(misses, *truth)) for name, best, misses, truth in verdicts]
    by_name = {entry["name"]: methods(entry) for entry in runs}
    # Pairs with the same ground truth, only the intraoperative image differing.
    pairs = [(changed, plain) for changed, plain in (("parietal-10mm-t2", "parietal-10mm"),
                                                      ("parietal-10mm-realistic", "parietal-10mm-resection"))
             if by_name.get(changed) and by_name.get(plain)]

    def best_p95(scene, prefix):
        values = [p95(method) for name, method in by_name[scene].items() if name.startswith(prefix)]
        return min(values) if values else None

    why = []
    for changed, plain in pairs:
        ours = (best_p95(plain, "biomechanical"), best_p95(changed, "biomechanical"))
        theirs = [(name, p95(by_name[plain][name]), p95(by_name[changed][name]))
                  for name in INTENSITY_PEER_ROWS
                  if name in by_name[plain] and name in by_name[changed]]
        if None not in ours:
            why.append("%s -> %s: biomechanical %.2f -> %.2f mm, %s" % (
                plain, changed, ours[0], ours[1],
                ", ".join("%s %.2f -> %.2f mm" % peer for peer in theirs)))
    return ["* **Target (issue 19): on the scenes with a contrast change or a resection, a lower 95th percentile than "
            "every intensity peer and at least as many edges within 1.7 mm: met on %d of %d scenes.** %s.%s" % (
                len(met), len(verdicts), "; ".join(details),
                (" The same truth with only the image changed (95th percentile, best of each kind): %s. The "
                 "biomechanical registrations read the intraoperative image for one number at most (gravity's "
                 "size), so a change of contrast moves their error only through it." % "; ".join(why))
                if why else "") +
            (" On %s an intensity registration registers more edges within 1.7 mm than the ground truth's own warp "
             "of the preoperative image: there the edge count rewards aligning edges that the motion did not move "
             "(another contrast's, the noise's), which no registration that recovers the motion does." %
             " and ".join(beyond_truth) if beyond_truth else "")]


def time_budget_target(runs, methods):
    """Issue 19's clinical budget: every discretization's registration within CLINICAL_BUDGET_S seconds (the
    uncertainty ensemble, which runs after a registration and is optional, is not one: calibration_table gives its
    time)."""
    slowest = {}
    for entry in runs:
        for name, method in methods(entry).items():
            if name.startswith("biomechanical") and name != UNCERTAINTY_ROW and \
                    method["seconds"] > slowest.get(name, (0.0, ""))[0]:
                slowest[name] = (method["seconds"], entry["name"])
    if not slowest:
        return []
    over = {name: value for name, value in slowest.items() if value[0] > CLINICAL_BUDGET_S}
    described = ["%s %.1f s (%s)" % (name, seconds, scene) for name, (seconds, scene) in sorted(slowest.items())]
    verdict = ("met by every discretization" if not over else
               "missed by %s" % ", ".join("%s (by %.1f s)" % (name, seconds - CLINICAL_BUDGET_S)
                                          for name, (seconds, _) in sorted(over.items())))
    return ["* **Target (issue 19): every discretization's registration within the clinical budget of %.0f s: %s.** "
            "Slowest scene of each: %s.%s" % (
                CLINICAL_BUDGET_S, verdict, "; ".join(described),
                " Times on a busy machine are upper bounds (first item); where the time of the gravity fits goes: "
                "docs/registration.md, \"Gravity fitted to the intraoperative image\"." if over else "")]


def busy(machine):
    """A sentence on the machine's load during the run, from the machine line's load averages."""
    import re
    loads = [float(value) for pair in re.findall(r"load average ([0-9.]+) (?:at the start and|to) ([0-9.]+)", machine)
             for value in pair]
    # The study's own jobs keep both cores busy (load average about 2, one 2-thread job at a time); more than
    # one thread beyond them is other work.
    cores = os.cpu_count() or 2
    if loads and max(loads) > cores + 1.0:
        return (" This run's machine was busy (load average up to %.1f on %d cores, other work beside the study's "
                "jobs): its times are upper bounds." % (max(loads), cores))
    if loads:
        return (" Load average up to %.1f on %d cores: the study's own jobs, which use both cores, and nothing else "
                "beside them." % (max(loads), cores))
    return ""


def markdown(runs, machine, large_scenes, other_kind_scenes=()):
    """docs/validation.md: the study's description, its table, the plots and the conclusions computed from them;
    `large_scenes`: the names of the 15-25 mm scenes (free rim, tetrahedral truth); `other_kind_scenes`: those whose
    truth has physics the registration does not model."""
    volumes = sorted({entry["report"]["ventricles"]["volume_mm3"] for entry in runs
                      if (entry["report"] or {}).get("ventricles")})
    ventricle_volume = (", %s mL on Colin27" % "-".join("%.1f" % (volume / 1000.0) for volume in volumes)
                        if volumes else "")
    lines = ["# Validation study: brain-shift registration against a known answer", "",
             "Written by the Snakemake workflow `examples/validation/Snakefile` (`snakemake -s "
             "examples/validation/Snakefile -j2`; the scenes and this report: `examples/validation_study.py`). Each "
             "scene: one job solves the ground truth (`biomech demo --truth-only`) and one job per method registers "
             "it (`biomech demo --truth-from`), on Colin27 (`ch2.nii.gz`, `ch2bet.nii.gz`). Ground truth: hexahedra of 4 mm (a grid not nested in the registration's; 5 mm ANP "
             "tetrahedra for 15, 20 and 25 mm), the exposed surface sunk by a smooth sag of the given "
             "size towards the brain's centroid (for 15, 20 and 25 mm only within 0.8 of the craniotomy's radius: the "
             "opening's outer fifth is left to the model), gravity 0.3 g on the rest, skull contact, CSF drained "
             "(weightless), "
             "dynamic relaxation to 0.01 mm. The registration is given only the displacements of tracked points of the "
             "exposed surface (one per 5 mm cube within the 30 mm craniotomy); `+ fitted gravity` (5 mm hexahedra and mixed "
             "cells; at 15, 20 and 25 mm also 7 mm tetrahedra): also gravity along "
             "the head's down, its size fitted to the intraoperative image (five sizes from 0 to 1 g and up to "
             "three refinements, the best Mattes mutual information kept; docs/registration.md), its CSF drained "
             "as the truth's. The intraoperative image is Colin27 "
             "warped by the ground truth on a 0.86 x 0.86 x 2.5 mm grid with 2% Gaussian noise; `-t2`: in a T2-like "
             "contrast; `-resection`: the 12 mm tumour and a 5 mm margin removed (a fluid-filled cavity whose walls "
             "sag, left out of the brain where errors are measured; the biomechanical registrations are given the "
             "planned resection, the same sphere, filled with fluid in their models: `--resection-mask`, "
             "docs/registration.md); `-realistic`: resection, T2-like contrast, a 20% "
             "bias field, 4% Rician noise, 1 x 1 x 3 mm voxels and a 160 mm field of view. Truths of another kind, "
             "physics the registration does not model (`biomech demo --truth-...`; examples/validation_study.py says "
             "why these values): `-partial-drainage`: the CSF drained only to 50 mm below the brain's top, the "
             "tissue below it still buoyed (weightless; Miga et al. 1999); `-bonded-base`: the skull-contact nodes "
             "beyond 100 mm below the craniotomy's centre bonded to the skull instead of sliding; `-grey-white`: grey "
             "and white matter of 1.39 and 1.90 kPa on three tissue classes (Budday et al. 2015), where the "
             "registration has one parenchyma of 3 kPa; `-mooney-rivlin`: the parenchyma and tumour Mooney-Rivlin "
             "with half the small-strain shear modulus on the second invariant (C01 / (C10 + C01) = 0.5, the same "
             "small-strain moduli), where the registration is neo-Hookean. Peers: the module's ITK "
             "B-spline registration, elastix (affine then B-spline, Mattes mutual information, the parameter files "
             "in examples/elastix, not tuned on the truth) as Debian's binary and through itk-elastix from Python "
             "(the same files), and ANTs SyN through antspyx (`ants.registration(type_of_transform=\"SyN\")`, its "
             "documented defaults, seed 121212), both Python peers run by `examples/validation_peers.py` in the "
             "project's venv and scored by `biomech demo --peer-field` like every other method. Displacement error: |T(x) - T_truth(x)| of the backward "
             "maps on every second voxel of the intraoperative brain (the whole brain, also outside a partial field of "
             "view). Edges: edge-based Hausdorff (Canny, axial slices) inside the intraoperative brain; fraction of "
             "edges within 1.7 mm. Ventricles: the 95th percentile of the symmetric distances between the lateral ventricles' "
             "surface moved by the method and by the truth (`ventricle_surface_distance_p95_mm`: the CSF class deeper than "
             "10 mm below the brain's surface, opened by 2 mm, the largest component" + ventricle_volume + "; boundary voxels "
             "of the two warped masks on a 0.5 mm grid, so the distances are steps of it: 0.50, 0.71, 0.87, 1.00 mm, "
             "...).",
             "", "Machine: " + machine, "",
             "| scene | method | time s | error mean mm | error p95 mm | error max mm | Hausdorff p95 mm | edges < 1.7 mm "
             "| ventricles p95 mm |",
             "|---|---|---|---|---|---|---|---|---|"]
    for entry in runs:
        if not entry["report"]:
            lines.append("| %s | failed: %s | | | | | | | |" % (entry["name"], Short(entry["error"])))
            continue
        for method in entry["report"]["methods"]:
            error = method["displacement_error_mm"]
            hausdorff = method["hausdorff_mm"] or {}
            fraction = method.get("fraction_within_1_7_mm")
            ventricles = method.get("ventricle_surface_distance_p95_mm")
            lines.append("| %s | %s | %.2f | %.2f | %.2f | %.2f | %s | %s | %s |" % (
                entry["name"], method["name"], method["seconds"], error["mean"], error["p95"], error["max"],
                "%.2f" % hausdorff["p95"] if hausdorff else "-",
                "%.1f%%" % (100 * fraction) if fraction is not None else "-",
                "%.2f" % ventricles if ventricles is not None else "-"))
        for method, error in entry.get("failed_methods", []):
            lines.append("| %s | %s failed: %s | | | | | | | |" % (entry["name"], method, Short(error)))
    lines += near_tumour_table(runs)
    lines += calibration_table(runs, other_kind_scenes)
    lines += ["", "![error against run time](validation-error-vs-time.png)", "",
              "![95th percentile error per scene](validation-per-scene.png)",
              reading(runs, machine, large_scenes, other_kind_scenes),
              "How far two ground truths of the same scene on different discretizations differ, and the registrations "
              "scored against each, is in [ground-truth-agreement.md](ground-truth-agreement.md); how far a truth from "
              "another solver (CalculiX, quadratic tetrahedra) differs from the study's, in "
              "[calculix-ground-truth.md](calculix-ground-truth.md).",
              "",
              "The stiff and extreme cases on every discretization are in [stability-matrix.md](stability-matrix.md)."]
    return "\n".join(lines) + "\n"


def truth_agreement(runs, machine):
    """docs/ground-truth-agreement.md: the two truths of each scene, their difference, and each registration
    against both; the sentences computed from the numbers."""
    lines = ["# Two ground truths of the same scene", "",
             "Written by `examples/validation_study.py --truths`. Each scene is `biomech demo --truth-check KIND:SIZE` "
             "on Colin27: the ground truth of the validation study (docs/validation.md: the exposed surface sunk by a "
             "smooth sag, gravity 0.3 g, skull contact, CSF drained, dynamic relaxation to 0.01 mm) solved a second "
             "time on another discretization, with the same loads. Both are fitted with the same B-spline transform; "
             "the difference is |T_1(x) - T_2(x)| of the two backward maps on every second voxel of the "
             "intraoperative brain. The registrations are scored against each truth.", "",
             "Machine: " + machine, "",
             "| scene | ground truth | second truth | steps | truth fit max residual mm | truths differ: mean / p95 / max mm |",
             "|---|---|---|---|---|---|"]
    scored = []
    for entry in runs:
        report = entry["report"]
        if not report or "ground_truth_check" not in report:
            lines.append("| %s | failed: %s | | | | |" % (entry["name"], Short(entry["error"])))
            continue
        first, second = report["ground_truth"], report["ground_truth_check"]
        difference = second["difference_from_truth_mm"]
        lines.append("| %s | %s %g mm, %d nodes | %s %g mm, %d nodes | %d / %d | %.2f / %.2f | %.2f / %.2f / %.2f |" % (
            entry["name"], first["grid"], first["element_size_mm"], first["nodes"], second["grid"],
            second["element_size_mm"], second["nodes"], first["solve_steps"], second["solve_steps"],
            first["fit_max_residual_mm"], second["fit_max_residual_mm"], difference["mean"], difference["p95"],
            difference["max"]))
        for method in report["methods"]:
            against = method["details"].get("displacement_error_against_second_truth_mm")
            if against:
                scored.append((entry["name"], method["name"], method["displacement_error_mm"], against, difference))
    lines += ["", "| scene | method | error against the ground truth: mean / p95 mm | against the second truth: "
              "mean / p95 mm |", "|---|---|---|---|"]
    for name, method, first, second, _ in scored:
        lines.append("| %s | %s | %.2f / %.2f | %.2f / %.2f |" % (name, method, first["mean"], first["p95"],
                                                                 second["mean"], second["p95"]))
    lines += ["", "## Reading the results", ""]
    registered = [(name, method, first, second, difference) for name, method, first, second, difference in scored
                  if method != "no registration"]
    for name, method, first, second, difference in registered:
        lines.append("* **%s, %s**: the truths differ by %.2f mm at the 95th percentile, %.0f %% of the "
                     "registration's %.2f mm; scored against the second truth its 95th percentile is %.2f mm (%+.2f)."
                     % (name, method, difference["p95"], 100 * difference["p95"] / first["p95"], first["p95"],
                        second["p95"], second["p95"] - first["p95"]))
    for entry in runs:
        report = entry["report"]
        if not report or "ground_truth_check" not in report:
            continue
        first, second = report["ground_truth"], report["ground_truth_check"]
        largest = second["difference_from_truth_mm"]["max"]
        fits = first["fit_max_residual_mm"] + second["fit_max_residual_mm"]
        lines.append("* **%s**: the truths' largest difference, %.2f mm, is %s the sum of their B-spline fits' "
                     "largest residuals (%.2f mm)%s. %s" % (
                         entry["name"], largest, "below" if largest < fits else "above", fits,
                         ", so it may come from the fits as much as from the discretizations" if largest < fits
                         else ": the discretizations differ by more than the fits can explain",
                         "Both truths are %s (of different, not nested meshes)." % first["grid"] if
                         first["grid"] == second["grid"] else "The two truths are different element types."))
    lines += ["* Why the 20 mm scene's second truth is tetrahedral too (measured 2026-11-26, not rerun by this "
              "script): hexahedra of 4 mm fold a cell at 20 mm, mixed cells of 4 mm invert a tetrahedron at the first "
              "step, and a meshless truth of 5 mm had not converged after 6 minutes (issue 17: meshless with skull "
              "contact at large shifts; since 2026-11-29 a meshless truth under gravity converges at 25 mm when its "
              "skull is closed by 1 mm or more, docs/model-building.md, as the study's truths have been since then; a "
              "meshless second truth of this scene was not tried again).",
              "* A third truth, from CalculiX (C3D10 on a conforming tetrahedral mesh, penalty skull contact, "
              "started cold and settled by proximal steps), for both scenes: "
              "[calculix-ground-truth.md](calculix-ground-truth.md), written by "
              "`build/benchmarks/bmrCalculixGroundTruth` (how it got there: docs/registration.md, "
              "\"A truth from CalculiX\")."]
    return "\n".join(lines) + "\n"
