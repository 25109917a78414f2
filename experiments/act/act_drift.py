"""How much of the built-in scene's exposure drift did a stage-1 run's ACT learn?

The synthetic training images are ``contrast_i * clean + brightness_i`` plus noise
(:func:`arcsem.synthetic.write.true_exposures`). A model with ACT renders ``W_i * c + b_i`` (scalar part:
the mean over RGB), where its canonical grey ``c`` may be any global affine map of the clean grey,
``c = (clean - h) / g``, so ACT is right when ``W_i = contrast_i / g`` and ``b_i = brightness_i - W_i h``
for ONE ``(g, h)`` shared by all views. The script fits ``(g, h)`` by least squares and reports, for
contrast and brightness, the share of the drift's variance (around its mean: what a model without ACT
is left with) that ACT removes: 1 = all, 0 = none, < 0 = ACT adds its own per-view changes.

Usage (a run directory holds ``metrics.json`` and ``stage1/``; several may be given)::

    .venv/bin/python benchmarks/act_drift.py multirun/.../0 multirun/.../1 [--per-view]
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from arcsem.synthetic.write import SceneParams, true_exposures


def learned_act(run: Path) -> tuple[list[str], np.ndarray, np.ndarray] | None:
    """Training-view names (ACT order) and their ``W, b`` ``[N]`` (mean over RGB); None without ACT."""
    ckpt = torch.load(run / "stage1" / "checkpoints" / "last.pt", map_location="cpu", weights_only=False)
    state = ckpt["model"]
    if "act.weight" not in state:
        return None
    with open(run / "stage1" / "views.csv", newline="") as f:
        names = [r["name"] for r in csv.DictReader(f) if r["split"] == "train"]
    W, b = state["act.weight"].double(), state["act.bias"].double()
    if "act.smooth" in state:  # act.smooth_degree >= 0: the transforms as applied (see ACT.effective)
        P = state["act.smooth"].double()
        W, b = W - P @ W, b - P @ b
    W, b = W.mean(1).numpy(), b.mean(1).numpy()
    if len(names) != len(W):
        sys.exit(f"{run}: views.csv lists {len(names)} training views, ACT has {len(W)} images")
    return names, W, b


def explained(C: np.ndarray, B: np.ndarray, W: np.ndarray, b: np.ndarray) -> tuple[float, float, float, float]:
    """``(share of contrast variance removed, same for brightness, g, h)`` for true ``C, B`` and learned ``W, b``."""
    g = float((C * W).sum() / (W * W).sum())
    h = float(((B - b) * W).sum() / (W * W).sum())
    rc, rb = C - W * g, B - (W * h + b)
    vc, vb = ((C - C.mean()) ** 2).sum(), ((B - B.mean()) ** 2).sum()
    return 1 - float((rc ** 2).sum() / vc), 1 - float((rb ** 2).sum() / vb), g, h


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="+", type=Path, help="run directories (metrics.json + stage1/)")
    ap.add_argument("--per-view", action="store_true", help="also print each view's drift left after ACT")
    args = ap.parse_args(argv)
    print("| run | ACT lr | drift | contrast removed | brightness removed | held-out PSNR |")
    print("|---|---|---|---|---|---|")
    for run in args.runs:
        metrics = json.loads((run / "metrics.json").read_text())
        meta = json.loads((Path(metrics["dataset"]["root"]) / "transforms.json").read_text())
        if "synthetic" not in meta:
            sys.exit(f"{run}: its dataset is not a built-in synthetic scene (no true drift to compare with)")
        truth = true_exposures(SceneParams.from_transforms(meta))
        test = metrics["stages"]["gray"]["stage1"]["test"]["psnr"]
        act_lr = OmegaConf.select(OmegaConf.load(run / "config.yaml"), "act.lr", default="?")
        got = learned_act(run)
        if got is None:
            print(f"| {run} | no ACT | {meta['synthetic']['drift']} | 0 | 0 | {test:.2f} |")
            continue
        names, W, b = got
        C = np.array([truth[n][0] for n in names])
        B = np.array([truth[n][1] for n in names])
        print(f"|   true drift over the {len(C)} views: mean contrast {C.mean():.4f}, mean brightness {B.mean():+.4f}, "
              f"sd {C.std():.4f} / {B.std():.4f} | | | | |")
        ec, eb, g, h = explained(C, B, W, b)
        print(f"| {run} | {act_lr} | {meta['synthetic']['drift']} | {ec:.2f} | {eb:.2f} | {test:.2f} |")
        if args.per_view:
            for n, rc, rb in zip(names, C - W * g, B - (W * h + b)):
                print(f"|   {n} | contrast left {rc:+.3f} | brightness left {rb:+.3f} | | | |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
