#!/usr/bin/env bash
# Main job: brain-shift registration of a real brain against a known answer.
# Builds the module, then `biomech demo` on Colin27 (Debian's mricron-data:
# ch2.nii.gz, brain mask ch2bet.nii.gz):
#   1. ground truth: a 30 mm superior craniotomy whose exposed surface sinks
#      10 mm, gravity on the rest of the brain, skull contact, solved with a
#      finer (4 mm) model; an intraoperative image made from it (0.86 x 0.86 x
#      2.5 mm, noise);
#   2. biomechanical registration from the displaced exposed surface only;
#   3. B-spline intensity registration on the same pair;
#   4. a table (time, displacement error against the ground truth, edge-based
#      Hausdorff) and, in out/demo: warped images, transforms (.h5), edge
#      overlays, demo-report.json and error-vs-time.png;
#   5. the same registration in the clinical workflow's two phases: `biomech
#      prepare` (the model bundle, out/demo/plan) and `biomech update` from
#      the displaced surface (out/demo/update), each with its time.
#
#   bash scripts/run-demo.sh                     # the Colin27 demo into out/demo
#   bash scripts/run-demo.sh SCENE.json [DIR]    # solve any scene instead
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

bash scripts/install-dependencies.sh

# Idle OpenMP threads spin briefly, then sleep (libgomp's GOMP_SPINCOUNT): on a
# quiet machine as fast as spinning, beside other work within a few per cent of
# sleeping at once, where libgomp's default long spin turned a 2 s brain-sized
# solve into 32-99 s (docs/wait-policy.md). Override by setting it yourself.
export GOMP_SPINCOUNT="${GOMP_SPINCOUNT:-1000}"

build_dir=build
jobs="$(nproc 2>/dev/null || echo 2)"

cmake -S . -B "${build_dir}" -DCMAKE_BUILD_TYPE=Release
cmake --build "${build_dir}" -j "${jobs}" --target biomech
biomech="${build_dir}/apps/biomech"

if [ "$#" -ge 1 ]; then
  output_dir="${2:-out/demo}"
  mkdir -p "${output_dir}"
  echo
  echo "== biomech solve $1 --output-dir ${output_dir}"
  "${biomech}" solve "$1" --output-dir "${output_dir}"
  exit
fi

output_dir=out/demo
echo
echo "== biomech demo -o ${output_dir} (Colin27 from mricron-data)"
"${biomech}" demo -o "${output_dir}" --load surface --variant hexahedra:5 --variant mixed:5 \
  --registration-gravity 1 --gravity-fit-candidates 5 --elastix
/usr/bin/python3 scripts/plot-demo.py "${output_dir}/demo-report.json" "${output_dir}/error-vs-time.png"

# The clinical workflow on the same scene: the model prepared before surgery
# (a bundle), then updated in seconds when the exposed surface is scanned.
echo
echo "== biomech prepare: before surgery (Colin27, 5 mm hexahedra) -> ${output_dir}/plan"
"${biomech}" prepare /usr/share/mricron/templates/ch2.nii.gz --mask /usr/share/mricron/templates/ch2bet.nii.gz \
  --craniotomy-centre -11 43 84 --craniotomy-radius 30 -o "${output_dir}/plan"
echo
echo "== biomech update: during surgery, from the displaced exposed surface -> ${output_dir}/update"
"${biomech}" update "${output_dir}/plan" --intraoperative-surface "${output_dir}/exposed-surface.vtp" \
  --intraoperative-image "${output_dir}/intraoperative.nii.gz" -o "${output_dir}/update"
