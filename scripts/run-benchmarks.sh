#!/usr/bin/env bash
# Builds the module in Release and runs the benchmark driver, then draws the
# error-against-run-time plot, then times model building from an MRI. Writes
# docs/benchmarks.md, docs/benchmark-error-vs-time.csv,
# docs/benchmark-error-vs-time.png, docs/stability-matrix.md,
# docs/wait-policy.md, docs/model-building-benchmark.md and
# docs/registration-benchmark.md (with their sections of docs/benchmarks.md).
#
#   scripts/run-benchmarks.sh [bmrBenchmark options, e.g. --quick or --threads 1,2]
#
# Environment: BUILD_DIR (default build-bench), JOBS (default 2).
# Takes about 15-30 minutes on 2 cores, most of it the CalculiX reference
# (cached in BUILD_DIR/benchmark-cache for later runs). Run it on a quiet
# machine: each timed case waits up to 300 s for one (--wait-quiet), and the
# report records how many cores other processes kept busy.
set -euo pipefail
# A bounded spin of idle OpenMP threads (docs/wait-policy.md), unless the caller chose.
export GOMP_SPINCOUNT="${GOMP_SPINCOUNT:-1000}"

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${BUILD_DIR:-${root}/build-bench}"
jobs="${JOBS:-2}"

cmake -S "${root}" -B "${build}" -DCMAKE_BUILD_TYPE=Release
cmake --build "${build}" --target bmrBenchmark bmrImageBenchmark bmrStabilityBenchmark biomech -j "${jobs}"

command -v ccx >/dev/null 2>&1 || echo "run-benchmarks: ccx (calculix-ccx) not found; the CalculiX-referenced part is skipped" >&2

cd "${root}"
"${build}/benchmarks/bmrBenchmark" \
  --output docs/benchmarks.md \
  --csv docs/benchmark-error-vs-time.csv \
  --reference-cache "${build}/benchmark-cache" \
  "$@"

if [ -f docs/benchmark-error-vs-time.csv ]; then
  # Debian's interpreter: the python3 first on PATH may not see python3-matplotlib.
  /usr/bin/python3 scripts/plot-benchmarks.py docs/benchmark-error-vs-time.csv docs/benchmark-error-vs-time.png
fi
# Stiff and extreme cases on every discretization: docs/stability-matrix.md.
# Two threads under each OpenMP wait policy, quiet and beside a busy core (docs/wait-policy.md).
/usr/bin/python3 scripts/benchmark-wait-policy.py --build "${build}"
"${build}/benchmarks/bmrStabilityBenchmark" --output docs/stability-matrix.md
# Image stages (fit, warp, B-spline baseline): their own section of docs/benchmarks.md.
"${build}/benchmarks/bmrImageBenchmark" --output docs/benchmarks.md
# Model building from an MRI (Colin27): docs/model-building-benchmark.md.
/usr/bin/python3 scripts/benchmark-model-building.py "${build}/apps/biomech"
# The whole registration, end to end, with its error: docs/registration-benchmark.md.
/usr/bin/python3 scripts/benchmark-registration.py
# Surgical simulation on the generic brain (haptic rate): its section of docs/benchmarks.md.
cmake --build "${build}" --target _bmr
PYTHONPATH="${build}/python" /usr/bin/python3 scripts/benchmark-simulation.py
# The intraoperative phase on prepared bundles (prepare, then update), with its error: its section of docs/benchmarks.md.
/usr/bin/python3 scripts/benchmark-update.py --build "${build}"
# The same bundles' solves by part, their memory roofline and 1 thread against 2 (issue 62): its section of docs/benchmarks.md.
/usr/bin/python3 scripts/benchmark-solve-parts.py --build "${build}"
# Each grid's dynamic-relaxation steps on the tests' real brains (issue 62 item 3): its section of docs/benchmarks.md.
/usr/bin/python3 scripts/benchmark-real-brain-steps.py --build "${build}"
# The uncertainty map's ensemble against one update (issue 63): its section of docs/benchmarks.md.
/usr/bin/python3 scripts/benchmark-uncertainty.py --build "${build}"
# README's measured numbers, copied from the docs just written.
/usr/bin/python3 scripts/update-readme.py
echo "run-benchmarks: wrote docs/benchmarks.md, docs/wait-policy.md, docs/model-building-benchmark.md, docs/registration-benchmark.md and README.md's measured numbers"
