"""A tiny two-stage run on ``rasterizer=triton`` against ``rasterizer=torch``: both stages end in the same place.

The configuration of tests/test_cuda.py's end-to-end test (4 views of 32x24, 2DGS + ACT, 20 stage-1 steps, 5 stage-2
steps, one reference), 300 random splats, the D-SSIM and normal-consistency losses on each rasteriser's own kernels
(the Triton ones with ``triton``, as ``auto`` on CUDA); on a GPU with ``device=cuda``, on a machine without one through Triton's
CPU interpreter (about 10 minutes)::

    TRITON_INTERPRET=1 python benchmarks/gpu/triton_parity.py            # device=cpu
    python benchmarks/gpu/triton_parity.py --device cuda

Prints each rasteriser's stage-1 training PSNR and stage-2 final loss, and their differences.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))


def run(rasterizer: str, device: str, tmp: Path) -> dict:
    import cv2
    import numpy as np
    from conftest import write_transforms_scene
    from test_config import compose_with

    from arcsem import app

    work = tmp / rasterizer
    scene = write_transforms_scene(work / "scene", n=4, w=32, h=24)
    cv2.imwrite(str(work / "view_01.png"), np.full((24, 32, 3), (0, 0, 200), np.uint8))
    cfg = compose_with("dataset=transforms", f"dataset.path={scene.parent}", "stage=all", "backbone=gs2d",
                       f"device={device}", "act=paper", "train.width=null", "train.steps=20", "train.eval.lpips=false",
                       "train.progress=false", "colorize.steps=5", "colorize.progress=false", "colorize.eval.lpips=false",
                       "colorize.losses.tcm.weight=0", "colorize.losses.ccm.weight=0",
                       f"colorize.references={work / 'view_01.png'}", f"cache_dir={work / 'cache'}", "mesh.enabled=false",
                       "backbone.random_init_points=300", f"backbone.rasterizer={rasterizer}",
                       # the losses' paths as `auto` takes them on CUDA with each rasteriser
                       f"+train.losses.dssim.impl={rasterizer}", f"+train.losses.normal_consistency.impl={rasterizer}")
    t0 = time.perf_counter()
    m = app.run(cfg, run_dir=work / "run")
    return {"status": m["status"], "psnr": m["stage1"]["train"]["psnr"], "loss2": m["stage2"]["final_loss"],
            "s": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        res = {r: run(r, a.device, Path(tmp)) for r in ("torch", "triton")}
    for r, v in res.items():
        print(f"{r}: {v['status']}, stage-1 training PSNR {v['psnr']:.6f} dB, stage-2 final loss {v['loss2']:.7f}, "
              f"{v['s']:.0f} s")
    print(f"difference: PSNR {res['triton']['psnr'] - res['torch']['psnr']:+.2e} dB, "
          f"stage-2 loss {res['triton']['loss2'] - res['torch']['loss2']:+.2e}")


if __name__ == "__main__":
    main()
