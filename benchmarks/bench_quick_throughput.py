"""Stage-1 training throughput of a trained Gaussian model: PyTorch vs fused C++ rasteriser.

Loads a stage-1 checkpoint (the `quick` preset's final model, at its final size: the steady-state
cost of a step) and runs the real trainer (`arcsem.train.train`: render, L1 + D-SSIM, backward,
Adam) for a few steps with ``rasterizer=torch`` and ``rasterizer=cpp``, alternating, in one process.
Densification is switched off so both paths time the same model. Usage::

    .venv/bin/python benchmarks/bench_quick_throughput.py RUN_DIR [--steps 20 --repeats 3 --threads 2]

``RUN_DIR``: a stage-1 run folder (``checkpoints/last.pt``), e.g. a ``gs2d_act`` job of the
grayscale comparison. The demo's time budget divided by the seconds per step gives the steps each
path affords; the held-out PSNR those steps reach is read off the tuning curve in
``benchmarks/results/README.md``.
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

import torch
from omegaconf import OmegaConf

from arcsem.data import load_scene
from arcsem.runs import load_stage1
from arcsem.train import LoopConfig, build_losses, train
from arcsem.train.checkpoint import load_checkpoint
from arcsem.train.stage1 import prepare_scene, train_config


def seconds_per_step(backbone, act, split, impl: str, steps: int) -> float:
    backbone.cfg.rasterizer = impl
    losses = build_losses({"l1": {"weight": 0.8}, "dssim": {"weight": 0.2}}, backbone.provides, backbone.batch_mode)
    with tempfile.TemporaryDirectory() as tmp:
        res = train(backbone, split, losses, LoopConfig(steps=steps, progress=False, checkpoint_every=0, resume="never"),
                    ckpt_dir=Path(tmp), act=act, act_lr=1e-4)
    return res.time_s / steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--budget-s", type=float, default=360.0, help="stage-1 time budget to convert into steps")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    ckpt = args.run_dir / "checkpoints" / "last.pt"
    saved = load_checkpoint(ckpt)["config"]
    scene = load_scene(saved["dataset"])
    backbone, act = load_stage1(ckpt, scene)
    backbone.train()
    backbone.cfg.densify = False
    split = prepare_scene(scene, train_config(OmegaConf.create(saved))).train
    print(f"{ckpt}: {backbone.name}, {backbone.num_primitives()} primitives, "
          f"{split.cameras.width}x{split.cameras.height}, {args.threads} threads")
    times: dict[str, list[float]] = {"torch": [], "cpp": []}
    for impl in times:  # warm-up: builds/loads the extension, allocator and thread pools
        seconds_per_step(backbone, act, split, impl, 1)
    for _ in range(args.repeats):
        for impl, runs in times.items():
            runs.append(seconds_per_step(backbone, act, split, impl, args.steps))
    med = {k: statistics.median(v) for k, v in times.items()}
    for impl, t in med.items():
        print(f"{impl:>6}: {t:.3f} s/step (median of {args.repeats} x {args.steps} steps), "
              f"{1 / t:.2f} steps/s; {args.budget_s:.0f} s buy {int(args.budget_s / t)} steps")
    print(f" ratio torch/cpp: {med['torch'] / med['cpp']:.2f}")


if __name__ == "__main__":
    main()
