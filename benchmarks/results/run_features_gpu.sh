#!/usr/bin/env bash
# The colourisation ablation of benchmarks/results/features/ (full, w/o TCM, w/o CCM at one reference; three
# seeds; the grain and the diatom) on a GPU machine: every (dataset, seed) sweep of run_features.sh runs as its
# own process with device=cuda, all at once, then arcsem-report pools each dataset's three seeds (paired
# notes). Set up as benchmarks/gpu_check.sh says (carried wheels, `pip install -e .`). Results: $OUT/report-*.
#
#   OUT=/tmp/features_gpu benchmarks/results/run_features_gpu.sh
#   DATASETS=synthetic THREADS=1 JOBS_EXTRA="hydra/launcher=joblib hydra.launcher.n_jobs=3" ...   # variants at once too
set -uo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-/tmp/features_gpu}
SEEDS=${SEEDS:-0 1 2}
DATASETS=${DATASETS:-synthetic diatom}
BIN=$(dirname "$(command -v arcsem)")
export ARCSEM_CACHE=$OUT/cache PYTHONUNBUFFERED=1 TQDM_DISABLE=1
mkdir -p "$OUT"
for ds in $DATASETS; do  # render each scene once before the jobs share it
  "$BIN/arcsem" stage=check dataset=$ds hydra.run.dir="$OUT/check-$ds" > "$OUT/check-$ds.log" 2>&1 &
done
wait
for ds in $DATASETS; do
  for seed in $SEEDS; do
    BIN=$BIN OUT=$OUT PARTS=ablation REFS=one DATASETS=$ds SEEDS=$seed THREADS=${THREADS:-2} EXTRA="device=cuda ${JOBS_EXTRA:-}" \
      benchmarks/results/run_features.sh > "$OUT/ablation-$ds-s$seed.log" 2>&1 &
  done
done
wait
for ds in $DATASETS; do
  runs=$(for seed in $SEEDS; do echo "$OUT/ablation-$ds-s$seed-one"; done)
  "$BIN/arcsem-report" $runs --out "$OUT/report-$ds-one"
done
