#!/usr/bin/env bash
# Every GPU check in one call, on a bare CUDA machine with its own PyTorch and no network (docs/gpu.md):
#   setup    install the carried wheels (.whl/), arcsem itself, gsplat's CUDA library (.gpu/gsplat_csrc.so when
#            carried, else built once, ~minutes, and left in $OUT for the next machine) and the built-in scene
#            (.gpu/scene.tar.xz, made on the CPU machine: the scene generator needs pycolmap, 38 MB)
#   quality  the demo job at more seeds (QUALITY_SEEDS, default 1 2; QUALITY_RASTERIZERS, default auto), run beside
#            the tests, for the held-out grey and colour PSNR against the CPU's (not timed: they share the GPU)
#   demoprobe  stage 1 of the demo on gsplat with every gradient at gsplat watched (nan_probe.py --demo), beside the
#            tests
#   probe    where a non-finite value first appears, if the gsplat 2DGS run of the tests failed (nan_probe.py)
#   launch   gsplat's 2DGS backward at 8/16/32-px tiles and its kernels' register counts
#   tests    pytest -m cuda (with the Triton kernels, the rasteriser's and the losses', against the PyTorch paths)
#   profile  stage 1 of the demo: steps/s, SM utilisation, host syncs, kernels (benchmarks/gpu/stage1_profile.py;
#            PROFILE_VARIANTS, default gs2d gs2d_gsplat (gs2d: auto, the Triton kernels on CUDA); gs2d_torch,
#            gs2d_triton, gs3d, gs3d_gsplat, gs2d_torchloss (auto with the PyTorch D-SSIM and normal consistency)
#            when named)
#   demo     the whole `make demo` job with device=cuda, each of DEMO_RASTERIZERS (default auto gsplat),
#            nvidia-smi dmon sampling; DEMO_PYSPY=1: under py-spy (carried wheel; --nonblocking, 50 Hz), its host time
#            by function into $OUT/demo_<r>.host.md (benchmarks/host_profile.py) and the raw profile (gzip)
#   float32  (only when named) float32 gradients of the PyTorch and Triton paths against float64 on the auto demo's
#            stage-1 model (benchmarks/gpu/triton_float32.py; after `demo`) into $OUT/float32.txt
#   stage2ab (only when named) stage 2 of the demo twice on the auto demo's stage 1 (S2AB_STAGE1, default
#            /tmp/demo_auto): through recorded renders (colorize.frozen_mb default) and compositing every step
#            (frozen_mb=0); their times and held-out colour into $OUT/stage2ab.txt (S2AB_DEVICE, default cuda)
# then writes $OUT/gpu_check.json (device, cuda_tests_failed, stage1_steps_per_s, sm_util_pct, stage2_complete,
# demo_wall_s, quality, ...) and $OUT/runs.tar.gz (every demo job's time-stamped log and metrics.json).
# Parts: GPU_CHECK_PARTS (default all). GSPLAT=0: no gsplat (its wheel not installed, its library not built, its tests
# deselected, its profile and demo dropped), for a call whose device time is too short for gsplat's ~90 s build.
# The default call takes about 8 minutes with that build (2026-11-28, H200: setup 50 s + the build, the quality runs
# beside the tests ~100 s, two profiles ~80 s, the auto and gsplat demos 75 + 95 s).
#
#   # on the CPU machine, from the repository root (cp312 wheels for the GPU machine's Python 3.12):
#   benchmarks/gpu/prepare.sh          # .whl/ and .gpu/scene.tar.xz (both git-ignored; 46 MB together)
#   # on the GPU machine, from the repository root:
#   benchmarks/gpu_check.sh            # results in ${OUT:-/tmp/gpu_check}
set -uo pipefail
OUT=${OUT:-/tmp/gpu_check}
PARTS=${GPU_CHECK_PARTS:-setup,quality,tests,probe,profile,demo,launch}  # demoprobe, stage2ab, float32: when named
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1 TQDM_DISABLE=1 ARCSEM_CACHE=/tmp/arcsem_cache PYTHONWARNINGS=ignore::DeprecationWarning
has() { [[ ",$PARTS," == *",$1,"* ]]; }
T0=$(date +%s)
stamp() { echo "== $1 ($(( $(date +%s) - T0 )) s)"; }
BG=()  # jobs run beside the tests (quality, demoprobe)
nogsplat() { for w in "$@"; do [[ "${GSPLAT:-1}" = 0 && "$w" == *gsplat* ]] || echo "$w"; done; }  # GSPLAT=0: drop
# demo NAME RASTERIZER SEED [OVERRIDE ...]: one demo job in /tmp/NAME, its output time-stamped in /tmp/NAME.log,
# its exit status in /tmp/NAME.rc and its wall seconds in /tmp/NAME.wall; a colour cache of its own (no job reuses
# another's pseudo-colours or matches)
demo() {
  local name=$1 r=$2 seed=$3 s spy=(); shift 3
  if [ "${DEMO_PYSPY:-0}" = 1 ] && [ -f /tmp/pyspy_ok ]; then  # the job's own exit status through exit_code.py
    spy=(py-spy record --subprocesses --nonblocking -r 50 -f raw -o "/tmp/$name.pyspy" -- python3 benchmarks/gpu/exit_code.py)
  fi
  rm -f "/tmp/$name.rc_job" "/tmp/$name.pyspy"
  s=$(date +%s.%N)
  env -u TQDM_DISABLE TQDM_MININTERVAL=5 EXIT_CODE_FILE="/tmp/$name.rc_job" ${spy[@]+"${spy[@]}"} timeout "${DEMO_TIMEOUT:-300}" arcsem experiment=demo device=cuda backbone.rasterizer="$r" seed="$seed" "$@" \
    colorize.cache_dir="/tmp/$name.cc" hydra.run.dir="/tmp/$name" 2>&1 | python3 benchmarks/gpu/summary.py --stamp > "/tmp/$name.log"
  echo "${PIPESTATUS[0]}" > "/tmp/$name.rc"
  if [ -s "/tmp/$name.rc_job" ]; then cp "/tmp/$name.rc_job" "/tmp/$name.rc"; fi
  python3 -c "print(round($(date +%s.%N) - $s, 1))" > "/tmp/$name.wall"
  if [ -s "/tmp/$name.pyspy" ]; then
    python3 benchmarks/host_profile.py "/tmp/$name.pyspy" --top 60 > "$OUT/$name.host.md" 2>&1
    gzip -c "/tmp/$name.pyspy" > "$OUT/$name.pyspy.gz"
  fi
}

if has setup; then
  stamp setup
  if [ "${GSPLAT:-1}" = 0 ]; then WHEELS=$(ls .whl/*.whl | grep -v /gsplat-); else WHEELS=$(ls .whl/*.whl); fi
  # shellcheck disable=SC2086
  python3 -m pip install -q --no-index --no-deps --no-compile $WHEELS 2>&1 | grep -v -i warning
  python3 -m pip install -q --no-index --no-deps --no-build-isolation -e . 2>&1 | grep -v -i warning
  mkdir -p "$ARCSEM_CACHE" && tar -xJf .gpu/scene.tar.xz -C "$ARCSEM_CACHE"
  python3 -m arcsem.mesh.fused  # the CPU-side TSDF kernel every job's mesh uses, built once here, not inside a timed job
  if [ "${GSPLAT:-1}" = 0 ]; then
    echo "GSPLAT=0: no gsplat"
  elif [ -f .gpu/gsplat_csrc.so ]; then
    python3 benchmarks/gpu/gsplat_build.py --install .gpu/gsplat_csrc.so
  else
    python3 benchmarks/gpu/gsplat_build.py --out "$OUT/gsplat_csrc.so"
  fi
  python3 -c "import torch; print('torch', torch.__version__, 'CUDA', torch.version.cuda, torch.cuda.get_device_name())"
  python3 -c "import gsplat; print('gsplat', gsplat.__version__)" || echo "no gsplat: rasterizer=gsplat cannot run here"
  python3 -c "import triton; print('triton', triton.__version__, '(rasterizer=triton)')" || echo "no triton: rasterizer=triton cannot run here"
  python3 -c "import imageio_ffmpeg as f; print('ffmpeg', f.get_ffmpeg_version(), '(MP4 orbits)')" || echo "no ffmpeg: the orbits are GIFs"
  if command -v py-spy > /dev/null && py-spy record --nonblocking -d 2 -f raw -o /tmp/pyspy_probe -- \
      python3 -c "sum(i * i for i in range(5 * 10**6))" > /dev/null 2>&1 && [ -s /tmp/pyspy_probe ]; then
    touch /tmp/pyspy_ok; echo "py-spy: samples here (DEMO_PYSPY=1 profiles the demos' host side)"
  else echo "py-spy: cannot sample here"; fi
  python3 -c "import torch; print(torch.cuda.get_device_name())" > "$OUT/device.txt"
fi

if has quality; then
  stamp "quality: seeds ${QUALITY_SEEDS:-1 2}, started beside the tests"
  nvidia-smi dmon -s u -d 1 -o T > /tmp/dmon_quality.txt 2>&1 & QDMON=$!
  for seed in ${QUALITY_SEEDS:-1 2}; do
    for r in ${QUALITY_RASTERIZERS:-auto}; do
      demo "q_${r}_s$seed" "$r" "$seed" threads=4 & BG+=($!)
    done
  done
fi

if has demoprobe; then
  stamp "demo probe (beside the tests)"
  (timeout "${DEMO_TIMEOUT:-300}" python3 benchmarks/gpu/nan_probe.py --demo threads=4 > "$OUT/demo_probe.log" 2>&1) &
  BG+=($!)
fi

if has tests; then
  stamp tests
  if [ "${GSPLAT:-1}" = 0 ]; then SEL=(tests/test_cuda.py tests/test_triton2d.py tests/test_triton_losses.py -k "not gsplat")
  else SEL=(tests/test_cuda.py tests/test_gsplat_bridge.py tests/test_triton2d.py tests/test_triton_losses.py); fi
  timeout "${TESTS_TIMEOUT:-420}" python3 -m pytest -q -m cuda "${SEL[@]}" -p no:cacheprovider \
    -o addopts="" -W ignore::DeprecationWarning 2>&1 | tee "$OUT/cuda_tests.log" | tail -25
fi

if [ ${#BG[@]} -gt 0 ]; then
  wait "${BG[@]}"
  stamp "background jobs done"
  tail -15 "$OUT/demo_probe.log" 2>/dev/null
fi

if has quality; then
  kill $QDMON 2>/dev/null
  for seed in ${QUALITY_SEEDS:-1 2}; do
    for r in ${QUALITY_RASTERIZERS:-auto}; do
      n="q_${r}_s$seed"
      echo "quality $n: exit $(cat /tmp/$n.rc) in $(cat /tmp/$n.wall) s"
      python3 benchmarks/gpu/summary.py --demo "/tmp/$n" "$r" "$seed" "$(cat /tmp/$n.rc)" "$(cat /tmp/$n.wall)" \
        /tmp/dmon_quality.txt "$OUT/quality_metrics.json" > /dev/null
    done
  done
  python3 benchmarks/gpu/summary.py --check "$OUT" > /dev/null
fi

if has probe && grep -q "FAILED tests/test_cuda.py::test_stages_end_to_end_on_cuda\[gs2d-gsplat" "$OUT/cuda_tests.log" 2>/dev/null; then
  stamp probe
  timeout 120 python3 benchmarks/gpu/nan_probe.py 2>&1 | tee "$OUT/nan_probe.log" | tail -40
fi

if has profile; then
  stamp profile
  declare -A VARIANT=([gs2d]="backbone.rasterizer=auto" [gs2d_gsplat]="backbone.rasterizer=gsplat"
    [gs2d_triton]="backbone.rasterizer=triton" [gs2d_torch]="backbone.rasterizer=torch"
    [gs3d]="backbone=gs3d backbone.rasterizer=auto" [gs3d_gsplat]="backbone=gs3d backbone.rasterizer=gsplat"
    [gs2d_torchloss]="backbone.rasterizer=auto +train.losses.dssim.impl=torch +train.losses.normal_consistency.impl=torch")
  for name in $(nogsplat ${PROFILE_VARIANTS:-gs2d gs2d_gsplat}); do
    ov=${VARIANT[$name]}
    echo "=== $name" >> "$OUT/profile.log"
    # shellcheck disable=SC2086
    timeout 150 python3 benchmarks/gpu/stage1_profile.py --name "$name" --steps "${PROFILE_STEPS:-300}" \
      --json "$OUT/gpu_profile.json" -- $ov >> "$OUT/profile.log" 2>&1 || echo "profile $name failed (exit $?)"
    python3 benchmarks/gpu/summary.py --profile "$OUT/gpu_profile.json" "$name"
  done
fi

if has demo; then
  stamp demo
  for r in $(nogsplat ${DEMO_RASTERIZERS:-auto gsplat}); do
    nvidia-smi dmon -s u -d 1 -o T > "/tmp/dmon_$r.txt" 2>&1 & DMON=$!
    demo "demo_$r" "$r" 0
    kill $DMON 2>/dev/null
    echo "demo $r: exit $(cat /tmp/demo_$r.rc) in $(cat /tmp/demo_$r.wall) s"
    { echo "=== demo $r: exit $(cat /tmp/demo_$r.rc), $(cat /tmp/demo_$r.wall) s"; tail -40 "/tmp/demo_$r.log"
      echo "--- dmon"; cat "/tmp/dmon_$r.txt"; } >> "$OUT/demo.log"
    python3 benchmarks/gpu/summary.py --demo "/tmp/demo_$r" "$r" 0 "$(cat /tmp/demo_$r.rc)" "$(cat /tmp/demo_$r.wall)" \
      "/tmp/dmon_$r.txt" "$OUT/demo_metrics.json"
    python3 benchmarks/gpu/summary.py --check "$OUT" > /dev/null
  done
fi

if has stage2ab; then
  stamp "stage 2: recorded renders against compositing"
  for mb in 2048 0; do
    timeout 300 arcsem experiment=demo device="${S2AB_DEVICE:-cuda}" stage=color colorize.stage1="${S2AB_STAGE1:-/tmp/demo_auto}" \
      colorize.frozen_mb=$mb colorize.progress=false colorize.eval.video=false mesh.enabled=false report=false \
      colorize.cache_dir="/tmp/s2ab_$mb.cc" hydra.run.dir="/tmp/s2ab_$mb" > "/tmp/s2ab_$mb.log" 2>&1
    python3 -c "import json; s = json.load(open('/tmp/s2ab_$mb/metrics.json'))['stage2']
print('frozen_mb=$mb: training', round(s['time_s'], 1), 's,', round(s['steps_per_s'], 1), 'steps/s, held-out colour',
      round(s['test']['psnr'], 4), 'dB, records', s.get('frozen_renders'))" 2>&1 | tee -a "$OUT/stage2ab.txt"
  done
fi

if has float32; then
  stamp "float32 against float64"
  timeout 120 python3 benchmarks/gpu/triton_float32.py --run "${S2AB_STAGE1:-/tmp/demo_auto}" --device cuda 2>&1 \
    | grep -v -i warn | tee "$OUT/float32.txt"
fi

if has launch; then
  stamp launch
  timeout 120 python3 benchmarks/gpu/gsplat_launch.py 2>&1 | tail -30
fi

stamp summary
(cd /tmp && tar -czf "$OUT/runs.tar.gz" --ignore-failed-read ./q_*.log ./demo_*.log ./q_*/metrics.json ./demo_*/metrics.json 2>/dev/null)
python3 benchmarks/gpu/summary.py --check "$OUT"
