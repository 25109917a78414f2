# Shared by the tuning scripts (sourced, not run): stage-1 runs of the quick preset, two at a time with one
# thread each (a 2-core machine), then one summary line per run from its metrics.json.
#
# The caller sets BIN, OUT, RUNS (an associative array: run name -> Hydra overrides) and optionally COMMON
# (overrides for every run), then calls `tune_runs`.

tune_run() {
  $BIN/arcsem stage=gray threads=1 train.eval.video=false train.progress=false train.eval_every=500 \
    ${COMMON:-} ${RUNS[$1]} hydra.run.dir="$OUT/$1" > "$OUT/$1.log" 2>&1 || echo "run $1 failed: see $OUT/$1.log"
}

tune_runs() {
  mkdir -p "$OUT"
  local names=("${!RUNS[@]}") i n
  for ((i = 0; i < ${#names[@]}; i += 2)); do
    tune_run "${names[i]}" &
    [[ -n "${names[i+1]:-}" ]] && tune_run "${names[i+1]}" &
    wait
  done
  for n in "${names[@]}"; do
    $BIN/python -c "import json, sys; s = json.load(open(sys.argv[1]))['stage1']; t = s['test']; \
print(f\"{sys.argv[2]:24s} held-out {t['psnr']:.2f} dB, mask {t['psnr_masked']:.2f} dB, SSIM {t['ssim']:.3f}, \
depth {s['depth']['test_mae_pct']:.2f} %, {s['num_primitives']} Gaussians\")" "$OUT/$n/metrics.json" "$n" 2>/dev/null \
      || echo "$n: no metrics"
  done
}
