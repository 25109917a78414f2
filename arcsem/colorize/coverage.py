"""Colour quality inside and outside the pseudo-colour coverage.

A specimen pixel is *covered* when pseudo-colours reach it: its 3-D point (its depth unprojected) has a
reference point within the search radius (:func:`arcsem.colorize.pseudocolor.query_view`, the same
test as the pseudo-colours). TCM and CCM exist for the rest: parts occluded in, or unseen by, every
reference. For held-out views the coverage is computed as for training views, from the depth the
pseudo-colours use (``colorize.depth``: the stage-1 model's render, or the dataset's depth maps).

PSNR over each part is pooled over the views (the MSE of all their pixels in that part), so small
uncovered regions of some views do not give noisy per-view numbers.
"""
from __future__ import annotations

import torch
from torch import Tensor

from .pseudocolor import query_view, reference_cloud

__all__ = ["coverage_masks", "coverage_metrics", "split_psnr"]


def coverage_masks(ref_cams, ref_depths: Tensor, ref_masks: Tensor, cams, depths: Tensor, masks: Tensor,
                   radius: float | None = None, radius_factor: float = 2.0) -> Tensor:
    """``[N, H, W]`` bool: the masked pixels of views ``cams`` (``depths``, ``masks`` ``[N, H, W]``) that a
    reference point (references: ``ref_cams``, ``ref_depths``, ``ref_masks`` ``[R, H, W]``) covers."""
    from scipy.spatial import cKDTree

    colours = torch.zeros(*ref_depths.shape, 3)
    pts, _ = reference_cloud(ref_cams, ref_depths, ref_masks.bool(), colours)
    out = torch.zeros(depths.shape, dtype=torch.bool)
    if len(pts) == 0:
        return out
    tree = cKDTree(pts, leafsize=16, balanced_tree=False, compact_nodes=False)
    for v in range(len(cams)):
        hit, _ = query_view(tree, cams[v], depths[v], masks[v].bool(), radius, radius_factor)
        out[v].view(-1)[hit] = True
    return out


def split_psnr(pred: Tensor, gt: Tensor, masks: Tensor, covered: Tensor) -> dict[str, float]:
    """Pooled PSNR of ``pred``/``gt`` ``[N, H, W, 3]`` inside ``masks & covered`` and ``masks & ~covered``
    (``[N, H, W]``), and the covered share of the masked pixels (:func:`arcsem.metrics.psnr` on the views
    stacked into one image)."""
    from ..metrics import psnr

    N, H, W = masks.shape
    flat = lambda x: x.reshape(N * H, W, *x.shape[3:])
    m, c = masks.bool(), covered.bool() & masks.bool()
    n = int(m.sum())
    return {"psnr_covered": psnr(flat(pred), flat(gt), flat(c)) if bool(c.any()) else float("nan"),
            "psnr_uncovered": psnr(flat(pred), flat(gt), flat(m & ~c)) if bool((m & ~c).any()) else float("nan"),
            "coverage": float(c.sum()) / n if n else float("nan")}


def _renders(backbone, split) -> Tensor:
    """``[N, H, W, 3]`` colour renders of every view (no ACT in stage 2)."""
    with torch.no_grad():
        return torch.stack([backbone.render(split.cameras[i:i + 1])["rgb"][0].clamp(0, 1).cpu()
                            for i in range(len(split))])


def coverage_metrics(backbone, scene, refs, masks: Tensor, valid: Tensor, cc) -> dict[str, dict]:
    """``{"train_nonref": {...}, "test": {...}}`` of :func:`split_psnr` against ground-truth colour (where the
    dataset has it and specimen masks). Training views use the pseudo-colours' own ``valid`` ``[N, H, W]``;
    held-out views get the same test against the references' points (``masks``: the stage-2 masks of the
    training views)."""
    from .stage2 import render_depths

    out: dict[str, dict] = {}
    train, test = scene.train, scene.test
    ref_idx = refs.indices.tolist()
    others = [i for i in range(len(train)) if i not in set(ref_idx)]
    if train.colors is not None and train.masks is not None and others:
        pred = _renders(backbone, train.subset(others))
        out["train_nonref"] = split_psnr(pred, train.colors[others], train.masks[others], valid[others])
    if test.colors is None or test.masks is None or not len(test):
        return out
    from_model = cc.depth == "model" or train.depths is None or test.depths is None
    ref_split = train.subset(ref_idx)
    ref_depths = render_depths(backbone, ref_split) if from_model else train.depths[ref_idx]
    depths = render_depths(backbone, test) if from_model else test.depths
    cov = coverage_masks(ref_split.cameras, ref_depths, masks[ref_idx], test.cameras, depths, test.masks,
                         cc.radius, cc.radius_factor)
    out["test"] = split_psnr(_renders(backbone, test), test.colors, test.masks, cov)
    out["test"]["uncovered_px"] = int((test.masks.bool() & ~cov).sum())
    return out
