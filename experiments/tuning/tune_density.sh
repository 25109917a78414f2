#!/usr/bin/env bash
# Depth error against the number and size of the surfels (section "Depth error against resolution
# and surfel density" in benchmarks/results/README.md): 2DGS + ACT, quick preset otherwise, built-in
# scene, seed 0, two runs at a time with one thread each (a 2-core machine).
#
#   experiments/tuning/tune_density.sh [OUT_DIR]           # default multirun/tune_density
#   ONLY="grad1e-4" experiments/tuning/tune_density.sh      # a subset of the runs
set -uo pipefail
cd "$(dirname "$0")/../.."
BIN=${BIN:-.venv/bin}
OUT=${1:-multirun/tune_density}
B=backbone
declare -A RUNS=(
  [grad1e-4]="$B.densify_grad_threshold=1e-4"          # preset 2e-4 (official): more clones and splits
  [pd0.05]="$B.percent_dense=0.05"                     # preset 0.185: split (smaller surfels) above 0.05 x extent
)
source "experiments/tuning/tune_runs.sh"
COMMON=$PRESET_192  # measured at 192 px with normal consistency 0.05 (the preset then)
tune_runs
