"""Seconds of a stage-1 run's final evaluation (the views of every protocol, PSNR/SSIM/LPIPS whole and masked, no
PNGs, no video), with LPIPS and without, on this machine.

    TORCH_HOME=<hub cache with the convention's LPIPS weights> .venv/bin/python benchmarks/eval_cost.py RUN_DIR

LPIPS runs only where its ImageNet weights are in the hub cache (``arcsem.weights``; else it is NaN and costs
nothing), so on a machine without them this measures the evaluation that users with network do not get: point
``TORCH_HOME`` at a cache holding the file (its values do not change the cost). Prints one line per setting.
"""
from __future__ import annotations

import argparse
import time


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run")
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args()
    import torch

    torch.set_num_threads(a.threads)
    from arcsem.configs import EvalConfig
    from arcsem.runs import load_run
    from arcsem.train.stage1 import evaluate

    m = load_run(a.run, colored=False)
    m.backbone.eval()
    for with_lpips in (False, True):
        ec = EvalConfig(lpips=with_lpips, video=False, renders=False)
        t = time.perf_counter()
        res = evaluate(m.backbone, m.scene, None, ec)
        dt = time.perf_counter() - t
        views = sum(1 for k in ("train", "train_paper", "test") if res.get(k))
        print(f"lpips={with_lpips}: {dt:.1f} s ({views} protocols/splits; lpips_weights: {res.get('lpips_weights')}; "
              f"held-out LPIPS {res['test'].get('lpips', float('nan')):.4f})")


if __name__ == "__main__":
    main()
