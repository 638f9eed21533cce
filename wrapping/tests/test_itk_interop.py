"""The binding inside an `import itk` notebook (issue 61): Debian's ITK 5.2 (which the
binding links) and ITK's own 5.4 wheels in one Python process, in both import orders.

Each order runs in a fresh interpreter (sys.executable -c PROBE ORDER ...), which prints
one JSON line: the ITK copies in /proc/self/maps, itk.imread and bmr.imread of Colin27,
ITK 5.4's object factories, a coarse registration through the binding (10 mm grid,
one thread), and files written by one ITK read by the other. The facts asserted here: both ITKs load, each with its own factories; the
two readers give the same image; the registration is bit for bit the one of a process
without itk; and no library of one ITK (or VTK) binds a symbol to the other's
(LD_DEBUG=bindings), apart from two constant objects of libstdc++'s headers that the
dynamic linker unifies process-wide (GNU unique symbols). pyvista's VTK wheel beside the
binding's Debian VTK 9.1: surfaces go both ways through .vtp files, an off-screen plot.

Needs `itk` (skipped without it, e.g. under Debian's /usr/bin/python3): run with the
environment of scripts/install-python-environment.sh,
    PYTHONPATH=build/python build/venv/bin/python -m pytest wrapping/tests/test_itk_interop.py
"""

import importlib.util
import json
import os
import pathlib
import re
import subprocess
import sys

import pytest

import biomechanical_registration as bmr
from conftest import COLIN27, SOURCE_DIR

if importlib.util.find_spec("itk") is None:
    pytest.skip("itk (ITK's 5.4 wheels) is not importable by %s: run with build/venv/bin/python "
                "(scripts/install-python-environment.sh)" % sys.executable, allow_module_level=True)
if not (COLIN27 / "ch2.nii.gz").exists():
    pytest.skip("Colin27 (mricron-data) is not installed", allow_module_level=True)

ORDERS = ["itk-first", "bmr-first"]

# argv: ORDER COLIN27_DIR SPARSE_CSV [--no-register]
PROBE = r'''
import hashlib, json, os, re, sys
import numpy as np
order, templates, sparse_csv = sys.argv[1:4]
register = "--no-register" not in sys.argv
ch2, bet_path = os.path.join(templates, "ch2.nii.gz"), os.path.join(templates, "ch2bet.nii.gz")
out = {"order": order}

def loaded():
    paths = {line.split()[5] for line in open("/proc/self/maps") if len(line.split()) >= 6}
    return {"itk52": sorted(os.path.basename(p) for p in paths if re.search(r"/lib(ITK|itk)[^/]*-5\.2\.so", p)),
            "itk54": sorted(os.path.basename(p) for p in paths if re.search(r"/site-packages/itk/_\w+\.abi3\.so$", p)),
            "vtk91": sorted(os.path.basename(p) for p in paths if re.search(r"/libvtk[^/]*-9\.1\.so", p))}

def sha(array):
    return hashlib.sha256(np.ascontiguousarray(array).tobytes()).hexdigest()

# `import itk` is lazy: itk.imread loads ITK 5.4 (ITKCommon, the IO modules) there and then.
if order == "itk-first":
    import itk
    itk.imread(bet_path)
    out["loaded_before_bmr"] = loaded()
    import biomechanical_registration as bmr
elif order == "bmr-first":
    import biomechanical_registration as bmr
    bmr.imread(bet_path)
    out["loaded_before_itk"] = loaded()
    import itk
else:
    import biomechanical_registration as bmr
    itk = None
out["bmr_file"] = bmr.__file__

b = bmr.imread(ch2)
out["bmr_image"] = dict(dtype=str(b.array.dtype), shape=list(b.array.shape), spacing=list(b.spacing),
                        origin=list(b.origin), direction=np.asarray(b.direction).tolist(), sha=sha(b.array))
if itk is not None:
    out["itk_version"] = itk.Version.GetITKVersion()
    image_itk = itk.imread(ch2)
    array = itk.array_from_image(image_itk)
    out["itk_image"] = dict(dtype=str(array.dtype), shape=list(array.shape), spacing=list(image_itk.GetSpacing()),
                            origin=list(image_itk.GetOrigin()), direction=np.asarray(image_itk.GetDirection()).tolist(),
                            sha=sha(array))
    out["same_image"] = bool(array.dtype == b.array.dtype and np.array_equal(array, b.array)
                             and np.array_equal(np.asarray(image_itk.GetSpacing()), b.spacing)
                             and np.array_equal(np.asarray(image_itk.GetOrigin()), b.origin)
                             and np.array_equal(np.asarray(image_itk.GetDirection()), np.asarray(b.direction)))
    out["itk_factories"] = [f.GetDescription() for f in itk.ObjectFactoryBase.GetRegisteredFactories()]
    out["itk_nifti_io"] = itk.ImageIOFactory.CreateImageIO(ch2, itk.CommonEnums.IOFileMode_ReadMode).GetNameOfClass()

if register:
    image = bmr.imread(ch2, pixel_type="float32")
    bet = bmr.imread(bet_path)
    mask = bmr.image_from_array((bmr.array_from_image(bet) > 0).astype(np.uint8), bet.spacing, bet.origin, bet.direction)
    points, displacements = bmr.read_sparse_displacements(sparse_csv)
    result = bmr.register(image, brain_mask=mask, sparse_points=points, sparse_displacements=displacements,
                          craniotomy_centre=(-11, 43, 84), craniotomy_radius=30, element_size=10, threads=1)
    axis = np.linspace(-60, 60, 7)
    samples = np.array(np.meshgrid(axis, axis, axis, indexing="ij")).reshape(3, -1).T
    out["registration"] = dict(steps=result.report["solve"]["steps"], converged=result.report["solve"]["converged"],
                               max_displacement_mm=result.report["solve"]["max_displacement_mm"],
                               fit_max_residual=result.fit_max_residual, warped=sha(result.warped_image.array),
                               transformed_points=sha(result.transform.transform_points(samples)))
if itk is not None:
    # Files from one ITK read by the other (after the registration): NRRD written by ITK 5.4, NIfTI by 5.2.
    import shutil, tempfile
    folder = tempfile.mkdtemp()
    itk.imwrite(image_itk, os.path.join(folder, "by-itk.nrrd"))
    bmr.imwrite(b, os.path.join(folder, "by-bmr.nii.gz"))
    by_itk, by_bmr = bmr.imread(os.path.join(folder, "by-itk.nrrd")), itk.imread(os.path.join(folder, "by-bmr.nii.gz"))
    out["files_exchanged"] = bool(np.array_equal(by_itk.array, b.array) and np.array_equal(by_itk.origin, b.origin)
                                  and np.array_equal(itk.array_from_image(by_bmr), b.array)
                                  and np.array_equal(np.asarray(by_bmr.GetDirection()), np.asarray(b.direction)))
    shutil.rmtree(folder)
out["loaded"] = loaded()
print(json.dumps(out))
'''

PYVISTA_PROBE = r'''
import json, os, sys
import numpy as np
order, folder = sys.argv[1:3]
if order == "pyvista-first":
    import pyvista as pv
    pv.Sphere()
    import biomechanical_registration as bmr
else:
    import biomechanical_registration as bmr
    bmr.make_ellipsoid_surface((30, 20, 10))
    import pyvista as pv
import vtk
out = {"vtk": vtk.vtkVersion.GetVTKVersion()}
z, y, x = np.indices((40, 40, 40)) - 19.5
brain, _ = bmr.brain_surfaces(bmr.image_from_array(((x**2 + y**2 + z**2) <= 12**2).astype(np.uint8)), skull_gap=3.0)
bmr.write_surface(os.path.join(folder, "brain.vtp"), brain)
mesh = pv.read(os.path.join(folder, "brain.vtp"))
out["bmr_to_pyvista"] = bool(np.array_equal(np.asarray(mesh.points, dtype=np.float64), np.asarray(brain.vertices)))
sphere = pv.Sphere(radius=10)
sphere.save(os.path.join(folder, "sphere.vtp"))
back = bmr.read_surface(os.path.join(folder, "sphere.vtp"))
# read_surface keeps the points, not their order.
out["pyvista_to_bmr"] = bool(np.array_equal(np.unique(np.asarray(back.vertices), axis=0),
                                            np.unique(np.asarray(sphere.points, dtype=np.float64), axis=0))
                             and len(back.triangles) == sphere.n_cells)
out["closed"] = back.is_closed()
pv.OFF_SCREEN = True
plotter = pv.Plotter(off_screen=True, window_size=(160, 120))
plotter.add_mesh(mesh, color="tan")
image = plotter.screenshot(os.path.join(folder, "plot.png"), return_img=True)
out["render_window"] = plotter.render_window.GetClassName()
plotter.close()
out["plot_colours"] = int(len(np.unique(image.reshape(-1, image.shape[-1]), axis=0)))
out["png_bytes"] = os.path.getsize(os.path.join(folder, "plot.png"))
del mesh, sphere  # before the interpreter's shutdown, where pyvista's __del__ would complain
print(json.dumps(out))
'''

# Cross-bindings allowed between the ITKs / VTKs: objects of libstdc++'s headers that are
# function-local statics of inline functions (GNU unique symbols, unified process-wide even
# under RTLD_LOCAL): std::_Sp_make_shared_tag::_S_ti()::__tag and
# std::__detail::__to_chars_10_impl<...>::__digits, constant data, the same in every copy.
ALLOWED_CROSS = re.compile(r"^_ZZNSt(19_Sp_make_shared_tag5_S_tiEvE5__tag|8__detail18__to_chars_10_impl\w+E8__digits)$")
BINDING = re.compile(r"binding file (\S+) \[\d+\] to (\S+) \[\d+\]: \w+ symbol `([^']+)'")


def side(path):
    """'debian' (the binding, Debian's ITK 5.2 and VTK 9.1), 'wheel' (ITK 5.4's and VTK's wheels) or None."""
    if "_bmr.cpython" in path or re.search(r"/lib(ITK|itk)[^/]*-5\.2\.so|/libvtk[^/]*-9\.1\.so", path):
        return "debian"
    if re.search(r"/site-packages/(itk|itk_\w+\.libs|vtkmodules)/", path):
        return "wheel"
    return None


def run(code, *arguments, env=None, timeout=300):
    completed = subprocess.run([sys.executable, "-c", code, *map(str, arguments)], capture_output=True, text=True,
                               env=env, timeout=timeout)
    assert completed.returncode == 0, "exit %d\n%s" % (completed.returncode, completed.stderr[-3000:])
    return completed


def probe(order, *flags, env=None):
    completed = run(PROBE, order, COLIN27, SOURCE_DIR / "examples" / "data" / "colin27-superior-craniotomy.csv",
                    *flags, env=env)
    return json.loads(completed.stdout.strip().splitlines()[-1]), completed


@pytest.fixture(scope="module")
def results():
    """The probe's findings for each order, and for a process without itk."""
    return {order: probe(order)[0] for order in ORDERS + ["bmr-only"]}


@pytest.mark.parametrize("order", ORDERS)
def test_both_itks_load(results, order):
    found = results[order]
    assert found["bmr_file"] == bmr.__file__
    assert found["itk_version"].startswith("5.4.")
    loaded = found["loaded"]
    # The binding's ITK 5.2 (Debian's shared libraries) and the wheels' ITK 5.4 (static in each _*Python module).
    assert "libITKCommon-5.2.so.1" in loaded["itk52"] and "libITKIONIFTI-5.2.so.1" in loaded["itk52"]
    assert "_ITKCommonPython.abi3.so" in loaded["itk54"] and "_ITKIONIFTIPython.abi3.so" in loaded["itk54"]
    assert "libvtkCommonCore-9.1.so.9.1.0" in loaded["vtk91"]
    first = found.get("loaded_before_bmr") or found.get("loaded_before_itk")
    if order == "itk-first":
        assert first["itk54"] and not first["itk52"]
    else:
        assert first["itk52"] and not first["itk54"]
    assert not results["bmr-only"]["loaded"]["itk54"]


@pytest.mark.parametrize("order", ORDERS)
def test_itk_and_bmr_read_the_same_image(results, order):
    found = results[order]
    assert found["same_image"]
    assert found["itk_image"] == found["bmr_image"]
    assert found["bmr_image"] == results["bmr-only"]["bmr_image"]
    assert found["bmr_image"]["shape"] == [181, 217, 181] and found["bmr_image"]["dtype"] == "uint8"


@pytest.mark.parametrize("order", ORDERS)
def test_itk_keeps_its_own_object_factories(results, order):
    found = results[order]
    assert any(description.startswith("Nifti ImageIO Factory") for description in found["itk_factories"])
    assert len(found["itk_factories"]) >= 15
    assert found["itk_nifti_io"] == "NiftiImageIO"
    assert found["files_exchanged"]


@pytest.mark.parametrize("order", ORDERS)
def test_registration_is_bitwise_that_of_a_process_without_itk(results, order):
    alone = results["bmr-only"]["registration"]
    assert alone["converged"] and alone["steps"] > 0 and alone["max_displacement_mm"] > 1
    assert results[order]["registration"] == alone


@pytest.mark.parametrize("order", ORDERS)
def test_no_symbol_binds_across_the_itks(order):
    """LD_DEBUG=bindings: no library of the binding's side (the binding, Debian's ITK 5.2 and VTK 9.1) binds
    a symbol to ITK 5.4's wheels or the reverse, beyond libstdc++'s unique constants."""
    env = dict(os.environ, LD_DEBUG="bindings")
    found, completed = probe(order, "--no-register", env=env)
    assert found["same_image"]
    total, cross = 0, set()
    for match in BINDING.finditer(completed.stderr):
        total += 1
        sides = side(match[1]), side(match[2])
        if None not in sides and sides[0] != sides[1]:
            cross.add((sides[0], sides[1], match[3]))
    assert total > 10000, "LD_DEBUG printed no bindings"
    unexpected = sorted(item for item in cross if not ALLOWED_CROSS.match(item[2]))
    assert not unexpected, unexpected


@pytest.mark.parametrize("order", ["pyvista-first", "bmr-first"])
def test_pyvista_beside_the_binding(tmp_path, order):
    if importlib.util.find_spec("pyvista") is None:
        pytest.skip("pyvista is not importable")
    completed = run(PYVISTA_PROBE, order, tmp_path)
    found = json.loads(completed.stdout.strip().splitlines()[-1])
    assert found["vtk"].startswith("9.") and found["bmr_to_pyvista"] and found["pyvista_to_bmr"] and found["closed"]
    assert found["plot_colours"] > 10 and found["png_bytes"] > 1000


GLOBAL_PROBE = r'''
import ctypes, json, os, sys
import numpy as np
ch2bet = sys.argv[1]
flags = sys.getdlopenflags()
sys.setdlopenflags(os.RTLD_NOW | os.RTLD_GLOBAL)  # as some notebooks and packages do
import biomechanical_registration as bmr
sys.setdlopenflags(flags)
out = {"bmr_file": bmr.__file__}
# What RTLD_GLOBAL would have put in the global scope: ITK's itk::Object::New.
try:
    getattr(ctypes.CDLL(None), "_ZN3itk6Object3NewEv")
    out["itk_in_global_scope"] = True
except AttributeError:
    out["itk_in_global_scope"] = False
import itk
import scipy.ndimage
mask = itk.imread(ch2bet)
smoothed = itk.array_from_image(itk.median_image_filter(mask, radius=1))
# ITK's median (zero-flux Neumann boundary) is SciPy's with mode="nearest", voxel for voxel.
out["itk_median_right"] = bool(np.array_equal(smoothed, scipy.ndimage.median_filter(itk.array_from_image(mask), size=3,
                                                                                    mode="nearest")))
image = bmr.imread(ch2bet, pixel_type="float32")
out["bmr_warp"] = float(bmr.warp_image(image, bmr.identity_transform()).array.astype(np.float64).sum())
print(json.dumps(out))
'''


def test_the_binding_stays_out_of_the_global_scope(tmp_path):
    """A caller's RTLD_GLOBAL (sys.setdlopenflags) does not reach the extension: the package's
    __init__ loads it with RTLD_LOCAL. Without that, Debian's ITK 5.2 entered the global scope and
    ITK 5.4's median filter bound to it (its sum 4.0e6 instead of 3.2e8), then malloc aborted.
    Runs the source tree's package .py files with the built extension."""
    package = tmp_path / "biomechanical_registration"
    package.mkdir()
    source = SOURCE_DIR / "wrapping" / "biomechanical_registration"
    for module in source.glob("*.py"):
        (package / module.name).symlink_to(module)
    for extension in pathlib.Path(bmr.__file__).parent.glob("_bmr*.so"):
        (package / extension.name).symlink_to(extension)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]))
    completed = run(GLOBAL_PROBE, COLIN27 / "ch2bet.nii.gz", env=env)
    found = json.loads(completed.stdout.strip().splitlines()[-1])
    assert found["bmr_file"] == str(package / "__init__.py")
    assert not found["itk_in_global_scope"]
    assert found["itk_median_right"]
    assert found["bmr_warp"] > 0
