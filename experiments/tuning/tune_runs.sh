# Shared by the tuning scripts (sourced, not run): stage-1 runs of the quick preset, two at a time with one
# thread each (a 2-core machine), then one summary line per run from its metrics.json.
#
# The caller sets BIN, OUT, RUNS (an associative array: run name -> Hydra overrides) and optionally COMMON
# (overrides for every run), then calls `tune_runs`. ONLY="name1 name2" (environment) runs a subset.

# The quick preset's scene size and normal-consistency weight before 2026-11-22 (192 px, 0.05; now 288 px,
# 0.1): the tables measured with them pin them here, so that they do not follow the preset.
PRESET_192="dataset.width=192 dataset.height=128 train.width=192 train.losses.normal_consistency.weight=0.05"

tune_run() {
  $BIN/arcsem stage=gray threads=1 train.eval.video=false train.progress=false train.eval_every=500 \
    ${COMMON:-} ${RUNS[$1]} hydra.run.dir="$OUT/$1" > "$OUT/$1.log" 2>&1 || echo "run $1 failed: see $OUT/$1.log"
}

tune_runs() {
  mkdir -p "$OUT"
  local names=(${ONLY:-"${!RUNS[@]}"}) i n
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
