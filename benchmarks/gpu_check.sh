#!/usr/bin/env bash
# The GPU checks of issue 21 on a machine with CUDA and its own PyTorch (no network there): install the
# wheels arcsem needs beside that PyTorch (downloaded beforehand into .whl/ on a machine with network, see
# below), arcsem itself, run the CUDA-marked tests and time the demo with device=cuda. Writes into ${OUT:-/tmp/gpu_check}.
#
#   # on a machine with network, from the repository root (cp312 wheels for the GPU machine's Python 3.12):
#   pip download --no-deps --only-binary=:all: --python-version 3.12 --platform manylinux_2_28_x86_64 -d .whl \
#     hydra-core==1.3.8 omegaconf==2.3.1 hydra-joblib-launcher==1.2.0 lpips==0.1.4 pycolmap==4.2.1 trimesh==5.2.0 plyfile==1.1.5
#   pip wheel --no-deps -w .whl antlr4-python3-runtime==4.9.3
#   # on the GPU machine, from the repository root:
#   benchmarks/gpu_check.sh
set -uo pipefail
OUT=${OUT:-/tmp/gpu_check}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1 TQDM_DISABLE=1
python3 -m pip install -q --no-deps --no-index .whl/*.whl
python3 -m pip install -q --no-deps --no-build-isolation -e .
python3 -c "import torch; print('torch', torch.__version__, torch.cuda.get_device_name())"
python3 -m pytest -v -m cuda tests/test_cuda.py -p no:cacheprovider -o addopts="" 2>&1 | tee "$OUT/cuda_tests.log"
/usr/bin/time -v arcsem experiment=demo device=cuda hydra.run.dir="$OUT/demo" > "$OUT/demo_stdout.log" 2> "$OUT/demo_stderr.log"
echo "demo exit status $?"
grep -E "Elapsed|Maximum resident" "$OUT/demo_stderr.log"
python3 - "$OUT/demo/metrics.json" <<'PY'
import json, sys
m = json.load(open(sys.argv[1]))
print("timings s:", {k: round(v, 1) for k, v in m["timings"].items()})
print("stage 1 held-out PSNR %.2f SSIM %.3f; %.1f steps/s" % (m["stage1"]["test"]["psnr"], m["stage1"]["test"]["ssim"], m["stage1"]["steps_per_s"]))
print("stage 2 held-out PSNR %.2f SSIM %.3f" % (m["stage2"]["test"]["psnr"], m["stage2"]["test"]["ssim"]))
PY
