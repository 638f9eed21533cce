#!/usr/bin/env bash
# Installs the Python package biomechanical_registration for Debian's
# /usr/bin/python3: installs the Debian packages, builds the module in build/
# (Release) and runs `cmake --install build --component python`.
#   bash scripts/install-python.sh            # into /usr/local (on Debian's sys.path)
#   bash scripts/install-python.sh PREFIX     # into PREFIX/lib/python3.X/dist-packages
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

prefix="${1:-/usr/local}"
bash scripts/install-dependencies.sh

cmake -S . -B build -DCMAKE_BUILD_TYPE=Release
cmake --build build -j "$(nproc 2>/dev/null || echo 2)" --target _bmr
cmake --install build --component python --prefix "${prefix}"

site="${prefix}/lib/$(/usr/bin/python3 -c 'import sys; print("python%d.%d" % sys.version_info[:2])')/dist-packages"
echo "install-python: installed biomechanical_registration into ${site}"
# Check from outside the source tree that Debian's interpreter finds it.
(cd / && PYTHONPATH="${site}${PYTHONPATH:+:${PYTHONPATH}}" /usr/bin/python3 -c \
  'import biomechanical_registration as bmr; print("install-python: import works:", bmr.__file__)')
