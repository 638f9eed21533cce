"""Shared fixtures of the binding's tests (run by CTest: see wrapping/CMakeLists.txt).

The environment names the build: PYTHONPATH has <build>/python, BMR_BIOMECH
the command-line tool, BMR_BUILD_DIR the build folder, BMR_SOURCE_DIR the
source tree.
"""

import os
import pathlib
import subprocess

import numpy as np
import pytest

import biomechanical_registration as bmr

COLIN27 = pathlib.Path("/usr/share/mricron/templates")
SOURCE_DIR = pathlib.Path(os.environ.get("BMR_SOURCE_DIR", pathlib.Path(__file__).resolve().parents[2]))


def pytest_configure(config):
    config.addinivalue_line("markers", "colin27: needs Colin27 from mricron-data")


@pytest.fixture(scope="session")
def biomech():
    """Runs the command-line tool: biomech(args..., cwd=...) -> CompletedProcess (text)."""
    executable = os.environ.get("BMR_BIOMECH")
    if not executable or not os.path.exists(executable):
        pytest.skip("BMR_BIOMECH does not name the biomech executable")

    def run(*arguments, cwd=None):
        return subprocess.run([executable, *map(str, arguments)], cwd=cwd, capture_output=True, text=True)

    return run


@pytest.fixture(scope="session")
def colin27():
    """(T1 image as float32, brain mask as uint8) of Colin27."""
    if not (COLIN27 / "ch2.nii.gz").exists():
        pytest.skip("Colin27 (mricron-data) is not installed")
    image = bmr.imread(COLIN27 / "ch2.nii.gz", pixel_type="float32")
    bet = bmr.imread(COLIN27 / "ch2bet.nii.gz")
    mask = bmr.image_from_array((bmr.array_from_image(bet) > 0).astype(np.uint8), bet.spacing, bet.origin, bet.direction)
    return image, mask


def ball_mask(size=32, radius=10.0, spacing=(1.0, 1.0, 1.0), origin=(0.0, 0.0, 0.0), direction=None):
    """A uint8 ball of `radius` voxels in the middle of a size^3 grid."""
    z, y, x = np.mgrid[0:size, 0:size, 0:size]
    centre = (size - 1) / 2.0
    inside = (x - centre) ** 2 + (y - centre) ** 2 + (z - centre) ** 2 <= radius**2
    return bmr.image_from_array(inside.astype(np.uint8), spacing, origin, direction)
