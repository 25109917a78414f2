#!/usr/bin/env bash
# Issue 39: the README's three "Your own SEM images" commands, run as written, on a raw series as a Zeiss microscope
# writes it: five LZW-compressed TIFF scans (200x140, 8-bit) with tag 34118 holding the stage tilt and the pixel size
# (the layout of tests/test_sem_raw_series.py), rendered from the built-in textured grain on one tilt arc. Everything
# goes under OUT_DIR (the raw folder, the calibrated dataset, the study's multirun folder). After `make setup`.
#   benchmarks/readme_sem_commands.sh OUT_DIR
set -euo pipefail
OUT=${1:?output folder}; ROOT=$(cd "$(dirname "$0")/.." && pwd)
export PATH="$ROOT/.venv/bin:$PATH"
mkdir -p "$OUT"; cd "$OUT"
[ -d raw ] || python - "$ROOT" <<'PY'
import sys
from pathlib import Path

sys.path[:0] = [sys.argv[1], sys.argv[1] + "/tests"]
import numpy as np
import tifffile
from test_sem_raw_series import ELEVATIONS, H, W, zeiss

from arcsem.synthetic.cameras import ViewSpec, arc_cameras
from arcsem.synthetic.render import RenderConfig, render_views
from arcsem.synthetic.write import SceneParams, make_specimen

views = [ViewSpec(f"v{i}", "train", "v", 0.0, e) for i, e in enumerate(ELEVATIONS)]
cams, _ = arc_cameras(views, W, H, "orthographic")
renders = render_views(make_specimen(SceneParams(texture=0.6)), cams, RenderConfig(supersample=1, texture=0.6))
rng = np.random.default_rng(0)
Path("raw").mkdir()
for i, (r, e) in enumerate(zip(renders, ELEVATIONS)):
    img = np.clip(np.round((r.grey.numpy() + rng.normal(0, 0.02, (H, W))) * 255), 0, 255).astype(np.uint8)
    tag = (34118, 2, 0, zeiss(e - 90.0, (W, H)).encode("latin-1"), True)
    tifffile.imwrite(f"raw/scan_{i + 1:02d}.tif", img, compression="lzw", metadata=None, extratags=[tag])
print(f"raw/: {len(renders)} Zeiss LZW TIFF scans, {W}x{H}")
PY
# the README's three commands, as written
arcsem-calibrate --inspect raw/
arcsem-calibrate raw/ --out pollen/
arcsem experiment=grayscale_comparison dataset=transforms dataset.path=pollen/
