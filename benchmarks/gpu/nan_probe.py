"""Where a non-finite value first appears in a short 2DGS + gsplat run (the CUDA test's 32 x 24 scene), on a GPU.

Run by benchmarks/gpu_check.sh (part ``probe``) when tests/test_cuda.py's gsplat 2DGS run fails: trains 20 steps
with the finiteness read every step and autograd's anomaly mode, printing each step's largest gradient per
parameter group, so one call says which operation and which step. No GPU here: it exits with a message.

    python benchmarks/gpu/nan_probe.py [OVERRIDE ...]
"""
from __future__ import annotations

import sys
import tempfile
import traceback
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))


def main(overrides: list[str]) -> int:
    if not torch.cuda.is_available():
        print("nan_probe: no CUDA device")
        return 0
    import cv2
    import numpy as np
    from conftest import write_transforms_scene
    from test_config import compose_with

    from arcsem import app
    from arcsem.train import loop

    tmp = Path(tempfile.mkdtemp())
    scene = write_transforms_scene(tmp / "scene", n=4, w=32, h=24)
    cv2.imwrite(str(tmp / "view_01.png"), np.full((24, 32, 3), (0, 0, 200), np.uint8))
    cfg = compose_with("dataset=transforms", f"dataset.path={scene.parent}", "stage=gray", "backbone=gs2d",
                       "device=cuda", "act=paper", "train.width=null", "train.steps=20", "train.eval.lpips=false",
                       "train.progress=false", "train.check_every=1", f"cache_dir={tmp / 'cache'}",
                       "mesh.enabled=false", "backbone.rasterizer=gsplat", *overrides)
    health_record = loop._Health.record

    def record(self, run, step, terms, params, grads):  # print the largest gradient of each group
        big = {g: max((float(t.abs().max()) for t in gs if t is not None and not t.is_sparse), default=0.0)
               for g, gs in grads.items()}
        print(f"step {step + 1}: " + ", ".join(f"{g} {v:.3g}" for g, v in big.items()))
        return health_record(self, run, step, terms, params, grads)

    loop._Health.record = record
    torch.autograd.set_detect_anomaly(True)
    try:
        metrics = app.run(cfg, run_dir=tmp / "run")
        print("nan_probe: run", metrics["status"])
    except Exception:  # noqa: BLE001 - the probe reports whatever stopped the run
        traceback.print_exc(limit=-12)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
