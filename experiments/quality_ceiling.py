"""How hard is the built-in scene? PSNR of its noise-free held-out views against perturbed copies.

A reconstruction from a few hundred CPU steps is never pixel-exact: its views are slightly
misregistered (sub-pixel) and slightly blurred. This script measures what such small errors alone
cost on the scene the quality targets are quoted on, so a measured held-out PSNR can be read
against them. Each row compares the clean held-out views with a perturbed copy of themselves:

* ``shift s px``: translated by ``s`` pixels (bilinear; along x, then along y, averaged);
* ``blur sigma px``: Gaussian blur (OpenCV);
* ``observed``: the noisy, drifting SEM images the model is trained on (training views).

Whole image and specimen mask. Usage (the quick preset's resolution by default)::

    .venv/bin/python benchmarks/quality_ceiling.py [--width 192]
"""
from __future__ import annotations

import argparse

import cv2
import numpy as np
import torch

from arcsem.data import load_scene
from arcsem.metrics import psnr
from arcsem.train.sampling import resize_split


def shifted(img: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """``[H, W, 3]`` image translated by ``(dx, dy)`` pixels (bilinear, edge pixels repeated)."""
    m = np.float32([[1, 0, dx], [0, 1, dy]])
    return cv2.warpAffine(img, m, img.shape[1::-1], flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def blurred(img: np.ndarray, sigma: float) -> np.ndarray:
    return cv2.GaussianBlur(img, (0, 0), sigma)


def mean_psnr(ref: torch.Tensor, other: list[np.ndarray], masks: torch.Tensor | None) -> tuple[float, float]:
    """Mean PSNR over views, whole image and inside the mask (NaN without masks)."""
    whole, inside = [], []
    for i, o in enumerate(other):
        o = torch.from_numpy(o).to(ref)
        whole.append(psnr(o, ref[i]))
        if masks is not None:
            inside.append(psnr(o, ref[i], masks[i]))
    return float(np.mean(whole)), float(np.mean(inside)) if inside else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=192, help="evaluation width (the quick preset: 192)")
    args = ap.parse_args()
    scene = load_scene({"kind": "synthetic"})
    test, train = resize_split(scene.test, width=args.width), resize_split(scene.train, width=args.width)
    clean = [c.numpy().astype(np.float32) for c in test.clean]
    print(f"built-in scene, {len(test)} held-out views at {test.cameras.width}x{test.cameras.height}")
    print(f"{'perturbation':>22} | {'PSNR':>6} | {'PSNR mask':>9}")
    rows = []
    for s in (0.1, 0.25, 0.5):
        a = mean_psnr(test.clean, [shifted(c, s, 0) for c in clean], test.masks)
        b = mean_psnr(test.clean, [shifted(c, 0, s) for c in clean], test.masks)
        rows.append((f"shift {s} px", (a[0] + b[0]) / 2, (a[1] + b[1]) / 2))
    for sigma in (0.3, 0.5, 1.0):
        rows.append((f"blur {sigma} px", *mean_psnr(test.clean, [blurred(c, sigma) for c in clean], test.masks)))
    rows.append(("observed (train views)", *mean_psnr(train.clean, [i.numpy() for i in train.images], train.masks)))
    for name, whole, inside in rows:
        print(f"{name:>22} | {whole:6.2f} | {inside:9.2f}")


if __name__ == "__main__":
    main()
