#!/usr/bin/env bash
# Creates the ITK-Python notebook environment of issue 61: a virtual
# environment at build/venv from Debian's /usr/bin/python3 with
# --system-site-packages (Debian's NumPy, SciPy and Matplotlib stay the ones
# in use), with requirements-python.txt (ITK's 5.4 wheels, itk-elastix,
# antspyx, pyvista and vtk, every package pinned) installed into it by pip.
# The module's binding is not installed there: put the build's python folder
# on PYTHONPATH, e.g.
#   PYTHONPATH=build/python build/venv/bin/python -c 'import itk, biomechanical_registration'
#
#   bash scripts/install-python-environment.sh           # build/venv
#   VENV=DIR bash scripts/install-python-environment.sh  # another folder
#
# Idempotent: a venv whose marker (the SHA-256 of requirements-python.txt and
# the interpreter's version) matches, and whose installed versions are the
# pins, is left alone; otherwise pip installs the pins into it (a venv made
# from another interpreter is made again). Needs Debian's python3-venv
# (installed with apt-get only when missing) and PyPI; takes about 1.5 minutes
# and 2.5 GiB of disk (ITK's wheels 1.6 GiB, vtk 0.6 GiB).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

python=/usr/bin/python3
venv="${VENV:-build/venv}"
requirements=requirements-python.txt
marker="${venv}/.requirements-python.sha256"

# Debian's python3 has venv without ensurepip until python3-venv is
# installed: scripts/install-dependencies.sh installs it (and the NumPy and
# SciPy the venv keeps).
if ! dpkg -s python3-venv >/dev/null 2>&1; then
  bash scripts/install-dependencies.sh
fi

wanted="$( (sha256sum "${requirements}" | cut -d' ' -f1; "${python}" -c 'import sys; print(sys.version)') | sha256sum | cut -d' ' -f1)"

# The pins that are not installed at their version in the venv (none: all there).
missing_pins() {
  "${venv}/bin/python" - "${requirements}" <<'EOF'
import re, sys
from importlib import metadata
for line in open(sys.argv[1]):
    line = line.split("#", 1)[0].strip()
    if not line:
        continue
    name, version = re.fullmatch(r"([A-Za-z0-9_.-]+)==(\S+)", line).groups()
    try:
        found = metadata.version(name)
    except metadata.PackageNotFoundError:
        found = None
    if found != version:
        print("%s==%s (found %s)" % (name, version, found))
EOF
}

if [ -x "${venv}/bin/python" ] && [ -f "${marker}" ] && [ "$(cat "${marker}")" = "${wanted}" ] &&
   [ -z "$(missing_pins)" ]; then
  echo "install-python-environment: ${venv} already has ${requirements} (marker ${wanted:0:12}); nothing to do"
  exit 0
fi

started=$(date +%s)
if [ -x "${venv}/bin/python" ] && "${venv}/bin/python" -c 'import sys; sys.exit(sys.base_prefix != "/usr")' 2>/dev/null &&
   grep -q '^include-system-site-packages = true' "${venv}/pyvenv.cfg" 2>/dev/null; then
  echo "install-python-environment: reusing ${venv}; installing the pins that differ:"
  missing_pins | sed 's/^/  /'
else
  echo "install-python-environment: creating ${venv} from ${python} ($("${python}" -V 2>&1)) with --system-site-packages"
  rm -rf "${venv}"
  "${python}" -m venv --system-site-packages "${venv}"
fi
rm -f "${marker}"

# pip's default upgrade strategy (only-if-needed), no --upgrade: what Debian
# provides and satisfies the pins stays Debian's.
"${venv}/bin/python" -m pip install --no-input --disable-pip-version-check -r "${requirements}"

left="$(missing_pins)"
if [ -n "${left}" ]; then
  echo "install-python-environment: pins not installed after pip:" >&2
  echo "${left}" >&2
  exit 1
fi
# Debian's NumPy, SciPy and Matplotlib must still be the ones imported.
"${venv}/bin/python" - <<'EOF'
import sys
import matplotlib, numpy, scipy
for module in (numpy, scipy, matplotlib):
    if not module.__file__.startswith("/usr/lib/python3/dist-packages/"):
        sys.exit("install-python-environment: %s %s comes from %s, not Debian's" %
                 (module.__name__, module.__version__, module.__file__))
    print("install-python-environment: %s %s is Debian's" % (module.__name__, module.__version__))
EOF
# Packages in the venv that requirements-python.txt does not pin (a dependency that changed).
unpinned="$("${venv}/bin/python" -m pip list --local --format=freeze --disable-pip-version-check |
  "${venv}/bin/python" -c '
import re, sys
pinned = {re.split("==", l.split("#")[0].strip())[0].lower().replace("_", "-")
          for l in open(sys.argv[1]) if l.split("#")[0].strip()}
for line in sys.stdin:
    name = line.split("==")[0].strip()
    if name.lower().replace("_", "-") not in pinned | {"pip", "setuptools"}:
        print(line.strip())' "${requirements}")"
if [ -n "${unpinned}" ]; then
  echo "install-python-environment: warning: installed but not pinned in ${requirements}: ${unpinned//$'\n'/ }" >&2
fi

echo "${wanted}" >"${marker}"
echo "install-python-environment: ${venv} ready in $(( $(date +%s) - started )) s, $(du -sh "${venv}" | cut -f1):" \
  "$("${venv}/bin/python" -c 'import itk, vtk, pyvista, ants; print("itk", itk.Version.GetITKVersion(), "vtk", vtk.vtkVersion.GetVTKVersion(), "pyvista", pyvista.__version__, "antspyx", ants.__version__)')"
