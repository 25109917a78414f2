#!/usr/bin/env bash
# The geometry-regulariser runs behind the quick preset's distortion and normal-consistency settings
# (table "Geometry regularisers" in benchmarks/results/README.md): 2DGS + ACT, quick preset, built-in
# scene, seed 0, one stage-1 run per line, two at a time with one thread each (a 2-core machine).
#
#   experiments/tuning/tune_geometry.sh [OUT_DIR]        # default multirun/tune_geometry
#
# Each run writes OUT_DIR/<name>/metrics.json (stage1.test.psnr, stage1.depth.test_mae_pct, ...).
set -uo pipefail
cd "$(dirname "$0")/../.."
BIN=${BIN:-.venv/bin}
OUT=${1:-multirun/tune_geometry}
G=train.losses
NORMALISED="$G.normal_consistency.official=false $G.normal_consistency.depth=expected"
declare -A RUNS=(
  [none]="$G.distortion.weight=0 $NORMALISED"
  [dist10]="$G.distortion.weight=10 $NORMALISED"
  [dist30]="$G.distortion.weight=30 $NORMALISED"
  [dist100]="$G.distortion.weight=100 $NORMALISED"
  [dist100_from750]="$G.distortion.weight=100 $G.distortion.start_step=750 $NORMALISED"
  [dist1000]="$G.distortion.weight=1000 $NORMALISED"
  [dist10_nc0.2]="$G.distortion.weight=10 $G.normal_consistency.weight=0.2 $NORMALISED"
  [dist10_official]="$G.distortion.weight=10 $G.normal_consistency.official=true $G.normal_consistency.depth=expected"
  [dist10_official_median]="$G.distortion.weight=10 $G.normal_consistency.official=true $G.normal_consistency.depth=median"
)
source "experiments/tuning/tune_runs.sh"
# measured before the preset's low-pass filter, size and normal consistency changed: pinned explicitly
COMMON="$PRESET_192 backbone.lowpass_sigma=0.7071067811865476"
tune_runs
