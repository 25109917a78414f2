"""How well does each TCM/CCM feature extractor carry colour to where pseudo-colours cannot? (no stage 2)

For every non-reference training view of a built-in synthetic scene, TCM matches each block-0 cell of
the grey view (16 px at the default ``tcm_downscale`` 4) to a cell of the grey references; this script
scores the matched reference cell's mean COLOUR against the view's ground-truth cell colour, separately
for cells inside and outside the pseudo-colour coverage (a cell is outside when most of its specimen
pixels have no pseudo-colour), per extractor and per reference set. Scores: ``1 - cos`` (what TCM's
colour loss space minimises: chromaticity) and the mean absolute colour difference; lower is better.
A "chance" row matches each cell to a uniformly random specimen cell of the references.

The depth is the scene's ground truth (pseudo-colour coverage, and the correspondences the learned
extractor trains on); a stage-2 run uses the stage-1 model's depth instead.

Usage::

    ARCSEM_CACHE=/tmp/cache .venv/bin/python benchmarks/feature_matching.py [--dataset synthetic diatom] \\
        [--features chance vgg16 daisy learned] [--references one three five] [--seeds 0 1 2] [--out results.md]
"""
from __future__ import annotations

import argparse
import sys
import time

import pandas as pd
import torch
import torch.nn.functional as F

from arcsem.colorize.features import ColourSpace, SceneContext, build_extractor
from arcsem.colorize.guidance import Guidance
from arcsem.colorize.pseudocolor import cache_key, pseudo_colors
from arcsem.colorize.references import load_references
from arcsem.colorize.vgg import _CACHE as vgg_cache
from arcsem.imageops import downscale


def load(dataset: str):
    from hydra import compose, initialize_config_module

    from arcsem.data import load_scene

    with initialize_config_module("arcsem.conf", version_base=None):
        cfg = compose("config", overrides=[f"dataset={dataset}"])
    return load_scene(cfg.dataset)


def cell_stats(split, valid, idx, f: int, cell: int):
    """Per cell of views ``idx``: GT mean colour ``[V, h, w, 3]``, specimen share, uncovered share ``[V, h, w]``."""
    c = cell * f
    m = split.masks[idx].float()[:, None]
    gt = F.avg_pool2d((split.colors[idx] * m.permute(0, 2, 3, 1)).permute(0, 3, 1, 2), c)
    share = F.avg_pool2d(m, c)[:, 0]
    gt = (gt / share[:, None].clamp_min(1e-6)).permute(0, 2, 3, 1)
    unc = F.avg_pool2d((m[:, 0] * (~valid[idx]).float())[:, None], c)[:, 0] / share.clamp_min(1e-6)
    return gt, share, unc


def score(pred, gt, sel) -> tuple[float, float, int]:
    if int(sel.sum()) == 0:
        return float("nan"), float("nan"), 0
    cos = F.cosine_similarity(pred[sel], gt[sel], dim=-1, eps=1e-6)
    return float((1 - cos).mean()), float((pred[sel] - gt[sel]).abs().mean()), int(sel.sum())


def run_one(scene, name, refs_name, seed, cache, f=4):
    split = scene.train
    refs = load_references(scene, refs_name)
    ridx = refs.indices.tolist()
    others = [i for i in range(len(split)) if i not in set(ridx)]
    _, valid = pseudo_colors(split.cameras, split.depths, split.masks, ridx, refs.images, progress=False)
    gt, share, unc = cell_stats(split, valid, others, f, SPACE_STRIDE)
    colours = ColourSpace((SPACE_STRIDE,))(downscale(refs.images.float(), f))[0]  # [R, 3, h, w]
    flat = colours.permute(0, 2, 3, 1).reshape(-1, 3)
    t0 = time.perf_counter()
    if name == "chance":
        ref_share = cell_stats(split, valid, ridx, f, SPACE_STRIDE)[1].reshape(-1)
        cand = (ref_share > 0.5).nonzero()[:, 0]
        g = torch.Generator().manual_seed(seed)
        pick = cand[torch.randint(len(cand), gt.shape[:3], generator=g)]
        pred = flat[pick]
    else:
        ctx = SceneContext(gray=split.images, cameras=split.cameras, masks=split.masks, depths=lambda: split.depths,
                           depth_key=cache_key(split.depths), seed=seed, downscale=f, cache_dir=cache)
        ext = build_extractor(name, ctx)
        guid = Guidance(ext, ColourSpace(ext.strides), split.images, ridx, refs.images, f, 16, cache_dir=None)
        pred = torch.stack([flat[guid.matches(v)["tcm_idx0"].reshape(-1)].reshape(*gt.shape[1:3], 3) for v in others])
    secs = time.perf_counter() - t0
    spec = share > 0.5
    inside, outside = spec & (unc <= 0.5), spec & (unc > 0.5)
    return score(pred, gt, inside), score(pred, gt, outside), secs


SPACE_STRIDE = 4  # block 0 of every extractor


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", nargs="+", default=["synthetic"])
    ap.add_argument("--features", nargs="+", default=["chance", "vgg16", "daisy", "learned"])
    ap.add_argument("--references", nargs="+", default=["one", "three", "five"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--cache", default=None, help="cache folder of the learned extractor (default: none)")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    rows = []
    for ds in a.dataset:
        scene = load(ds)
        for seed in a.seeds:
            for refs_name in a.references:
                for name in a.features:
                    torch.manual_seed(seed)  # vgg16's random weights: a new network per seed
                    vgg_cache.clear()
                    (ci, li, ni), (co, lo, no), secs = run_one(scene, name, refs_name, seed, a.cache)
                    rows.append({"dataset": ds, "seed": seed, "references": refs_name, "features": name, "in_cos": ci,
                                 "in_l1": li, "n_in": ni, "out_cos": co, "out_l1": lo, "n_out": no, "s": secs})
                    print(rows[-1], flush=True)
    text = report(pd.DataFrame(rows), a)
    print(text)
    if a.out:
        with open(a.out, "w") as fh:
            fh.write(text)
    return 0


def report(df: pd.DataFrame, a) -> str:
    """Per (dataset, references, features): means over seeds; then each extractor's mean over the settings."""
    g = df.groupby(["dataset", "references", "features"], sort=False)
    mean = g[["in_cos", "in_l1", "out_cos", "out_l1"]].mean()
    n = g[["n_in", "n_out"]].first()
    lines = [(f"seeds {a.seeds}; block-0 cells (16 px at 288x192), ground-truth depth; 1 - cos and mean |colour "
             "error| of the matched reference colour (lower is better); means over the seeds"), "",
             "| dataset | references | features | inside 1-cos | inside L1 | cells in | outside 1-cos | outside L1 | cells out |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|"]
    for (ds, r, f), m in mean.iterrows():
        k = n.loc[(ds, r, f)]
        lines.append(f"| {ds} | {r} | {f} | {m.in_cos:.4f} | {m.in_l1:.4f} | {k.n_in} | {m.out_cos:.4f} | "
                     f"{m.out_l1:.4f} | {k.n_out} |")
    over = mean.groupby("features", sort=False).mean()
    lines += ["", "Mean over the (dataset, references) settings (outside: those with cells outside):", "",
              "| features | inside 1-cos | inside L1 | outside 1-cos | outside L1 |", "|---|---:|---:|---:|---:|"]
    for f, m in over.iterrows():
        lines.append(f"| {f} | {m.in_cos:.4f} | {m.in_l1:.4f} | {m.out_cos:.4f} | {m.out_l1:.4f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
