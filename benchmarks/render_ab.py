"""Seconds per render of a finished run's model with this checkout's code (run it with each checkout's Python,
side by side or alternately, to compare two commits' renderers on one model; issue 38's stage-2 timing).

    python benchmarks/render_ab.py RUN_DIR [--threads 1] [--repeats 5]

Loads RUN_DIR's stage-1 checkpoint and scene, renders its first test view ``--repeats`` times (forward, no
gradients: as stage 2's evaluation renders and the forward half of each step), prints the median.
"""
from __future__ import annotations

import argparse
import statistics
import time

import torch


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    from omegaconf import OmegaConf

    from arcsem.data import load_scene
    try:
        from arcsem.runs import load_stage1
    except ImportError:  # older trees
        from arcsem.train.stage1 import load_stage1
    cfg = OmegaConf.load(f"{a.run}/config.yaml")
    scene = load_scene(cfg.dataset)
    backbone, _ = load_stage1(f"{a.run}/checkpoints/last.pt", scene, cfg)
    cams = scene.test.cameras[0:1]
    times = []
    for _ in range(a.repeats + 1):
        t0 = time.perf_counter()
        with torch.no_grad():
            backbone.render(cams)
        times.append(time.perf_counter() - t0)
    n = sum(p.numel() for p in backbone.parameters())
    print(f"{torch.__version__}: {statistics.median(times[1:]) * 1000:.1f} ms a render "
          f"(forward, {a.threads} thread(s), {n} parameters)")


if __name__ == "__main__":
    main()
