"""Which ACT should a held-out view get? The mean over training views, or its nearest views' ACT.

ArCSEM renders novel views with the mean ACT. That is right for random per-image exposure drift (a
held-out view's nearest training views carry their own drift), but wrong for anything ACT absorbed
that varies smoothly with the view (view-dependent brightness that the scene should have learned):
the mean then misses it. This script re-scores a stage-1 run's held-out views, against their
noise-free images, with ACT = mean over training views (k = 0, the protocol of the tables) and with
ACT = mean over the k training views whose viewing directions are closest (k = 1, 2, 4, ...).

Usage (a run directory with ``config.yaml`` and ``stage1/checkpoints/last.pt``; its dataset must be
readable, e.g. the same ``ARCSEM_CACHE`` as the run)::

    .venv/bin/python benchmarks/act_heldout.py RUN_DIR [RUN_DIR ...] [--k 0 1 2 4]
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import torch
from omegaconf import OmegaConf

from arcsem.act import ACT
from arcsem.data import load_scene
from arcsem.metrics import psnr
from arcsem.runs import load_stage1
from arcsem.train.stage1 import prepare_scene, train_config


def neighbour_act(act: ACT, train_dirs: torch.Tensor, d: torch.Tensor, k: int) -> ACT:
    """A one-image ACT holding the mean ``W, b`` of the ``k`` training views nearest to direction ``d``."""
    one = ACT(1, act.mode, 0.0)
    nearest = (train_dirs @ d).topk(k).indices
    with torch.no_grad():
        W, b = act.effective()
        one.weight.copy_(W[nearest].mean(0, keepdim=True))
        one.bias.copy_(b[nearest].mean(0, keepdim=True))
    return one.to(act.weight.device)


def heldout_psnr(run: Path, ks: list[int]) -> dict[int, float]:
    """Mean held-out PSNR against the noise-free images for each ``k`` (0 = the mean ACT)."""
    cfg = OmegaConf.load(run / "config.yaml")
    scene = load_scene(cfg.dataset)
    backbone, act = load_stage1(run / "stage1" / "checkpoints" / "last.pt", scene, cfg)
    if act is None:
        sys.exit(f"{run}: stage 1 ran without ACT")
    if scene.test.clean is None:
        sys.exit(f"{run}: the dataset has no noise-free held-out images")
    sc = prepare_scene(scene, train_config(cfg))
    tdirs, hdirs = sc.train.cameras.forward.double(), sc.test.cameras.forward.double()
    out = {}
    for k in ks:
        vals = []
        for i in range(len(sc.test.cameras)):
            cams = sc.test.cameras[i : i + 1]
            if k == 0:
                cams = dataclasses.replace(cams, image_ids=torch.full_like(cams.image_ids, -1))
            else:
                backbone.act = neighbour_act(act, tdirs, hdirs[i], k)
                cams = dataclasses.replace(cams, image_ids=torch.zeros_like(cams.image_ids))
            with torch.no_grad():
                img = backbone.render(cams)["rgb"][0].clamp(0, 1)
            backbone.act = act
            vals.append(float(psnr(img, sc.test.clean[i])))
        out[k] = sum(vals) / len(vals)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--k", nargs="+", type=int, default=[0, 1, 2, 4], help="neighbour counts (0 = mean ACT)")
    args = ap.parse_args(argv)
    print("| run | " + " | ".join("mean ACT" if k == 0 else f"{k} nearest" for k in args.k) + " |")
    print("|---|" + "---|" * len(args.k))
    for run in args.runs:
        res = heldout_psnr(run, args.k)
        print(f"| {run} | " + " | ".join(f"{res[k]:.2f}" for k in args.k) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
