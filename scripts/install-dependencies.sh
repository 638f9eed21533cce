#!/usr/bin/env bash
# Installs the Debian (bookworm) packages the module needs to build, test and
# run its demo. Idempotent: packages already installed are left alone, and
# apt-get runs only when something is missing. libgdcm-tools: the DICOM
# reader's GDCM exports its tools as CMake targets (CMake warns when they are
# missing), and gdcmdump / gdcminfo are what one reads a hospital's series with.
# python3-venv and python3-scipy: the ITK-Python environment
# (scripts/install-python-environment.sh) is a venv over Debian's NumPy and
# SciPy, which its PyPI packages must not replace. ccache: the wheel that
# `pip install .` builds (pyproject.toml) compiles the same sources with the
# same flags as build/, so its objects come from the cache.
set -euo pipefail

packages=(
  build-essential cmake g++ pkg-config ccache
  libinsighttoolkit5-dev libvtk9-dev libcgal-dev libeigen3-dev
  libgtest-dev googletest libbenchmark-dev
  nlohmann-json3-dev libcli11-dev libnanoflann-dev zlib1g-dev
  calculix-ccx mricron-data insighttoolkit5-examples elastix
  libgdcm-tools
  python3 python3-dev python3-numpy python3-matplotlib python3-pytest
  pybind11-dev python3-nbclient python3-nbformat python3-ipykernel
  python3-scipy python3-venv
  snakemake
)

missing=()
for package in "${packages[@]}"; do
  if ! dpkg -s "${package}" >/dev/null 2>&1; then
    missing+=("${package}")
  fi
done

if [ "${#missing[@]}" -eq 0 ]; then
  echo "install-dependencies: all ${#packages[@]} packages already installed"
  exit 0
fi

echo "install-dependencies: installing ${missing[*]}"

# Root runs apt-get directly; otherwise use sudo where it exists.
run_as_root=()
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then
    run_as_root=(sudo)
  else
    echo "install-dependencies: not root and no sudo; install as root: ${missing[*]}" >&2
    exit 1
  fi
fi

export DEBIAN_FRONTEND=noninteractive
"${run_as_root[@]}" apt-get update
"${run_as_root[@]}" apt-get install -y --no-install-recommends "${missing[@]}"
echo "install-dependencies: installed ${missing[*]}"
