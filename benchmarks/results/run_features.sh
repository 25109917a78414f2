#!/usr/bin/env bash
# Runs behind benchmarks/results/features/ (see README.md there): for each dataset and seed, the TCM/CCM
# ablation rows (full, w/o TCM, w/o CCM: one shared stage-1 model) with the default features, then the
# feature comparison (FEATURES x 1, 3, 5 references, one sweep; default vgg16, daisy and learned).
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
FEATURES=${FEATURES:-vgg16,daisy,learned}   # the comparison's extractors (vgg16: random weights without a download)
CREFS=${CREFS:-one,three,five}     # the comparison's reference counts
ABLATIONS=${ABLATIONS:-full,no_tcm,no_ccm}  # the ablation's rows
EXTRA=${EXTRA:-}                   # further overrides, e.g. "device=cuda" (benchmarks/results/run_features_gpu.sh)
COMMON="threads=$THREADS colorize.progress=false train.progress=false colorize.eval.video=false $EXTRA"

for part in $PARTS; do
  for ds in $DATASETS; do
    for seed in $SEEDS; do
      if [ "$part" = ablation ]; then
        for refs in $REFS; do
          sfx=$([ "$refs" = five ] && echo "" || echo "-$refs")
          cmd="$BIN/arcsem experiment=colorization_ablation dataset=$ds seed=$seed ablation=$ABLATIONS colorize.references=$refs $COMMON hydra.sweep.dir=$OUT/ablation-$ds-s$seed$sfx"
          echo "== $(date -u '+%H:%M:%S') $cmd"
          $cmd
        done
        continue
      fi
      cmd="$BIN/arcsem experiment=feature_comparison dataset=$ds seed=$seed colorize.features=$FEATURES colorize.references=$CREFS $COMMON hydra.sweep.dir=$OUT/comparison-$ds-s$seed"
      echo "== $(date -u '+%H:%M:%S') $cmd"
      $cmd
    done
  done
done
