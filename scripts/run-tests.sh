#!/usr/bin/env bash
# THE test command: installs dependencies, builds build/ (Release) and runs
# every test through CTest. Exits with CTest's status.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

bash scripts/install-dependencies.sh
# ITK's Python wheels, itk-elastix, antspyx and pyvista in build/venv (PyPI):
# the test Python.itk_interop runs with it.
bash scripts/install-python-environment.sh

build_dir=build
jobs="$(nproc 2>/dev/null || echo 2)"

cmake -S . -B "${build_dir}" -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=ON
cmake --build "${build_dir}" -j "${jobs}"

status=0
ctest --test-dir "${build_dir}" --output-on-failure -j 2 || status=$?
exit "${status}"
