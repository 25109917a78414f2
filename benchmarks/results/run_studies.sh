#!/usr/bin/env bash
# Regenerate benchmarks/results/<study>/: run each study sweep, then arcsem-report into the study folder,
# and record command, date, machine and wall time in <study>/RUN.md. See README.md next to this file.
#
#   benchmarks/results/run_studies.sh                          # all three studies, quick preset, seed 0
#   SEEDS=0,1,2 LAUNCHER=joblib benchmarks/results/run_studies.sh reference_count
#   SUFFIX=_real EXTRA="dataset=transforms dataset.path=..." benchmarks/results/run_studies.sh grayscale_comparison
set -uo pipefail
cd "$(dirname "$0")/../.."
BIN=${BIN:-.venv/bin}
PRESET=${PRESET:-quick}
LAUNCHER=${LAUNCHER:-basic}        # basic (sequential) | joblib | submitit_local | submitit_slurm
SEEDS=${SEEDS:-0}
EXTRA=${EXTRA:-}                   # further overrides, e.g. "dataset=transforms dataset.path=/data/pollen"
SUFFIX=${SUFFIX:-}                 # e.g. _real: writes benchmarks/results/<study>_real/ (another dataset's study)
export ARCSEM_CACHE=${ARCSEM_CACHE:-$PWD/multirun/results/cache}   # fresh stage-1 cache for these runs
STUDIES=${*:-grayscale_comparison colorization_ablation reference_count}

for study in $STUDIES; do
  sweep=multirun/results/$study$SUFFIX-$PRESET
  out=benchmarks/results/$study$SUFFIX
  rm -rf "$sweep" "$out"
  cmd="$BIN/arcsem experiment=$study preset=$PRESET seed=$SEEDS hydra/launcher=$LAUNCHER hydra.sweep.dir=$sweep $EXTRA"
  echo "== $cmd"
  start=$(date +%s)
  $cmd; status=$?                 # an interrupted sweep still gets a report (missing jobs listed)
  wall=$(( $(date +%s) - start ))
  $BIN/arcsem-report "$sweep" --out "$out" || exit 1
  cat > "$out/RUN.md" <<EOT
# $study$SUFFIX ($PRESET preset)

- command: \`$cmd\` (exit status $status), then \`$BIN/arcsem-report $sweep --out $out\`
- date: $(date -u '+%Y-%m-%d %H:%M UTC'); wall time of the sweep: ${wall} s
- machine: $(uname -srm); $(nproc) cores; $(lscpu 2>/dev/null | sed -n 's/^Model name: *//p' | head -1);
  $(free -g 2>/dev/null | awk '/^Mem:/{print $2 " GiB RAM"}')
- software: git $(git rev-parse --short HEAD 2>/dev/null || echo unknown); $($BIN/python -c 'import torch, arcsem; print("torch", torch.__version__, "arcsem", arcsem.__version__)')
- stage-1 cache: $ARCSEM_CACHE

Tables: [$study.md]($study.md) ([CSV]($study.csv), [LaTeX]($study.tex)); page: [index.html](index.html).
EOT
done
