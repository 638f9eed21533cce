#!/usr/bin/env python3
"""Fuzzes the scene parser and the `biomech` command line.

Over 800 lines: the seed inputs and the mutations of both targets, which
share the runner and the checks of each run's outcome.

Takes tiny valid scenes (each solves in well under a second) and tiny valid
argument lists, mutates them (deleted keys, wrong types, huge, zero, negative
or non-finite numbers, NaN / Infinity / 1e999 written into the JSON text,
empty or wrongly sized arrays, duplicated and unknown keys, truncated files,
flipped bytes, missing or broken referenced files, bad option values, unknown
and repeated options) and runs `biomech` on each. Every run must end in one of

* exit 0 (or 2, "not converged", for solve) with its declared outputs complete
  and valid (the report parses, the .vtu is a whole VTK file), or
* exit 1 with a clear one-line message `biomech: error: ...` on stderr and no
  output file (nor a temporary one) left behind;

never a signal, another exit status, an uncaught-exception text (std::bad_alloc,
stoi, basic_string, nlohmann's [json.exception...], terminate called, ...), a
hang or a half-written file. Runs that the mutation made legitimately long
(e.g. a million steps asked for) may time out; they are counted, not failed.

Prints a summary; exits 1 on any failure and leaves each failing input (scene,
data files, command line, output) under WORK/failures/.

    /usr/bin/python3 test/fuzz_inputs.py --biomech build/apps/biomech --mutations 500 --work /tmp/fuzz

Standard library only. One file (about 850 lines: base scenes, mutations, runner,
checks) so that CTest runs it as one case.
"""

import argparse
import json
import math
import os
import random
import re
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parent.parent

# Exit statuses of biomech: 0 success, 1 error (nothing written), 2 solved but
# not converged (results written, report says so).
EXIT_STATUSES = {0, 1, 2}

# Text that only an unhandled or unwrapped exception prints.
BAD_MESSAGE_PATTERNS = [
    r"std::", r"bad_alloc", r"\bstoi\b", r"\bstod\b", r"\bstol\b", r"basic_string", r"json\.exception",
    r"nlohmann", r"terminate called", r"what\(\):", r"vector::", r"_M_", r"map::at", r"out_of_range",
    r"invalid_iterator", r"type_error", r"Segmentation", r"Assertion", r"core dumped", r"itk::ExceptionObject",
    r"Location: \"", r"ERROR: In ", r"Generic Warning", r"0x[0-9a-f]{6,}",
]

# The inputs that make the image commands fail at once.
BROKEN_INPUTS = {"data/truncated.mha", "data/broken.nii.gz", "data/empty.nii.gz", "data/missing.vtu",
                 "data/missing.nii.gz", "data/missing.mha", "data/not-a-transform.tfm"}

PROGRESS_LINE = re.compile(r"\s+\S.*\.\.\.( [0-9.]+ s)?")
PROGRESS_PREFIX = re.compile(r"^\s+\S[^:]*\.\.\.( [0-9.]+ s)?(?=biomech: error: )")

# Memory limit of each run: a mutation that asks for a huge model must end in
# a clear error, not in swapping (or the OOM killer) on the test machine.
MEMORY_LIMIT_BYTES = 3 * 1024**3

# Placeholders replaced in the serialised JSON text by tokens that JSON does not allow.
SPECIAL_TOKENS = {
    "@@NAN@@": "NaN",
    "@@INF@@": "Infinity",
    "@@NEGINF@@": "-Infinity",
    "@@HUGEEXP@@": "1e999",
    "@@NEGHUGEEXP@@": "-1e999",
    "@@BIGINT@@": "123456789012345678901234567890",
    "@@NEGBIGINT@@": "-98765432109876543210",
}


# ---------------------------------------------------------------------------
# Tiny inputs
# ---------------------------------------------------------------------------

MATERIAL = {"name": "brain", "youngs_modulus": 3000, "poisson_ratio": 0.45, "density": 1000}


def base_scenes():
    """Name -> (scene dict, data files it refers to). Each solves in well under a second."""
    top_box = {"nodes_in_box": {"min": [-1, -1, 9.9], "max": [11, 11, 10.1]}}
    return {
        "block-hex": ({
            "description": "2 x 2 x 2 hexahedra pressed 0.5 mm",
            "mesh": {"generate": "block", "size": [10, 10, 10], "divisions": [2, 2, 2], "cells": "hexahedra",
                     "origin": [0, 0, 0]},
            "materials": [dict(MATERIAL)],
            "node_sets": {"top": top_box,
                          "ball": {"nodes_in_sphere": {"center": [5, 5, 10], "radius": 3}},
                          "some": {"ids": [0, 1, 2]}},
            "fixed": [{"node_set": "zmin", "components": [True, True, True]}],
            "prescribed_displacements": [{"node_set": "top", "displacement": [0, 0, -0.5],
                                          "components": [False, False, True],
                                          "curve": {"shape": "smooth", "ramp_time": 1.0}}],
            "gravity": [0, 0, -9810],
            "gravity_curve": {"shape": "linear"},
            "fluid_surface": [0, 0, 5],
            "solver": {"integrator": "dynamic_relaxation", "tetrahedron": "anp", "tolerance": 0.01,
                       "max_steps": 20000, "load_steps": 50, "adapt_interval": 20, "hourglass_coefficient": 0.2,
                       "threads": 1, "compute_stress": True},
            "output": {"vtu": "result.vtu", "report": "report.json"},
        }, []),
        "block-tet-contact": ({
            "mesh": {"generate": "block", "size": [10, 10, 10], "divisions": [1, 1, 1], "cells": "tetrahedra"},
            "materials": [dict(MATERIAL)],
            "node_sets": {"top": {"surface_nodes_in_box": {"min": [-1, -1, 9.9], "max": [11, 11, 10.1]}}},
            "fixed": [{"node_set": "zmin"}],
            "prescribed_displacements": [{"node_set": "top", "displacement": [0, 0, 0.5]}],
            "contact": [{"name": "skull", "surface": {"generate": "ellipsoid", "semi_axes": [20, 20, 20],
                                                      "subdivisions": 1, "center": [5, 5, 5]},
                         "body_side": "inside", "flip_normals": False, "slave_node_set": "all"}],
            "solver": {"tetrahedron": "linear", "tolerance": 0.01, "max_steps": 20000},
        }, []),
        "file-vtk-labels-csv": ({
            "mesh": "data/small-block.vtk",
            "material_array": "material",
            "materials": [dict(MATERIAL, label=1), {"name": "tumour", "label": 2, "youngs_modulus": 6000,
                                                    "poisson_ratio": 0.45}],
            "node_sets": {"base": {"point_data": "zmin"}},
            "fixed": [{"node_set": "base"}],
            "prescribed_displacements": [{"csv": "data/small-block-top.csv", "curve": {"shape": "step"}}],
            "solver": {"tolerance": 0.01, "max_steps": 20000},
        }, ["data/small-block.vtk", "data/small-block-top.csv"]),
        "file-vtu-fields-stl": ({
            "mesh": "data/block.vtu",
            "material_fields": {"youngs_modulus": "youngs_modulus", "poisson_ratio": "poisson_ratio",
                                "density": "density"},
            "node_sets": {"base": {"point_data": "zmin"}},
            "fixed": [{"node_set": "base"}],
            "prescribed_displacements": [{"csv": "data/block-top.csv"}],
            "contact": [{"surface": "data/box.stl", "body_side": "inside"}],
            "solver": {"tolerance": 0.01, "max_steps": 20000},
            "output": {"vtu": "sub/result.vtu"},
        }, ["data/block.vtu", "data/block-top.csv", "data/box.stl"]),
        "explicit-probe": ({
            "mesh": {"generate": "block", "size": [10, 10, 10], "divisions": [1, 1, 1]},
            "materials": [dict(MATERIAL)],
            "fixed": [{"node_set": "zmin"}],
            "tools": [{"name": "probe", "shape": "probe", "radius": 1, "length": 20,
                       "trajectory": [{"time": 0, "position": [5, 5, 12]},
                                      {"time": 0.02, "position": [5, 5, 9.5], "rotation": [0, 0, 0]}],
                       "slave_node_set": "zmax"}],
            "solver": {"integrator": "explicit_dynamics", "end_time": 0.05, "damping": 50, "safety_factor": 0.8,
                       "time_step": 0, "output_interval": 0.01},
        }, []),
        "meshless": ({
            "mesh": {"generate": "block", "size": [10, 10, 10], "divisions": [2, 2, 2]},
            "materials": [dict(MATERIAL)],
            "discretization": "meshless",
            "meshless": {"basis": "linear", "dilatation": 1.6, "essential_boundary": "ebciem",
                         "integration": {"cell_size": 0, "points_per_direction": 2, "adaptive": False,
                                         "adaptive_tolerance": 0.01, "max_levels": 1}},
            "fixed": [{"node_set": "zmin"}],
            "prescribed_displacements": [{"node_set": "zmax", "displacement": [0, 0, -0.2]}],
            "solver": {"tolerance": 0.01, "max_steps": 20000},
        }, []),
    }


def box_stl(lower, upper):
    """A closed triangulated box, outward normals, ASCII STL."""
    (x0, y0, z0), (x1, y1, z1) = lower, upper
    corners = [(x, y, z) for z in (z0, z1) for y in (y0, y1) for x in (x0, x1)]
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    lines = ["solid box"]
    for a, b, c, d in quads:
        for tri in ((a, b, c), (a, c, d)):
            lines.append("  facet normal 0 0 0\n    outer loop")
            lines.extend("      vertex %g %g %g" % corners[i] for i in tri)
            lines.append("    endloop\n  endfacet")
    lines.append("endsolid box")
    return "\n".join(lines) + "\n"


def tiny_mha(size=6, inside=(1, 5)):
    """A MetaImage mask: size^3 voxels of 2 mm, a cube of ones inside."""
    header = ("ObjectType = Image\nNDims = 3\nDimSize = {0} {0} {0}\nElementSpacing = 2 2 2\n"
              "Offset = 0 0 0\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n").format(size)
    voxels = bytearray(size ** 3)
    for k in range(*inside):
        for j in range(*inside):
            for i in range(*inside):
                voxels[i + size * (j + size * k)] = 1
    return header.encode() + bytes(voxels)


def prepare_inputs(biomech, base):
    """Writes the data files the base scenes and commands use into BASE/data."""
    data = base / "data"
    data.mkdir(parents=True, exist_ok=True)
    shutil.copy(REPOSITORY / "examples/scenes/data/small-block.vtk", data)
    shutil.copy(REPOSITORY / "examples/scenes/data/small-block-top.csv", data)
    subprocess.run([biomech, "make-mesh", "--shape", "block", "--size", "10", "10", "10", "--divisions", "2", "2",
                    "2", "-o", str(data / "block.vtu")], check=True, stdout=subprocess.DEVNULL, env=child_env())
    # Nodes of the top face (z = 10) of the 2 x 2 x 2 block: ids 18 to 26.
    (data / "block-top.csv").write_text("id,ux,uy,uz\n" + "".join("%d,0,0,-0.3\n" % i for i in range(18, 27)))
    (data / "box.stl").write_text(box_stl((-5, -5, -5), (15, 15, 15)))
    (data / "mask.mha").write_bytes(tiny_mha())
    (data / "broken.nii.gz").write_bytes(b"\x1f\x8b\x08\x00garbage")
    (data / "empty.nii.gz").write_bytes(b"")
    mha = tiny_mha()
    (data / "truncated.mha").write_bytes(mha[: len(mha) // 2])
    (data / "displacements.csv").write_text("x,y,z,ux,uy,uz\n0,0,0,1,0,0\n4,4,4,0,1,0\n")
    (data / "not-a-transform.tfm").write_text("#Insight Transform File V1.0\n#Transform 0\nTransform: Nothing\n")


# ---------------------------------------------------------------------------
# Scene mutations
# ---------------------------------------------------------------------------

def paths_of(value, prefix=()):
    """Every (path, value) in a JSON tree, the root included."""
    yield prefix, value
    if isinstance(value, dict):
        for key, child in value.items():
            yield from paths_of(child, prefix + (key,))
    elif isinstance(value, list):
        for index, child in enumerate(value):
            yield from paths_of(child, prefix + (index,))


def get_at(tree, path):
    for part in path:
        tree = tree[part]
    return tree


def set_at(tree, path, value):
    if not path:
        return value
    get_at(tree, path[:-1])[path[-1]] = value
    return tree


TYPE_REPLACEMENTS = ["abc", "", "3", "1e3", 0, 1, -1, 2.5, True, False, None, [], {}, [1, 2, 3], [[1]],
                     {"x": 1}, ["a", "b", "c"], [True, False, True], [None, None, None]]
HUGE_NUMBERS = [1e308, -1e308, 1.7976931348623157e308, 5e-324, -5e-324, 1e-300, 2**31, 2**31 - 1, -2**31, 2**32,
                2**53 + 1, 2**63, 2**64, -2**63 - 1, 99999, 100001, 1e15, 9e15, -0.0]
SPECIAL_VALUES = list(SPECIAL_TOKENS)
# Relative paths only: biomech may create the folders an output name asks for.
STRING_REPLACEMENTS = ["", " ", "x" * 5000, "missing/none.vtk", "nonexistent/file.vtu", "../outside.vtu",
                       "data", "data/", "\u00e9\u4e2d\u0000", "result.vtu", "report.json", "a\nb", "..", "/",
                       "data/small-block.vtk", "data/block.vtu", "data/box.stl", "data/mask.mha",
                       "data/block-top.csv", "zmin", "all", "surface"]


def mutate_tree(scene, rng):
    """One structural mutation of the scene tree; returns (scene, description)."""
    nodes = list(paths_of(scene))
    path, value = rng.choice(nodes)
    where = "/" + "/".join(str(p) for p in path)
    kind = rng.choice(["delete", "type", "huge", "special", "negate", "zero", "empty", "length", "unknown",
                       "string", "duplicate_entry", "nest"])
    if kind == "delete" and path:
        parent = get_at(scene, path[:-1])
        del parent[path[-1]]
        return scene, "delete " + where
    if kind == "type":
        replacement = rng.choice(TYPE_REPLACEMENTS)
        return set_at(scene, path, json.loads(json.dumps(replacement))), "type %s = %r" % (where, replacement)
    if kind == "huge":
        replacement = rng.choice(HUGE_NUMBERS)
        return set_at(scene, path, replacement), "huge %s = %r" % (where, replacement)
    if kind == "special":
        token = rng.choice(SPECIAL_VALUES)
        return set_at(scene, path, token), "special %s = %s" % (where, SPECIAL_TOKENS[token])
    if kind in ("negate", "zero") and isinstance(value, (int, float)) and not isinstance(value, bool):
        replacement = -value if kind == "negate" else 0
        if kind == "negate" and value == 0:
            replacement = -1
        return set_at(scene, path, replacement), "%s %s = %r" % (kind, where, replacement)
    if kind == "empty" and isinstance(value, (list, dict)):
        return set_at(scene, path, type(value)()), "empty " + where
    if kind == "length" and isinstance(value, list):
        if value and rng.random() < 0.5:
            value.pop(rng.randrange(len(value)))
            return scene, "shorten " + where
        value.append(rng.choice(value) if value else 1)
        return scene, "lengthen " + where
    if kind == "unknown" and isinstance(value, dict):
        value[rng.choice(["bogus", "tolerence", "Mesh", "", "solver ", "node_set"])] = rng.choice([1, "x", {}])
        return scene, "unknown key in " + where
    if kind == "string" and isinstance(value, str):
        replacement = rng.choice(STRING_REPLACEMENTS)
        return set_at(scene, path, replacement), "string %s = %r" % (where, replacement[:40])
    if kind == "duplicate_entry" and isinstance(value, list) and value:
        value.append(json.loads(json.dumps(rng.choice(value))))
        return scene, "duplicate entry in " + where
    if kind == "nest":
        return set_at(scene, path, [json.loads(json.dumps(value))]), "nest %s in a list" % where
    # The chosen kind does not fit this value: replace its type instead.
    replacement = rng.choice(TYPE_REPLACEMENTS)
    return set_at(scene, path, json.loads(json.dumps(replacement))), "type %s = %r" % (where, replacement)


def dump_with_duplicates(value, rng, duplicate_probability):
    """JSON text; some objects repeat one of their keys with another value."""
    if isinstance(value, dict):
        items = ["%s: %s" % (json.dumps(k), dump_with_duplicates(v, rng, duplicate_probability))
                 for k, v in value.items()]
        if value and rng.random() < duplicate_probability:
            key = rng.choice(list(value))
            items.insert(rng.randrange(len(items) + 1),
                         "%s: %s" % (json.dumps(key), json.dumps(rng.choice(TYPE_REPLACEMENTS + HUGE_NUMBERS))))
        return "{" + ", ".join(items) + "}"
    if isinstance(value, list):
        return "[" + ", ".join(dump_with_duplicates(v, rng, duplicate_probability) for v in value) + "]"
    if isinstance(value, str) and value in SPECIAL_TOKENS:
        return SPECIAL_TOKENS[value]
    return json.dumps(value)


def mutate_bytes(data, rng):
    """Byte-level damage: truncation, flipped bytes, inserted or deleted bytes."""
    data = bytearray(data)
    kind = rng.choice(["truncate", "flip", "insert", "delete"])
    if not data:
        return bytes(data), "empty"
    if kind == "truncate":
        cut = rng.randrange(len(data))
        return bytes(data[:cut]), "truncate at byte %d of %d" % (cut, len(data))
    count = rng.randint(1, 4)
    for _ in range(count):
        position = rng.randrange(len(data))
        if kind == "flip":
            data[position] ^= 1 << rng.randrange(8)
        elif kind == "insert":
            data[position:position] = bytes([rng.choice(b"0123456789-+.eE,[]{}\":NaI \n\x00\xff")])
        elif len(data) > 1:
            del data[position]
    return bytes(data), "%s %d byte(s)" % (kind, count)


# ---------------------------------------------------------------------------
# Cost guard: which mutated scenes may legitimately run long
# ---------------------------------------------------------------------------

def number(value):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value)


def may_run_long(text):
    """True when the mutated scene, if accepted, asks for much more work than its base.

    A timeout of such a run is counted as a long run, not a hang."""
    try:
        scene = json.loads(text)
    except (ValueError, RecursionError):
        return False  # biomech must refuse it at once
    if not isinstance(scene, dict):
        return False

    def get(*keys):
        value = scene
        for key in keys:
            if not isinstance(value, dict) or key not in value:
                return None
            value = value[key]
        return value

    def numbers(value):
        if isinstance(value, list):
            return [n for n in (number(v) for v in value) if n is not None]
        n = number(value)
        return [] if n is None else [n]

    divisions = numbers(get("mesh", "divisions"))
    if divisions and (max(divisions) > 12 or math.prod(abs(d) for d in divisions) > 64):
        return True
    semi_axes, spacing = numbers(get("mesh", "semi_axes")), numbers(get("mesh", "spacing"))
    if semi_axes and spacing and (spacing[0] <= 0 or max(abs(a) for a in semi_axes) / spacing[0] > 12):
        return True
    solver = get("solver") if isinstance(get("solver"), dict) else {}
    for key, limit in (("max_steps", 50000), ("load_steps", 5000), ("adapt_interval", 5000)):
        value = numbers(solver.get(key))
        if value and value[0] > limit:
            return True
    tolerance = numbers(solver.get("tolerance"))
    if tolerance and tolerance[0] < 1e-4:
        return True
    explicit = solver.get("integrator") == "explicit_dynamics"
    if explicit or "integrator" not in solver:
        end_time = numbers(solver.get("end_time"))
        time_step = numbers(solver.get("time_step"))
        safety = numbers(solver.get("safety_factor"))
        output = numbers(solver.get("output_interval"))
        if end_time and end_time[0] > 0.2:
            return True
        if time_step and 0 < time_step[0] < 1e-4:
            return True
        if safety and safety[0] < 0.05:
            return True
        if output and 0 < output[0] < 1e-3:
            return True
        materials = get("materials") if isinstance(get("materials"), list) else []
        for material in materials:
            if isinstance(material, dict):
                modulus = numbers(material.get("youngs_modulus"))
                poisson = numbers(material.get("poisson_ratio"))
                density = numbers(material.get("density"))
                if (modulus and modulus[0] > 1e5) or (poisson and poisson[0] > 0.49) or (density and density[0] < 10):
                    return True
        if "materials" not in scene and explicit:
            return True  # material_fields or a mutated file: unknown stiffness
    for contact in get("contact") if isinstance(get("contact"), list) else []:
        surface = contact.get("surface") if isinstance(contact, dict) else None
        if isinstance(surface, dict) and (numbers(surface.get("subdivisions")) or [0])[0] > 5:
            return True
    meshless = get("meshless") if isinstance(get("meshless"), dict) else {}
    if (numbers(meshless.get("dilatation")) or [0])[0] > 3:
        return True
    integration = meshless.get("integration") if isinstance(meshless.get("integration"), dict) else {}
    if (numbers(integration.get("max_levels")) or [0])[0] > 2 or \
       (numbers(integration.get("points_per_direction")) or [0])[0] > 2:
        return True
    cell_size = numbers(integration.get("cell_size"))
    if cell_size and 0 < cell_size[0] < 2:
        return True
    if (numbers(integration.get("adaptive_tolerance")) or [1])[0] < 1e-3:
        return True
    for tool in get("tools") if isinstance(get("tools"), list) else []:
        if isinstance(tool, dict) and (numbers(tool.get("radius")) or [0])[0] > 50:
            return True
    return False


# ---------------------------------------------------------------------------
# Running and judging
# ---------------------------------------------------------------------------

def child_env():
    env = dict(os.environ)
    env.update({"OMP_NUM_THREADS": "1", "OMP_WAIT_POLICY": "PASSIVE", "ITK_GLOBAL_DEFAULT_NUMBER_OF_THREADS": "1",
                "LC_ALL": "C"})
    return env


def limit_child():
    os.setsid()
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT_BYTES, MEMORY_LIMIT_BYTES))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))


def run(command, cwd, time_limit):
    """(returncode or None on timeout, stdout, stderr, seconds)."""
    start = time.monotonic()
    process = subprocess.Popen(command, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               stdin=subprocess.DEVNULL, env=child_env(), preexec_fn=limit_child)
    try:
        out, err = process.communicate(timeout=time_limit)
        code = process.returncode
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        out, err = process.communicate()
        code = None
    return code, out.decode("utf-8", "replace"), err.decode("utf-8", "replace"), time.monotonic() - start


def snapshot(folder):
    return {p.relative_to(folder): p.stat().st_size for p in folder.rglob("*") if p.is_file() or p.is_symlink()}


def message_problem(stderr):
    """Why an error's stderr is not a clear message, or None."""
    # Without --quiet, commands show their steps ("  read           ... 0.01 s"); an error may end such a line.
    lines = [PROGRESS_PREFIX.sub("", line) for line in stderr.splitlines() if line.strip()]
    lines = [line for line in lines if line.strip() and not PROGRESS_LINE.fullmatch(line)]
    errors = [line for line in lines if line.startswith("biomech: error: ")]
    if not errors:
        return "no 'biomech: error:' message on stderr"
    if len(errors) > 1:
        return "more than one error message"
    message = errors[0][len("biomech: error: "):]
    if len(message.strip()) < 12:
        return "message too short to say what is wrong"
    for pattern in BAD_MESSAGE_PATTERNS:
        if re.search(pattern, stderr):
            return "internal text in the message (%s)" % pattern
    # CLI11's parse errors add one usage hint line; other output must be warnings at most.
    extra = [line for line in lines if line not in errors and not line.startswith("run 'biomech --help'")
             and not line.lower().startswith("biomech: warning") and not line.startswith("warning")]
    if extra:
        return "stray output on stderr: %r" % extra[0][:200]
    return None


def vtk_file_problem(path):
    data = path.read_bytes()
    if not data.lstrip().startswith(b"<?xml") and not data.lstrip().startswith(b"<VTKFile"):
        return "%s does not start like a VTK XML file" % path.name
    if not data.rstrip().endswith(b"</VTKFile>"):
        return "%s is not complete (no </VTKFile> at its end)" % path.name
    return None


def judge_solve(code, stderr, run_dir, before, outputs):
    """outputs: paths (relative to run_dir) the run declares; None if unknown (then any new .vtu/.json)."""
    after = snapshot(run_dir)
    new_files = sorted(str(p) for p in after if p not in before or after[p] != before[p])
    temporaries = [p for p in new_files if ".tmp" in p or p.endswith("~")]
    if code in (0, 2):
        if temporaries:
            return "temporary file left behind: %s" % temporaries[0]
        if not new_files:
            return "exit %d but nothing written" % code
        for relative in outputs or []:
            if not (run_dir / relative).is_file():
                return "exit %d but declared output %s missing" % (code, relative)
        for relative in new_files:
            path = run_dir / relative
            head = path.read_bytes()[:64].lstrip()
            if head.startswith(b"{"):
                try:
                    content = json.loads(path.read_text())
                except ValueError as error:
                    return "report %s does not parse: %s" % (relative, error)
                if "converged" in content and content["converged"] is not (code == 0):
                    return "exit %d but report says converged: %r" % (code, content["converged"])
            elif relative.endswith((".vtu", ".pvd")):
                problem = vtk_file_problem(path)
                if problem:
                    return problem
            elif path.stat().st_size == 0:
                return "empty output %s" % relative
        return None
    if code == 1:
        problem = message_problem(stderr)
        if problem:
            return problem
        if new_files:
            return "error exit but files left behind: %s" % ", ".join(new_files[:5])
        return None
    if code is None:
        return "timeout"
    if code < 0:
        return "killed by signal %d (%s)" % (-code, signal.Signals(-code).name if -code in
                                                 signal.valid_signals() else "?")
    return "exit status %d (biomech uses 0, 1 and 2)" % code


class Fuzzer:
    def __init__(self, args):
        self.args = args
        self.rng = random.Random(args.seed)
        self.work = Path(args.work).resolve()
        self.biomech = str(Path(args.biomech).resolve())
        self.failures = []
        self.counts = {"ok": 0, "error": 0, "not_converged": 0, "long": 0, "skipped": 0}
        self.case = 0

    def setup(self):
        if self.work.exists():
            shutil.rmtree(self.work)
        (self.work / "base").mkdir(parents=True)
        prepare_inputs(self.biomech, self.work / "base")
        self.scenes = base_scenes()
        # Every base input must pass unchanged, quickly: otherwise the fuzzing says nothing.
        for name, (scene, files) in self.scenes.items():
            code, problem, seconds = self.run_scene(name, json.dumps(scene), {}, ["solve"], "base", check_long=False)
            if problem or code != 0:
                raise SystemExit("base scene %s does not solve cleanly (exit %s, %s)" % (name, code, problem))
            if seconds > 5:
                raise SystemExit("base scene %s took %.1f s; the fuzzer needs tiny scenes" % (name, seconds))

    def new_run_dir(self):
        self.case += 1
        run_dir = self.work / "runs" / ("case-%05d" % self.case)
        if run_dir.exists():
            shutil.rmtree(run_dir)
        (run_dir / "data").mkdir(parents=True)
        for item in (self.work / "base" / "data").iterdir():
            shutil.copy(item, run_dir / "data" / item.name)
        return run_dir

    def record_failure(self, run_dir, description, command, code, stdout, stderr, problem):
        target = self.work / "failures" / run_dir.name
        if target.exists():
            shutil.rmtree(target)
        shutil.copytree(run_dir, target)
        (target / "command.txt").write_text(" ".join(_quote(c) for c in command) + "\n")
        (target / "outcome.txt").write_text(
            "mutation: %s\nproblem: %s\nexit: %s\n--- stderr\n%s\n--- stdout\n%s\n" %
            (description, problem, code, stderr[-4000:], stdout[-2000:]))
        self.failures.append((run_dir.name, description, problem))

    def run_scene(self, name, text, data_changes, command_kind, description, check_long=True, extra_args=()):
        raw = text.encode("utf-8", "surrogateescape") if isinstance(text, str) else text
        if re.search(rb'"\s*/', raw):
            # An absolute path could make biomech (run as root) write outside the work folder.
            self.counts["skipped"] += 1
            return None, None, 0.0
        run_dir = self.new_run_dir()
        scene_path = run_dir / "scene.json"
        scene_path.write_bytes(raw)
        for relative, content in data_changes.items():
            target = run_dir / relative
            if content is None:
                target.unlink(missing_ok=True)
            else:
                target.write_bytes(content)
        subcommand = command_kind[0]
        command = [self.biomech, subcommand, "scene.json", "-d", "out", "--threads", "1"]
        if self.rng.random() < 0.7:
            command.append("-q")
        command.extend(extra_args)
        long_possible = check_long and may_run_long(raw.decode("utf-8", "replace"))
        limit = min(self.args.time_limit, 4.0) if long_possible else self.args.time_limit
        before = snapshot(run_dir)
        code, out, err, seconds = run(command, run_dir, limit)
        if code is None and long_possible:
            self.counts["long"] += 1
            shutil.rmtree(run_dir, ignore_errors=True)
            return code, None, seconds
        problem = judge_solve(code, err, run_dir, before, None)
        if problem:
            self.record_failure(run_dir, "%s: %s" % (name, description), command, code, out, err, problem)
        else:
            self.counts[{0: "ok", 1: "error", 2: "not_converged"}[code]] += 1
            shutil.rmtree(run_dir, ignore_errors=True)
        return code, problem, seconds

    def scene_case(self):
        name = self.rng.choice(sorted(self.scenes))
        scene, files = self.scenes[name]
        scene = json.loads(json.dumps(scene))
        descriptions = []
        data_changes = {}
        roll = self.rng.random()
        if roll < 0.12 and files:
            # Damage or remove a file the scene refers to.
            relative = self.rng.choice(files)
            if self.rng.random() < 0.2:
                data_changes[relative] = None
                descriptions.append("remove " + relative)
            else:
                content, what = mutate_bytes((self.work / "base" / relative).read_bytes(), self.rng)
                data_changes[relative] = content
                descriptions.append("%s: %s" % (relative, what))
            text = json.dumps(scene)
        elif roll < 0.27:
            # Damage the scene text itself.
            content, what = mutate_bytes(json.dumps(scene, indent=1).encode(), self.rng)
            descriptions.append("scene text: " + what)
            text = content
        else:
            for _ in range(self.rng.choice([1, 1, 1, 2, 3])):
                scene, what = mutate_tree(scene, self.rng)
                descriptions.append(what)
            duplicates = 0.3 if self.rng.random() < 0.15 else 0.0
            if duplicates:
                descriptions.append("duplicated keys")
            text = dump_with_duplicates(scene, self.rng, duplicates)
        kind = ["simulate"] if name == "explicit-probe" and self.rng.random() < 0.4 else ["solve"]
        self.run_scene(name, text, data_changes, kind, "; ".join(descriptions))

    # -- command lines ------------------------------------------------------

    def base_commands(self):
        """(argument list, outputs it declares, relative to the run folder). Each is quick or fails fast."""
        scene = json.dumps(self.scenes["block-hex"][0])
        return [
            (["solve", "scene.json", "-d", "out", "--threads", "1", "-q"], ["out/result.vtu", "out/report.json"],
             scene),
            (["simulate", "scene.json", "-d", "out", "--threads", "1", "-q"], ["out/scene.pvd"],
             json.dumps(self.scenes["explicit-probe"][0])),
            (["make-mesh", "--shape", "block", "--size", "10", "10", "10", "--divisions", "2", "2", "2", "--cells",
              "hexahedra", "--origin", "0", "0", "0", "-o", "out/mesh.vtu"], ["out/mesh.vtu"], None),
            (["make-mesh", "--shape", "ellipsoid", "--semi-axes", "10", "10", "8", "--spacing", "4", "--cells",
              "tetrahedra", "-o", "out/mesh.vtk"], ["out/mesh.vtk"], None),
            # Image commands get broken or missing images: they must fail fast and clearly.
            (["classify", "data/truncated.mha", "--mask", "data/mask.mha", "-o", "out/c", "--classes", "3",
              "--fuzziness", "2", "--classifier-tolerance", "1e-5", "--classifier-max-iterations", "300"], None, None),
            (["grid", "data/broken.nii.gz", "-o", "out/grid.vtu", "--grid", "hexahedra", "--element-size", "5",
              "--threads", "1"], None, None),
            (["surfaces", "data/empty.nii.gz", "-o", "out/brain.vtp", "--skull-output", "out/skull.vtp",
              "--skull-gap", "1.5"], None, None),
            (["loads", "data/missing.vtu", "-o", "out/loads.csv", "--craniotomy-centre", "0", "0", "0",
              "--craniotomy-radius", "10", "--max-distance", "10"], None, None),
            (["model", "data/broken.nii.gz", "--mask", "data/mask.mha", "--craniotomy-centre", "5", "5", "5",
              "--craniotomy-radius", "4", "--element-size", "2", "--threads", "1", "-o", "out/model", "-q"],
             None, None),
            (["register", "data/missing.nii.gz", "--mask", "data/mask.mha", "--craniotomy-centre", "5", "5", "5",
              "--craniotomy-radius", "4", "--sparse-displacements", "data/displacements.csv", "--threads", "1",
              "-o", "out/reg", "-q"], None, None),
            (["fit-transform", "data/block.vtu", "data/truncated.mha", "-o", "out/t.h5", "--tolerance", "0.1",
              "--min-spacing", "1", "-q"], None, None),
            (["warp", "data/mask.mha", "data/not-a-transform.tfm", "-o", "out/w.mha", "--interpolation", "linear",
              "--default-value", "0"], None, None),
            (["evaluate", "data/empty.nii.gz", "data/mask.mha", "--variance", "2", "--threshold", "1.7", "-o",
              "out/e.json", "-q"], None, None),
            (["bspline-register", "data/missing.mha", "data/mask.mha", "-o", "out/b.mha",
              "--control-point-spacing", "20", "--iterations", "2", "--threads", "1", "-q"], None, None),
        ]

    NUMERIC_VALUES = ["nan", "NaN", "inf", "-inf", "Infinity", "-1", "0", "-0", "1e400", "-1e400", "1e308",
                      "4.9e-324", "abc", "", "1,5", "0x10", "2147483648", "-2147483649", "99999", "1e9", "3.7",
                      " 5", "5 ", "--", "-", "1e", "١"]

    def mutate_arguments(self, args):
        args = list(args)
        descriptions = []
        for _ in range(self.rng.choice([1, 1, 2, 3])):
            kind = self.rng.choice(["number", "number", "number", "delete", "unknown", "repeat", "swap", "value",
                                    "missing_file", "empty"])
            if len(args) < 2:
                break
            index = self.rng.randrange(1, len(args))
            if kind == "number":
                numeric = [i for i, a in enumerate(args) if re.fullmatch(r"-?[0-9.e+-]+", a) and i > 0]
                if numeric:
                    index = self.rng.choice(numeric)
                value = self.rng.choice(self.NUMERIC_VALUES)
                args[index] = value
                descriptions.append("arg %d = %r" % (index, value))
            elif kind == "delete":
                descriptions.append("delete %r" % args[index])
                del args[index]
            elif kind == "unknown":
                flag = self.rng.choice(["--bogus", "-z", "--threads=", "--output", "---", "-", "--tolerance"])
                args.insert(index, flag)
                descriptions.append("insert %r" % flag)
            elif kind == "repeat":
                options = [i for i, a in enumerate(args) if a.startswith("-") and i > 0]
                if options:
                    start = self.rng.choice(options)
                    end = start + 1
                    while end < len(args) and not args[end].startswith("-"):
                        end += 1
                    args.extend(args[start:end])
                    descriptions.append("repeat %r" % args[start])
            elif kind == "swap" and len(args) > 2:
                other = self.rng.randrange(1, len(args))
                args[index], args[other] = args[other], args[index]
                descriptions.append("swap %d %d" % (index, other))
            elif kind == "value":
                value = self.rng.choice(["hexahedra", "prisms", "block", "sphere", "out/x.txt", "out/", ".", "",
                                         "data/block.vtu", "scene.json", "linear", "cubic", "none", "3"])
                args[index] = value
                descriptions.append("arg %d = %r" % (index, value))
            elif kind == "missing_file":
                value = self.rng.choice(["data/missing.vtu", "nonexistent/x.nii.gz", "data", "data/box.stl",
                                         "data/block-top.csv", "data/empty.nii.gz"])
                args[index] = value
                descriptions.append("arg %d = %r" % (index, value))
            else:
                args[index] = ""
                descriptions.append("arg %d = ''" % index)
        return args, "; ".join(descriptions) or "unchanged"

    def command_case(self):
        args, outputs, scene = self.rng.choice(self.base_commands())
        mutated, description = self.mutate_arguments(args)
        if args[0] not in ("solve", "simulate", "make-mesh", "warp") and \
                not any(argument in BROKEN_INPUTS for argument in mutated[1:3]):
            # No broken input left where the command reads first: it could start a real (minutes long) computation.
            self.counts["skipped"] += 1
            return
        run_dir = self.new_run_dir()
        if scene is not None:
            (run_dir / "scene.json").write_text(scene)
        before = snapshot(run_dir)
        command = [self.biomech] + mutated
        long_possible = args[0] in ("solve", "simulate", "make-mesh") and any(
            re.fullmatch(r"[0-9.e+]+", a) and _float(a) > 20 for a in mutated) or args[0] in ("solve", "simulate") \
            and "--threads" in mutated and mutated.count("--threads") > 1
        # Only the fast commands may legitimately do work; image commands must fail at once.
        if args[0] == "make-mesh":
            long_possible = long_possible or any(re.fullmatch(r"[0-9.e+-]+", a) and 0 < abs(_float(a)) < 1
                                                 for a in mutated)
        limit = min(self.args.time_limit, 4.0) if long_possible else self.args.time_limit
        code, out, err, seconds = run(command, run_dir, limit)
        if code is None and long_possible:
            self.counts["long"] += 1
            shutil.rmtree(run_dir, ignore_errors=True)
            return
        declared = outputs if mutated == args else None
        problem = judge_solve(code, err, run_dir, before, declared)
        if problem is None and code in (0, 2) and args[0] == "make-mesh":
            meshes = [p for p in snapshot(run_dir) if p not in before]
            for mesh in meshes:
                if mesh.suffix == ".vtu":
                    problem = vtk_file_problem(run_dir / mesh)
        if problem is None and code in (0, 2) and args[0] not in ("solve", "simulate", "make-mesh"):
            problem = "an image command succeeded on a broken or missing input"
        if problem:
            self.record_failure(run_dir, "%s: %s" % (args[0], description), command, code, out, err, problem)
        else:
            self.counts[{0: "ok", 1: "error", 2: "not_converged"}[code]] += 1
            shutil.rmtree(run_dir, ignore_errors=True)

    def run_all(self):
        start = time.monotonic()
        self.setup()
        for index in range(self.args.mutations):
            if self.rng.random() < self.args.command_fraction:
                self.command_case()
            else:
                self.scene_case()
            if self.args.verbose and (index + 1) % 100 == 0:
                print("%d/%d runs, %d failures, %.0f s" % (index + 1, self.args.mutations, len(self.failures),
                                                            time.monotonic() - start), flush=True)
        shutil.rmtree(self.work / "runs", ignore_errors=True)
        elapsed = time.monotonic() - start
        print("fuzzed biomech with %d mutations (seed %d) in %.1f s: %d valid results, %d not converged, "
              "%d clear errors, %d long runs stopped, %d failures" %
              (self.args.mutations, self.args.seed, elapsed, self.counts["ok"], self.counts["not_converged"],
               self.counts["error"], self.counts["long"], len(self.failures)))
        for name, description, problem in self.failures:
            print("FAIL %s: %s\n     input: %s\n     reproducer: %s" %
                  (name, problem, description, self.work / "failures" / name))
        return 1 if self.failures else 0


def _float(text):
    try:
        return float(text)
    except ValueError:
        return 0.0


def _quote(text):
    return text if re.fullmatch(r"[A-Za-z0-9_./=:,+-]+", text) else "'" + text.replace("'", "'\\''") + "'"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--biomech", required=True, help="the biomech executable")
    parser.add_argument("--seed", type=int, default=20261125, help="random seed (the runs are reproducible)")
    parser.add_argument("--mutations", type=int, default=300, help="number of mutated runs")
    parser.add_argument("--work", default="fuzz-work", help="work folder (emptied first); failures stay here")
    parser.add_argument("--time-limit", type=float, default=20.0, help="seconds per run before it counts as a hang")
    parser.add_argument("--command-fraction", type=float, default=0.3, help="share of runs that mutate arguments")
    parser.add_argument("--verbose", action="store_true", help="progress every 100 runs")
    args = parser.parse_args()
    return Fuzzer(args).run_all()


if __name__ == "__main__":
    sys.exit(main())
