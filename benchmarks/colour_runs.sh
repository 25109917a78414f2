#!/usr/bin/env bash
# The colour comparison of benchmarks/results/colour/README.md: stage 1 once per colour scene (2DGS + ACT, quick,
# 192 px wide), then stage 2 (quick, 600 steps) from it with each variant, at the given reference counts and seeds.
# One job at a time (2 cores).
#   benchmarks/colour_runs.sh OUT_DIR [SCENES] [REFS] [VARIANTS] [SEEDS]
#   e.g. benchmarks/colour_runs.sh /tmp/colour "synthetic diatom" "one five" "default pseudo_only no_ccm" "0 1 2"
#   .venv/bin/python benchmarks/colour_table.py OUT_DIR/s2
# Variants (stage-2 overrides on top of the default):
#   default      this commit's stage 2            pseudo_only  +ablation=pseudo_only (the paper's pseudo-colours)
#   no_tcm / no_ccm                               TCM / CCM weight 0 (validation still chooses the rest)
#   no_shading / no_surface / no_validate / no_guard / no_prior   one addition off
#   everywhere   TCM/CCM also inside the pseudo-colour coverage (colorize.guard.uncovered_only=false)
#   no_check     TCM/CCM kept at one reference whatever the match check says (colorize.guard.check=false)
# Run folders: OUT_DIR/s2/<scene>_<refs>_<variant>[_s<seed>] (seed 0 has no suffix, as in earlier tables).
# EXTRA="threads=1 ..." adds overrides to every stage-2 job (two lanes of one thread each on two cores: give the
# lanes disjoint scenes, seeds or variants).
set -euo pipefail
OUT=${1:?output folder}; SCENES=${2:-synthetic diatom}; REFS=${3:-one three five}
VARIANTS=${4:-default pseudo_only}; SEEDS=${5:-0}; EXTRA=${EXTRA:-}
ARCSEM=${ARCSEM:-$(dirname "$0")/../.venv/bin/arcsem}
overrides() {
  case $1 in
    default) ;;
    pseudo_only) echo "+ablation=pseudo_only" ;;
    no_tcm) echo "colorize.losses.tcm.weight=0.0" ;;
    no_ccm) echo "colorize.losses.ccm.weight=0.0" ;;
    no_shading) echo "colorize.shading=off" ;;
    no_surface) echo "colorize.surface.mode=off" ;;
    no_validate) echo "colorize.validate=off" ;;
    no_guard) echo "colorize.guard.enabled=false" ;;
    no_prior) echo "colorize.prior=off" ;;
    everywhere) echo "colorize.guard.uncovered_only=false" ;;
    no_check) echo "colorize.guard.check=false" ;;
    *) echo "error: unknown variant $1" >&2; exit 2 ;;
  esac
}
mkdir -p "$OUT/s2"
for ds in $SCENES; do
  [ -f "$OUT/s1_$ds/metrics.json" ] || "$ARCSEM" dataset=$ds backbone=gs2d act=paper train=quick stage=gray \
    train.width=192 mesh.enabled=false train.progress=false train.eval.video=false train.eval.lpips=false \
    hydra.run.dir="$OUT/s1_$ds" > "$OUT/s1_$ds.log" 2>&1
  for seed in $SEEDS; do
    for refs in $REFS; do
      for variant in $VARIANTS; do
        suffix=""; [ "$seed" = 0 ] || suffix="_s$seed"
        run="$OUT/s2/${ds}_${refs}_${variant}${suffix}"
        [ -f "$run/metrics.json" ] && continue
        extra=$(overrides "$variant")
        # shellcheck disable=SC2086
        "$ARCSEM" dataset=$ds backbone=gs2d stage=color colorize=quick colorize.stage1="$OUT/s1_$ds" seed=$seed \
          colorize.references=$refs colorize.eval.video=false colorize.eval.lpips=false mesh.enabled=false \
          colorize.progress=false hydra.run.dir="$run" $extra $EXTRA > "$run.log" 2>&1
      done
    done
  done
done
