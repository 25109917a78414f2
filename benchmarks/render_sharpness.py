"""How sharp are a study's held-out renders? Gradient energy against the ground truth's, in the specimen's mask.

For each run folder (a study job, e.g. ``multirun/results/grayscale_comparison_real-quick/0``, or its
``stage1`` folder), each held-out render ``stage1/renders/test/<view>.png`` is compared with the ground truth
saved beside it (``<view>_gt.png``): PSNR over the image and inside the mask, and the **energy ratio**
``sqrt(mean |grad render|^2) / sqrt(mean |grad gt|^2)`` over the mask's pixels (forward differences of the
grey image): 1 for a render as detailed as the image, less for a blurred one. The mask is the dataset's ``masks/<view>.png`` (``--masks``),
resized to the render; without one, the whole image.

``--grid PX [PX ...]`` (>= 1) also prints the ratio of the ground truth itself held by a 2-D grid of that
spacing in render pixels, read back bilinearly, its values fitted by least squares (as a voxel grid with
trilinear interpolation renders a flat texture facing the camera): about the best a grid of that voxel
size can show of this view.

    .venv/bin/python benchmarks/render_sharpness.py multirun/results/grayscale_comparison_real-quick/* \\
        --masks /tmp/plenox_cache/real/dsa/masks --grid 1.35 0.68
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def grey(path: Path) -> np.ndarray:
    """``[H, W]`` float64 in [0, 1] of an 8-bit image."""
    from PIL import Image

    return np.asarray(Image.open(path).convert("L"), dtype=np.float64) / 255.0


def energy(img: np.ndarray, mask: np.ndarray) -> float:
    """RMS forward-difference gradient of ``img [H, W]`` over ``mask [H, W]``."""
    gx, gy = np.diff(img, axis=1)[:-1], np.diff(img, axis=0)[:, :-1]
    return float(np.sqrt((gx**2 + gy**2)[mask[:-1, :-1]].mean()))


def on_grid(img: np.ndarray, spacing: float, iters: int = 200) -> np.ndarray:
    """``img [H, W]`` as well as a grid of ``spacing`` pixels read back bilinearly can hold it: the grid's values
    fitted by least squares (L-BFGS from the box averages), as training fits a voxel grid to the views."""
    import torch
    import torch.nn.functional as F

    h, w = img.shape
    n = (max(2, round(h / spacing)), max(2, round(w / spacing)))
    t = torch.from_numpy(img)[None, None]
    g = F.adaptive_avg_pool2d(t, n).clone().requires_grad_()
    opt = torch.optim.LBFGS([g], max_iter=iters, line_search_fn="strong_wolfe")

    def loss():
        opt.zero_grad()
        out = ((F.interpolate(g, size=(h, w), mode="bilinear", align_corners=False) - t) ** 2).mean()
        out.backward()
        return out

    opt.step(loss)
    with torch.no_grad():
        return F.interpolate(g, size=(h, w), mode="bilinear", align_corners=False)[0, 0].numpy()


def mask_for(masks: Path | None, view: str, shape: tuple[int, int]) -> np.ndarray:
    if masks is None or not (masks / f"{view}.png").is_file():
        return np.ones(shape, dtype=bool)
    from PIL import Image

    m = Image.open(masks / f"{view}.png").convert("L").resize(shape[::-1], Image.Resampling.NEAREST)
    return np.asarray(m) > 127


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(-10 * np.log10(max(((a - b) ** 2).mean(), 1e-20)))


def name_of(run: Path) -> str:
    over = run / ".hydra" / "overrides.yaml"
    if over.is_file():
        for line in over.read_text().splitlines():
            if "variant=" in line:
                return line.split("variant=")[1].strip()
    return run.name


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--masks", type=Path, default=None, help="folder of the dataset's masks (<view>.png)")
    ap.add_argument("--split", default="test", choices=("test", "train"), help="renders/<split> (train: own ACT)")
    ap.add_argument("--grid", type=float, nargs="*", default=[], help="voxel sizes (render pixels, >= 1) to bound")
    a = ap.parse_args()
    if any(s < 1 for s in a.grid):
        raise SystemExit("error: --grid spacings must be >= 1 render pixel")
    print(f"{'run':>12} {'view':>10} {'PSNR':>6} {'in mask':>7} {'energy ratio':>12}")
    bounds_done = set()
    for run in a.runs:
        folder = (run / "stage1" if (run / "stage1").exists() else run) / "renders" / a.split
        for gt_path in sorted(folder.glob("*_gt.png")):
            view = gt_path.name[: -len("_gt.png")]
            gt, img = grey(gt_path), grey(folder / f"{view}.png")
            mask = mask_for(a.masks, view, gt.shape)
            ratio = energy(img, mask) / energy(gt, mask)
            print(f"{name_of(run):>12} {view:>10} {psnr(img, gt):6.2f} {psnr(img[mask], gt[mask]):7.2f} {ratio:12.3f}")
            if view not in bounds_done:
                bounds_done.add(view)
                for s in a.grid:
                    g = on_grid(gt, s)
                    print(f"{'grid ' + str(s) + ' px':>12} {view:>10} {psnr(g, gt):6.2f} {psnr(g[mask], gt[mask]):7.2f} "
                          f"{energy(g, mask) / energy(gt, mask):12.3f}")


if __name__ == "__main__":
    main()
