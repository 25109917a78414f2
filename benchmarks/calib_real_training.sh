#!/usr/bin/env bash
# Issue 39's real-series line: a public real tilt series calibrated with the defaults (dense start on) against the
# same series with --features 12000 and no dense start, each trained (2DGS + ACT, quick) with the middle view held
# out; prints the held-out PSNR/SSIM of both. One job at a time (2 cores).
#   benchmarks/calib_real_training.sh OUT_DIR SERIES_DIR [SERIES_DIR ...]
#   e.g. git clone https://github.com/Karido/3D-SEM /tmp/3D-SEM
#        benchmarks/calib_real_training.sh /tmp/real /tmp/3D-SEM/res/dsa /tmp/3D-SEM/res/quarz
# Held out: the file matching *_02.* (the middle one of the 3-view series); HOLDOUT=<glob> for others.
# CALIB_ARGS: more arcsem-calibrate options for both variants, e.g. "--init factorization" for files without stage
# angles (Karido's series: its README says the angles are unknown, 5-10 degrees apart).
set -euo pipefail
OUT=${1:?output folder}; shift
BIN=${BIN:-$(dirname "$0")/../.venv/bin}
mkdir -p "$OUT"
for series in "$@"; do
  name=$(basename "$series")
  for variant in default features12000; do
    ds="$OUT/${name}_$variant"
    # shellcheck disable=SC2206
    extra=(${CALIB_ARGS:-}); [ "$variant" = features12000 ] && extra+=(--features 12000 --dense-features 0)
    [ -f "$ds/transforms.json" ] || "$BIN/arcsem-calibrate" "$series" --out "$ds" --holdout "${HOLDOUT:-*_02.*}" \
      "${extra[@]}" > "$ds.calib.log" 2>&1
    run="$OUT/${name}_${variant}_train"
    [ -f "$run/metrics.json" ] || "$BIN/arcsem" dataset=transforms dataset.path="$ds" backbone=gs2d act=paper \
      train=quick stage=gray mesh.enabled=false train.progress=false train.eval.video=false hydra.run.dir="$run" \
      > "$run.log" 2>&1
    "$BIN/python" - "$run" "$ds" <<'PY'
import json, sys
m = json.load(open(sys.argv[1] + "/metrics.json"))
t = m["stages"]["gray"]["stage1"]
print(f"{sys.argv[1]}: held-out PSNR {t['test']['psnr']:.2f} dB, SSIM {t['test']['ssim']:.3f}; "
      f"train PSNR {t['train']['psnr']:.2f}")
PY
  done
done
