#!/usr/bin/python3
"""Executes examples/BrainShiftRegistration.ipynb and fails when a cell fails.

    PYTHONPATH=build/python build/venv/bin/python examples/run_notebook.py [--coarse] [--output executed.ipynb] [--timeout S]

--coarse sets BMR_NOTEBOOK_COARSE=1 (the CI settings). The kernel is this interpreter (the venv of
scripts/install-python-environment.sh: ITK's wheels, itk-elastix, antspyx and pyvista beside Debian's NumPy,
matplotlib and ipykernel), started in a temporary folder with this environment (PYTHONPATH must name the built
package; BMR_SOURCE_DIR, the source tree, defaults to this script's). Exit status 1 and the failing cell's
error when a cell fails. The repository's copy is stored executed with the full settings:
    PYTHONPATH=build/python build/venv/bin/python examples/run_notebook.py --output examples/BrainShiftRegistration.ipynb
"""
import argparse
import json
import os
import re
import shutil
import sys
import tempfile
import time

import nbformat
from jupyter_client.kernelspec import KernelSpecManager
from jupyter_client.manager import AsyncKernelManager
from nbclient import NotebookClient
from nbclient.exceptions import CellExecutionError, CellTimeoutError

NOTEBOOK = os.path.join(os.path.dirname(os.path.abspath(__file__)), "BrainShiftRegistration.ipynb")


def kernel_manager(folder):
    """A manager for the kernel "python3" that runs this interpreter: the installed kernelspec when it does,
    otherwise a private one (sys.executable -m ipykernel_launcher)."""
    spec = KernelSpecManager().get_kernel_spec("python3")
    program = spec.argv[0]
    if program in ("python", "python3"):  # jupyter_client runs these as sys.executable
        program = sys.executable
    # Paths, not their targets: a venv's python is a link to the system's, and only its own path makes it the venv.
    if os.path.abspath(shutil.which(program) or program) == os.path.abspath(sys.executable):
        return AsyncKernelManager(kernel_name="python3")
    kernels = os.path.join(folder, "kernels")
    os.makedirs(os.path.join(kernels, "python3"))
    with open(os.path.join(kernels, "python3", "kernel.json"), "w") as handle:
        json.dump({"argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
                   "display_name": "Python 3", "language": "python"}, handle)
    return AsyncKernelManager(kernel_name="python3", kernel_spec_manager=KernelSpecManager(kernel_dirs=[kernels]))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--coarse", action="store_true", help="the CI settings (BMR_NOTEBOOK_COARSE=1)")
    parser.add_argument("--output", help="write the executed notebook here (also when a cell fails)")
    parser.add_argument("--timeout", type=int, default=1800, help="seconds per cell (default 1800)")
    parser.add_argument("--notebook", default=NOTEBOOK, help="the notebook (default: %(default)s)")
    args = parser.parse_args()

    if args.coarse:
        os.environ["BMR_NOTEBOOK_COARSE"] = "1"
    # The solver's OpenMP threads synchronise often: spinning threads on a shared machine make it crawl.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    os.environ.setdefault("PYDEVD_DISABLE_FILE_VALIDATION", "1")  # quiets the kernel's debugger warning
    # The notebook finds the study's elastix parameter files in the source tree.
    os.environ.setdefault("BMR_SOURCE_DIR", os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    # The kernel inherits this environment; absolute paths keep the package importable from the temporary folder.
    paths = [os.path.abspath(path) for path in os.environ.get("PYTHONPATH", "").split(os.pathsep) if path]
    os.environ["PYTHONPATH"] = os.pathsep.join(paths)
    sys.path[:0] = paths
    try:
        import biomechanical_registration  # noqa: F401  (a clear message before the kernel starts)
    except ImportError as error:
        sys.exit("run_notebook.py: cannot import biomechanical_registration (%s); set PYTHONPATH=<build>/python" % error)

    notebook = nbformat.read(args.notebook, as_version=4)
    start = time.perf_counter()
    failed = None
    with tempfile.TemporaryDirectory(prefix="bmr-notebook-") as folder:
        client = NotebookClient(notebook, km=kernel_manager(folder), timeout=args.timeout,
                                resources={"metadata": {"path": folder}})
        try:
            client.execute(cleanup_kc=True)  # shut the kernel down: nbclient leaves a given km running
        except (CellExecutionError, CellTimeoutError) as error:
            failed = error
    if args.output:
        nbformat.write(notebook, args.output)
    if failed is not None:
        sys.stderr.write("run_notebook.py: %s failed after %.0f s:\n%s\n"
                         % (os.path.basename(args.notebook), time.perf_counter() - start,
                            re.sub(r"\x1b\[[0-9;]*m", "", str(failed))))  # no terminal colours in CI logs
        return 1
    print("run_notebook.py: %s (%s settings) ran in %.0f s" % (os.path.basename(args.notebook),
                                                              "coarse" if args.coarse else "full", time.perf_counter() - start))
    return 0


if __name__ == "__main__":
    sys.exit(main())
