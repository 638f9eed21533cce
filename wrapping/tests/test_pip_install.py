"""`pip install .` as users install (issue 61): pyproject.toml (scikit-build-core, the module's
CMake) builds the binding into a fresh virtual environment, whose `import biomechanical_registration`
then runs a small registration, bit for bit the one of the build tree's binding.

The venv is made from Debian's /usr/bin/python3 with --system-site-packages (Debian's NumPy);
pip fetches scikit-build-core from PyPI into its isolated build environment. The wheel's CMake
tree is kept in <build>/pip-install, so a second run rebuilds only what changed; with ccache
(scripts/install-dependencies.sh) a fresh tree takes its objects from build/'s compilation.
"""

import json
import os
import pathlib
import subprocess
import sys
import time

import pytest

from conftest import COLIN27, SOURCE_DIR

BUILD_DIR = pathlib.Path(os.environ.get("BMR_BUILD_DIR", SOURCE_DIR / "build"))
DEBIAN_PYTHON = "/usr/bin/python3"

PROBE = r'''
import hashlib, json, sys
import numpy as np
import biomechanical_registration as bmr
templates, sparse_csv = sys.argv[1:3]
image = bmr.imread(templates + "/ch2.nii.gz", pixel_type="float32")
bet = bmr.imread(templates + "/ch2bet.nii.gz")
mask = bmr.image_from_array((bmr.array_from_image(bet) > 0).astype(np.uint8), bet.spacing, bet.origin, bet.direction)
points, displacements = bmr.read_sparse_displacements(sparse_csv)
result = bmr.register(image, brain_mask=mask, sparse_points=points, sparse_displacements=displacements,
                      craniotomy_centre=(-11, 43, 84), craniotomy_radius=30, element_size=10, threads=1)
print(json.dumps(dict(file=bmr.__file__, version=bmr.__version__, steps=result.report["solve"]["steps"],
                      converged=result.report["solve"]["converged"],
                      max_displacement_mm=result.report["solve"]["max_displacement_mm"],
                      warped=hashlib.sha256(np.ascontiguousarray(result.warped_image.array).tobytes()).hexdigest())))
'''


def run(command, env, cwd, timeout):
    completed = subprocess.run([str(part) for part in command], capture_output=True, text=True, env=env, cwd=cwd,
                               timeout=timeout)
    assert completed.returncode == 0, "%s: exit %d\n%s\n%s" % (
        " ".join(map(str, command)), completed.returncode, completed.stdout[-4000:], completed.stderr[-4000:])
    return completed


def test_pip_install_gives_a_working_package(tmp_path):
    if not (COLIN27 / "ch2.nii.gz").exists():
        pytest.skip("Colin27 (mricron-data) is not installed")
    # Neither the build tree's package nor a user's site packages may stand in for the installed one.
    env = {key: value for key, value in os.environ.items() if key not in ("PYTHONPATH", "PYTHONHOME")}
    env.update(PIP_DISABLE_PIP_VERSION_CHECK="1", PYTHONNOUSERSITE="1")
    # build/'s compilers (CMake's default c++ and cc), not the x86_64-linux-gnu-g++ that Python's sysconfig
    # would hand scikit-build-core: ccache keys on the compiler's name, and then finds build/'s objects.
    env.setdefault("CXX", "c++")
    env.setdefault("CC", "cc")
    venv = tmp_path / "venv"
    run([DEBIAN_PYTHON, "-m", "venv", "--system-site-packages", venv], env, tmp_path, 300)
    python = venv / "bin" / "python"
    start = time.monotonic()
    installed = run([python, "-m", "pip", "install", "--no-cache-dir",
                     "--config-settings=build-dir=%s" % (BUILD_DIR / "pip-install"), SOURCE_DIR], env, tmp_path, 2400)
    print("pip install . took %.0f s" % (time.monotonic() - start))
    assert "Successfully installed biomechanical-registration-0.1.0" in installed.stdout
    # Debian's NumPy stays the one in use (no NumPy from PyPI in the venv).
    numpy = run([python, "-c", "import numpy; print(numpy.__file__)"], env, tmp_path, 60).stdout.strip()
    assert numpy.startswith("/usr/lib/python3/dist-packages/"), numpy
    files = run([python, "-m", "pip", "show", "-f", "biomechanical-registration"], env, tmp_path, 60).stdout
    for name in ("__init__.py", "image.py", "itk_bridge.py", "_bmr.cpython"):
        assert "biomechanical_registration/" + name in files, files

    arguments = [COLIN27, SOURCE_DIR / "examples" / "data" / "colin27-superior-craniotomy.csv"]
    from_wheel = json.loads(run([python, "-c", PROBE, *arguments], env, tmp_path, 600).stdout.strip().splitlines()[-1])
    assert from_wheel["file"].startswith(str(venv)), from_wheel["file"]
    assert from_wheel["converged"] and from_wheel["steps"] > 0 and from_wheel["max_displacement_mm"] > 1
    tree_env = dict(env, PYTHONPATH=str(BUILD_DIR / "python"))
    from_tree = json.loads(run([sys.executable, "-c", PROBE, *arguments], tree_env, tmp_path, 600).stdout.strip()
                           .splitlines()[-1])
    assert from_tree["file"].startswith(str(BUILD_DIR / "python"))
    assert {key: value for key, value in from_wheel.items() if key != "file"} == \
        {key: value for key, value in from_tree.items() if key != "file"}
