#!/usr/bin/env bash
# Runs behind benchmarks/results/features/ (see README.md there): for each dataset and seed, the TCM/CCM
# ablation rows (full, w/o TCM, w/o CCM: one shared stage-1 model) with the default features, then the
# feature comparison (vgg16 / daisy / learned x 1, 3, 5 references; learned x 5 is the ablation's "full").
# One job at a time, one thread each (a shared 2-core machine); every job reuses the seed's stage-1 model.
#
# The ablation runs at the paper's five references and at one (REFS): with five, the references see
# all but about 0.1 % of the held-out specimen (benchmarks/results/features/README.md), so what TCM and
# CCM do outside the pseudo-colour coverage shows only with fewer references.
#
#   DATASETS="synthetic diatom" SEEDS="0 1 2" REFS="one five" PARTS="ablation comparison" benchmarks/results/run_features.sh
set -uo pipefail
cd "$(dirname "$0")/../.."
BIN=${BIN:-.venv/bin}
DATASETS=${DATASETS:-synthetic diatom}
SEEDS=${SEEDS:-0 1 2}
PARTS=${PARTS:-ablation comparison}
REFS=${REFS:-one five}
OUT=${OUT:-multirun/features}
export ARCSEM_CACHE=${ARCSEM_CACHE:-$PWD/multirun/features/cache}
THREADS=${THREADS:-1}
EXTRA=${EXTRA:-}                   # further overrides, e.g. "device=cuda" (benchmarks/results/run_features_gpu.sh)
COMMON="threads=$THREADS colorize.progress=false train.progress=false colorize.eval.video=false $EXTRA"

for part in $PARTS; do
  for ds in $DATASETS; do
    for seed in $SEEDS; do
      if [ "$part" = ablation ]; then
        for refs in $REFS; do
          sfx=$([ "$refs" = five ] && echo "" || echo "-$refs")
          cmd="$BIN/arcsem experiment=colorization_ablation dataset=$ds seed=$seed ablation=full,no_tcm,no_ccm colorize.references=$refs $COMMON hydra.sweep.dir=$OUT/ablation-$ds-s$seed$sfx"
          echo "== $(date -u '+%H:%M:%S') $cmd"
          $cmd
        done
        continue
      else
        cmd="$BIN/arcsem experiment=feature_comparison dataset=$ds seed=$seed colorize.features=vgg16,daisy colorize.references=one,three,five $COMMON hydra.sweep.dir=$OUT/comparison-$ds-s$seed"
        extra="$BIN/arcsem experiment=feature_comparison dataset=$ds seed=$seed colorize.features=learned colorize.references=one,three $COMMON hydra.sweep.dir=$OUT/comparison-learned-$ds-s$seed"
      fi
      echo "== $(date -u '+%H:%M:%S') $cmd"
      $cmd
      if [ "$part" = comparison ]; then echo "== $(date -u '+%H:%M:%S') $extra"; $extra; fi
    done
  done
done
