#!/usr/bin/env bash
# The colour comparison of benchmarks/results/colour/README.md: stage 1 once per built-in colour scene (2DGS + ACT,
# quick, 192 px wide), then stage 2 (quick, 600 steps) from it with the default stage 2 and with pseudo-colours
# alone (+ablation=pseudo_only), at one, three and five references, seed 0. One job at a time (2 cores).
#   benchmarks/colour_runs.sh OUT_DIR [SCENES] [REFS]      e.g. benchmarks/colour_runs.sh /tmp/colour "synthetic diatom" "one five"
#   .venv/bin/python benchmarks/colour_table.py OUT_DIR/s2
set -euo pipefail
OUT=${1:?output folder}; SCENES=${2:-synthetic diatom}; REFS=${3:-one three five}
ARCSEM=${ARCSEM:-$(dirname "$0")/../.venv/bin/arcsem}
mkdir -p "$OUT/s2"
for ds in $SCENES; do
  [ -f "$OUT/s1_$ds/metrics.json" ] || "$ARCSEM" dataset=$ds backbone=gs2d act=paper train=quick stage=gray \
    train.width=192 mesh.enabled=false train.progress=false train.eval.video=false train.eval.lpips=false \
    hydra.run.dir="$OUT/s1_$ds" > "$OUT/s1_$ds.log" 2>&1
  for refs in $REFS; do
    for variant in default pseudo_only; do
      run="$OUT/s2/${ds}_${refs}_${variant}"
      [ -f "$run/metrics.json" ] && continue
      extra=(); [ "$variant" = pseudo_only ] && extra=(+ablation=pseudo_only)
      "$ARCSEM" dataset=$ds backbone=gs2d stage=color colorize=quick colorize.stage1="$OUT/s1_$ds" \
        colorize.references=$refs colorize.eval.video=false colorize.eval.lpips=false mesh.enabled=false \
        colorize.progress=false hydra.run.dir="$run" "${extra[@]}" > "$run.log" 2>&1
    done
  done
done
