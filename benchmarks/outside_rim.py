"""Where "outside the coverage" lies: the silhouette's rim or the specimen's inside, and the default's gain on each.

Issue 38's second line asks the default stage 2 to beat pseudo-colours alone by 2 dB outside the references'
coverage. This splits the held-out (test) views' specimen pixels four ways, covered or not (decided on the true
depth, as the run's metrics) and on the silhouette's rim (within ``--rim`` px of the specimen mask's edge, by the
mask's distance transform) or inside it, and gives the held-out colour PSNR of the default and of pseudo-colours
alone on each part, pooled over the views and the seeds. The renders are the PNGs each stage 2 saves
(``colorize/renders/test/<view>.png``; 8-bit, so within a hundredth of a dB of ``metrics.json``). The last column:
the stage-1 model's grey renders (``renders/{test,train}/<view>.png`` of its run) on the rim and inside, of the
test views and of the training views it was fitted to, where that run saved them::

    .venv/bin/python benchmarks/outside_rim.py DIR [DIR ...] [--references one three five] [--rim 1.5]

DIR: sweep folders as ``colour_table.py`` reads them (the default's and ``ablation=pseudo_only``'s runs, paired by
scene, reference count and seed; a later DIR's run replaces an earlier one's). On scenes without depth maps the
coverage is the stage-1 model's, as in the run's metrics (pixels where the model has no surface in no part).
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))  # colour_table beside it (benchmarks/ is no package)
import colour_table

PARTS = ("rim covered", "rim outside", "inside covered", "inside outside", "outside")


def rim_masks(masks: torch.Tensor, width: float) -> torch.Tensor:
    """``[N, H, W]`` bool: the mask pixels within ``width`` px (Euclidean) of a pixel outside the mask (``masks
    [N, H, W]`` bool; the image border counts as outside)."""
    from scipy import ndimage

    padded = np.pad(masks.numpy(), ((0, 0), (1, 1), (1, 1)))
    dist = np.stack([ndimage.distance_transform_edt(m)[1:-1, 1:-1] for m in padded])
    return masks & torch.from_numpy(dist <= width)


def split_parts(masks: torch.Tensor, covered: torch.Tensor, rim: torch.Tensor) -> dict[str, torch.Tensor]:
    """The five selections of :data:`PARTS` (``[N, H, W]`` bool each)."""
    inner = masks & ~rim
    return {"rim covered": rim & covered, "rim outside": rim & ~covered, "inside covered": inner & covered,
            "inside outside": inner & ~covered, "outside": masks & ~covered}


def _renders(folder: Path, names: list[str], suffix: str = "") -> torch.Tensor:
    """``[N, H, W, 3]`` in [0, 1]: the PNGs ``<folder>/<name><suffix>.png``."""
    import cv2

    return torch.stack([torch.from_numpy(cv2.imread(str(folder / f"{n}{suffix}.png"), cv2.IMREAD_COLOR)[..., ::-1]
                                         .copy()) for n in names]).float() / 255


def errors(default: Path, pseudo: Path, rim_px: float) -> dict[str, tuple[int, float, float]] | None:
    """Per part of :data:`PARTS`: (pixels, the default's and pseudo-colours' summed squared error), and under
    ``grey``, per ``test rim``/``test inside``/``train rim``/``train inside`` (of the masks): (pixels, the stage-1
    model's grey renders' summed squared error against their ground truth), where it saved them; None without colour
    or masks of the test views."""
    from omegaconf import OmegaConf

    from arcsem.colorize import inputs as prep
    from arcsem.colorize.coverage import coverage_masks
    from arcsem.colorize.references import load_references
    from arcsem.colorize.stage2 import find_stage1
    from arcsem.data import load_scene
    from arcsem.runconfig import run_config

    rc = run_config(OmegaConf.load(default / "config.yaml"))
    cfg, cc = rc.cfg, rc.colorize
    ckpt = find_stage1(cfg, cc, default)
    scene = prep.prepare_scene(load_scene(cfg.dataset), ckpt, cc)
    train, test = scene.train, scene.test
    if test.colors is None or test.masks is None or not len(test):
        return None
    ridx = load_references(scene, cc.references).indices.tolist()
    masks = test.masks.bool()
    if train.depths is not None and test.depths is not None:  # the true geometry decides, as the run's metrics
        covered = coverage_masks(train.cameras[ridx], train.depths[ridx], train.masks[ridx].bool(), test.cameras,
                                 test.depths, masks, cc.radius, cc.radius_factor)
    else:  # the stage-1 model's depth, as the run's metrics: pixels without model surface in neither part
        covered, surface = _model_coverage(ckpt, scene, cfg, cc, ridx)
        masks = masks & surface
    names = [Path(str(n)).stem for n in test.names]
    gt = test.colors.float()
    a, b = (_renders(run / "colorize" / "renders" / "test", names) for run in (default, pseudo))
    rim = rim_masks(masks, rim_px)
    out = {}
    for part, sel in split_parts(masks, covered, rim).items():
        out[part] = (int(sel.sum()), float(((a - gt)[sel] ** 2).sum()), float(((b - gt)[sel] ** 2).sum()))
    grey = {}
    for name, split in (("test", test), ("train", train)):  # the stage-1 run's grey renders, if it saved them
        folder, views = ckpt.parent.parent / "renders" / name, [Path(str(n)).stem for n in split.names]
        if split.masks is None or not all((folder / f"{n}{x}.png").is_file() for n in views for x in ("", "_gt")):
            continue
        g, g_gt, m = _renders(folder, views), _renders(folder, views, "_gt"), split.masks.bool()
        r = rim_masks(m, rim_px)
        grey.update({f"{name} {k}": (int(sel.sum()), float(((g - g_gt)[sel] ** 2).sum()))
                     for k, sel in (("rim", r), ("inside", m & ~r))})
    if len(grey) == 4:
        out["grey"] = grey
    return out


def _model_coverage(ckpt: Path, scene, cfg, cc, ridx: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
    """``[N, H, W]`` covered and with-surface pixels of the test views by the stage-1 model's depth (the split of
    :func:`arcsem.colorize.coverage.coverage_metrics` for a dataset without depth maps)."""
    from arcsem.colorize.coverage import coverage_masks
    from arcsem.colorize.masks import specimen_masks
    from arcsem.colorize.pseudocolor import render_depths
    from arcsem.runs import load_stage1

    backbone, _ = load_stage1(ckpt, scene, cfg)
    refs = scene.train.subset(ridx)
    ref_masks = specimen_masks(scene.train, cc.masks, cc.mask_folder, cc.sam_checkpoint)[ridx].bool()
    depth = render_depths(backbone, scene.test)
    covered = coverage_masks(refs.cameras, render_depths(backbone, refs), ref_masks, scene.test.cameras, depth,
                             scene.test.masks.bool(), cc.radius, cc.radius_factor)
    return covered, depth > 0


def _db(sq: float, n: int) -> float:
    return -10 * math.log10(sq / (3 * n)) if n else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dirs", nargs="+")
    ap.add_argument("--references", nargs="+", default=["five"])
    ap.add_argument("--rim", type=float, default=1.5, help="the rim's width in pixels")
    args = ap.parse_args()
    runs = colour_table._runs(args.dirs)
    groups = colour_table._paired(runs, "pseudo_only")
    print(f"| scene, references | seeds | {' | '.join(f'{p}: px / default / pseudo / gain' for p in PARTS)} | "
          "stage-1 grey, test: rim / inside; train: rim / inside |")
    print("|---|---:|" + "---|" * (len(PARTS) + 1))
    for stem in sorted(groups):
        if stem.rpartition("_")[2] not in args.references:
            continue
        got = [errors(runs[a], runs[b], args.rim) for a, b in groups[stem].values()]
        if any(g is None for g in got):
            continue
        cells = []
        for part in PARTS:
            n = sum(g[part][0] for g in got)
            da, db = _db(sum(g[part][1] for g in got), n), _db(sum(g[part][2] for g in got), n)
            cells.append(f"{n // len(got)} / {da:.2f} / {db:.2f} / {da - db:+.2f}" if n else "0")
        if all("grey" in g for g in got):
            db = {k: _db(sum(g["grey"][k][1] for g in got), sum(g["grey"][k][0] for g in got)) for k in got[0]["grey"]}
            cells.append(f"{db['test rim']:.2f} / {db['test inside']:.2f}; {db['train rim']:.2f} / {db['train inside']:.2f}")
        else:
            cells.append("-")
        print(f"| {stem} | {len(got)} | {' | '.join(cells)} |")


if __name__ == "__main__":
    main()
