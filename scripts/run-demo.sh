#!/usr/bin/env bash
# Main job: a brain-shift model of a real brain. Builds the module, makes a
# patient-specific model of Colin27 (Debian's mricron-data: ch2.nii.gz, brain
# mask ch2bet.nii.gz) with `biomech model` (fuzzy c-means tissue classes,
# hexahedral grid, skull surface, fixed skull base, a superior craniotomy
# loaded by 61 sparse intraoperative displacements), solves it with
# `biomech solve`, and prints both reports. (The full registration demo with
# a warped image and its evaluation comes with the registration pipeline.)
#
#   bash scripts/run-demo.sh                     # the Colin27 demo into out/demo
#   bash scripts/run-demo.sh SCENE.json [DIR]    # solve any scene instead
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

bash scripts/install-dependencies.sh

# Idle OpenMP threads sleep instead of spinning: on a machine that is busy with
# other work, spinning threads turn every barrier into a lost time slice
# (measured: 2 s -> 99 s for a brain-sized scene). Override by setting it yourself.
export OMP_WAIT_POLICY="${OMP_WAIT_POLICY:-PASSIVE}"

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

templates=/usr/share/mricron/templates
output_dir=out/demo
echo
echo "== biomech model ${templates}/ch2.nii.gz (Colin27) -> ${output_dir}/scene.json"
"${biomech}" model "${templates}/ch2.nii.gz" --mask "${templates}/ch2bet.nii.gz" \
  --craniotomy-centre -11 43 84 --craniotomy-radius 30 \
  --sparse-displacements examples/data/colin27-superior-craniotomy.csv \
  --grid hexahedra --element-size 5 -o "${output_dir}"
echo
echo "== biomech solve ${output_dir}/scene.json"
"${biomech}" solve "${output_dir}/scene.json" --output-dir "${output_dir}"
