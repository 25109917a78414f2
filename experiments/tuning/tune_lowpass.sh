#!/usr/bin/env bash
# The low-pass-filter runs behind the quick preset's backbone.lowpass_sigma (table "Surfels inside the
# surface: the low-pass filter" in benchmarks/results/README.md): 2DGS + ACT, quick preset, built-in
# scene, seed 0, one stage-1 run per line, two at a time with one thread each (a 2-core machine).
# Every run sets its sigma explicitly, so the table does not depend on the preset's current value.
#
#   experiments/tuning/tune_lowpass.sh [OUT_DIR]        # default multirun/tune_lowpass
#   ONLY="sigma0.5 sigma0.354" experiments/tuning/tune_lowpass.sh    # a subset of the runs
#
# Each run writes OUT_DIR/<name>/metrics.json; `experiments/error_breakdown.py OUT_DIR/<name> --surfels`
# says where its surfels sit.
set -uo pipefail
cd "$(dirname "$0")/../.."
BIN=${BIN:-.venv/bin}
OUT=${1:-multirun/tune_lowpass}
B=backbone.lowpass_sigma
G=train.losses
declare -A RUNS=(
  [sigma0.707]="$B=0.7071067811865476"
  [sigma0.5]="$B=0.5"
  [sigma0.354]="$B=0.35355339059327373"
  [sigma0.289]="$B=0.28867513459481287"
  [sigma0.354_dist30]="$B=0.35355339059327373 $G.distortion.weight=30"
  [sigma0.5_dist30]="$B=0.5 $G.distortion.weight=30"
  [sigma0.354_nc0.1]="$B=0.35355339059327373 $G.normal_consistency.weight=0.1"
  [sigma0.354_nc0.2]="$B=0.35355339059327373 $G.normal_consistency.weight=0.2"
  [sigma0.354_nc0.2_from750]="$B=0.35355339059327373 $G.normal_consistency.weight=0.2 $G.normal_consistency.start_step=750"
  [sigma0.354_nc0.2_from1100]="$B=0.35355339059327373 $G.normal_consistency.weight=0.2 $G.normal_consistency.start_step=1100"
)
source "experiments/tuning/tune_runs.sh"
COMMON=$PRESET_192  # measured at 192 px with normal consistency 0.05 (the preset then)
tune_runs
