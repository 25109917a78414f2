"""Colour quality inside and outside the pseudo-colour coverage.

A specimen pixel is *covered* when pseudo-colours reach it: its 3-D point (its depth unprojected) has a
reference point within the search radius (:func:`arcsem.colorize.pseudocolor.query_view`, the same
test as the pseudo-colours). TCM and CCM exist for the rest: parts occluded in, or unseen by, every
reference. Where the dataset has depth maps (the synthetic scenes) the test runs on that true geometry,
so "outside" means parts no reference sees, not pixels where the stage-1 depth is wrong (by the model's
depth, most held-out pixels "outside" at five references were silhouette and depth errors of the model).
Otherwise it uses the stage-1 model's depth, as the pseudo-colours do.

PSNR over each part is pooled over the views (the MSE of all their pixels in that part), so small
uncovered regions of some views do not give noisy per-view numbers. With the model's depth, specimen
pixels (ground-truth mask) where the model has no surface (alpha < 0.5) are in neither part: geometry
errors no colour term can fix; their share is ``no_surface``.
"""
from __future__ import annotations

import torch
from torch import Tensor

from .pseudocolor import query_view, reference_cloud, render_depths

__all__ = ["RULE", "coverage_masks", "coverage_metrics", "split_psnr"]

RULE = 3
"""Version of the coverage split recorded as ``coverage_rule`` (3: decided on the dataset's depth where it has
depth maps; 2: model depth, pixels without model surface excluded; absent: model depth, all mask pixels)."""


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


def split_psnr(pred: Tensor, gt: Tensor, masks: Tensor, covered: Tensor, surface: Tensor | None = None
               ) -> dict[str, float]:
    """Pooled PSNR of ``pred``/``gt`` ``[N, H, W, 3]`` inside ``masks & covered`` and ``masks & surface &
    ~covered`` (``[N, H, W]``; ``surface``: where the model has depth, default everywhere), the covered
    share of ``masks & surface`` and the share of ``masks`` without surface (:func:`arcsem.metrics.psnr`
    on the views stacked into one image)."""
    from ..metrics import psnr

    N, H, W = masks.shape
    flat = lambda x: x.reshape(N * H, W, *x.shape[3:])
    m = masks.bool()
    s = m if surface is None else m & surface.bool()
    c, u = covered.bool() & s, s & ~covered.bool()
    n, ns = int(m.sum()), int(s.sum())
    return {"psnr_covered": psnr(flat(pred), flat(gt), flat(c)) if bool(c.any()) else float("nan"),
            "psnr_uncovered": psnr(flat(pred), flat(gt), flat(u)) if bool(u.any()) else float("nan"),
            "coverage": float(c.sum()) / ns if ns else float("nan"),
            "no_surface": 1.0 - ns / n if n else float("nan"), "uncovered_px": int(u.sum())}


def _renders(backbone, split) -> Tensor:
    """``[N, H, W, 3]`` colour renders of every view (no ACT in stage 2)."""
    with torch.no_grad():
        return torch.stack([backbone.render(split.cameras[i:i + 1])["rgb"][0].clamp(0, 1).cpu()
                            for i in range(len(split))])


def coverage_metrics(backbone, scene, refs, masks: Tensor, valid: Tensor, cc) -> dict[str, dict]:
    """``{"train_nonref": {...}, "test": {...}}`` of :func:`split_psnr` against ground-truth colour (where the
    dataset has it and specimen masks).

    Where the dataset has depth maps for every view (the synthetic scenes), coverage is decided on the
    TRUE geometry: a pixel is outside when no reference sees its surface point, whatever the stage-1 model
    got wrong (``coverage_depth: dataset``). Otherwise the references' and views' depth is the stage-1
    model's, as the pseudo-colours use it (``coverage_depth: model``; ``valid`` ``[N, H, W]`` for training
    views; ``masks``: the stage-2 masks of the training views).
    """
    out: dict[str, dict] = {}
    train, test = scene.train, scene.test
    ref_idx = refs.indices.tolist()
    others = [i for i in range(len(train)) if i not in set(ref_idx)]
    truth = train.depths is not None and (test.depths is not None or not len(test))
    ref_split = train.subset(ref_idx)
    ref_depths = train.depths[ref_idx] if truth else render_depths(backbone, ref_split)
    ref_masks = train.masks[ref_idx] if truth and train.masks is not None else masks[ref_idx]
    info = {"coverage_rule": RULE, "coverage_depth": "dataset" if truth else "model"}

    def part(split, idx, model_valid=None):
        sub = split.subset(idx)
        if truth:
            cov = coverage_masks(ref_split.cameras, ref_depths, ref_masks, sub.cameras, sub.depths, sub.masks,
                                 cc.radius, cc.radius_factor)
            surface = None
        else:
            depth = render_depths(backbone, sub)
            cov = model_valid if model_valid is not None else coverage_masks(
                ref_split.cameras, ref_depths, ref_masks, sub.cameras, depth, sub.masks, cc.radius, cc.radius_factor)
            surface = depth > 0
        return {**split_psnr(_renders(backbone, sub), sub.colors, sub.masks, cov, surface), **info}

    if train.colors is not None and train.masks is not None and others:
        out["train_nonref"] = part(train, others, valid[others])
    if test.colors is not None and test.masks is not None and len(test):
        out["test"] = part(test, list(range(len(test))))
    return out
