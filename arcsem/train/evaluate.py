"""Evaluation of a trained scene: image metrics, depth error, renders, per-view CSV, turntable video.

Protocols (:data:`PROTOCOLS`): ``paper`` renders each view with its own ACT and scores it against the
observed image (the paper's Table 1 protocol, for training views; held-out cameras carry ``image_id = -1``
and so get the mean ACT); ``clean`` renders with the mean ACT and scores against the noise-free image
(``split.clean``, the synthetic scenes): a noise-free image has no per-image exposure drift, so a view's own
transform (fitted to its drift) would be scored for reproducing it. ``auto`` is ``clean`` where the split
has noise-free images, else ``paper``. With masks, masked
variants (``psnr_masked`` ...) are added. With ground-truth depth, the median absolute depth error
over the pixels inside the GT mask (``depth > 0`` and the specimen mask) is reported, also as a
percentage of ``length_scale`` (``scene.scale``: the specimen's diameter where the dataset states
it, else the bounding-box diagonal). The rendered depth is ``median_depth``
when the backbone provides it (2DGS), else the expected ``depth``.

Metrics come from :mod:`arcsem.metrics` (the one implementation); LPIPS is NaN when its ImageNet
weights are missing, and the reason is recorded as ``lpips_weights``.
"""
from __future__ import annotations

import csv
import dataclasses
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from ..scene import Split
from ..visual import DEPTH_SPAN, depth_display, to_uint8

__all__ = ["PROTOCOLS", "depth_error", "evaluate_split", "mean_metrics", "render_view", "resolve_protocol",
           "write_views_csv"]

METRICS = ("psnr", "ssim", "lpips")
PROTOCOLS = {
    "paper": "each view with its own ACT (held-out views: the mean ACT), against the observed image",
    "clean": "the mean ACT, against the noise-free image",
}
"""What each evaluation protocol does (recorded in ``metrics.json`` beside the numbers)."""


def resolve_protocol(split: Split, protocol: str) -> str:
    """``auto`` -> ``clean`` where ``split`` has noise-free images, else ``paper``; checks the choice."""
    if protocol == "auto":
        return "clean" if split.clean is not None else "paper"
    if protocol not in PROTOCOLS:
        raise ValueError(f"evaluation protocol must be auto, {', '.join(PROTOCOLS)}; got {protocol!r}")
    if protocol == "clean" and split.clean is None:
        raise ValueError("evaluation protocol 'clean' needs noise-free images (split.clean)")
    return protocol
def depth_error(pred: torch.Tensor, gt: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Absolute depth errors ``[P]`` over the valid pixels (``gt > 0``, inside ``mask``) of ``[H,W]`` maps."""
    valid = (gt > 0) & torch.isfinite(pred)
    if mask is not None:
        valid &= mask.bool()
    return (pred[valid].double() - gt[valid].double()).abs()


def render_view(backbone: nn.Module, split: Split, i: int, protocol: str = "auto") -> dict[str, torch.Tensor]:
    """Image outputs (``[H, W, k]`` each) of view ``i`` as ``protocol`` scores it: ``clean``, the mean ACT;
    ``paper``, the view's own ACT (see the module docstring)."""
    cams = split.cameras[i : i + 1]
    if resolve_protocol(split, protocol) == "clean":  # a drift-free target: the mean ACT
        cams = dataclasses.replace(cams, image_ids=torch.full_like(cams.image_ids, -1))
    with torch.no_grad():
        out = backbone.render(cams)
    return {k: v[0].detach().cpu() for k, v in out.items() if torch.is_tensor(v) and v.ndim == 4}


def _image_row(pred, gt, mask, with_lpips: bool, convention: str) -> dict[str, Any]:
    from ..metrics import image_metrics

    row = image_metrics(pred, gt, None, with_lpips, convention)
    if mask is not None:
        masked = image_metrics(pred, gt, mask, with_lpips, convention)
        row.update({f"{k}_masked": masked[k] for k in METRICS})
    return row


def evaluate_split(backbone: nn.Module, split: Split, *, split_name: str = "test", length_scale: float = 1.0,
                   out_dir: str | Path | None = None, with_lpips: bool = True, max_views: int | None = None,
                   protocol: str = "auto", metrics: str = "3dgs", progress: bool = False,
                   ) -> tuple[list[dict[str, Any]], dict[str, Any], list[torch.Tensor]]:
    """Render and score every view of ``split`` (up to ``max_views``, evenly spaced) under ``protocol``
    (:data:`PROTOCOLS`; ``auto``: ``clean`` where the split has noise-free images, else ``paper``) with the
    metric convention ``metrics`` (:data:`arcsem.metrics.CONVENTIONS`); ``progress``: a tqdm bar over the views.

    Returns:
        rows: one dict per view (``split``, ``name``, metrics, ``depth_mae``, ``depth_mae_pct``).
        summary: means over views (NaN-aware), pooled-median depth error, ``lpips_weights``.
        errors: the per-view absolute depth errors (for pooling across calls).
    Writes ``out_dir/renders/<split_name>/<name>.png``, ``<name>_depth.png`` and the ground truth
    ``<name>_gt.png`` / ``<name>_depth_gt.png`` when ``out_dir`` is set (depth: :func:`arcsem.visual.depth_display`,
    ``0 .. DEPTH_SPAN x length_scale`` below the nearest ground-truth point, the same pixels in both).
    """
    n = len(split)
    views = range(n) if not max_views or max_views >= n else np.linspace(0, n - 1, max_views).round().astype(int)
    protocol = resolve_protocol(split, protocol)
    target = split.clean if protocol == "clean" else split.images
    render_dir = Path(out_dir) / "renders" / split_name if out_dir is not None else None
    if render_dir is not None:
        render_dir.mkdir(parents=True, exist_ok=True)
    from tqdm import tqdm

    rows, errors, weights = [], [], set()
    for i in tqdm([int(v) for v in views], desc=f"evaluating {split_name} views", disable=not progress, leave=False):
        out = render_view(backbone, split, i, protocol)
        pred, mask = out["rgb"].clamp(0, 1), None if split.masks is None else split.masks[i]
        row = {"split": split_name, "name": split.names[i], **_image_row(pred, target[i], mask, with_lpips, metrics)}
        weights.add(row.pop("lpips_weights", "skipped"))
        depth = out.get("median_depth", out.get("depth"))
        if split.depths is not None and depth is not None:
            err = depth_error(depth[..., 0], split.depths[i], mask)
            errors.append(err)
            row["depth_mae"] = float(err.median()) if err.numel() else math.nan
            row["depth_mae_pct"] = 100.0 * row["depth_mae"] / length_scale
        rows.append(row)
        if render_dir is not None:
            _write_view(render_dir, split, i, out, target[i], depth, DEPTH_SPAN * length_scale)
    summary = mean_metrics(rows)
    if errors:
        pooled = torch.cat(errors)
        summary["depth_mae"] = float(pooled.median()) if pooled.numel() else math.nan
        summary["depth_mae_pct"] = 100.0 * summary["depth_mae"] / length_scale
    summary["lpips_weights"] = min(weights) if len(weights) == 1 else "; ".join(sorted(weights))
    return rows, summary, errors


def _write_view(render_dir: Path, split: Split, i: int, out: dict, target: torch.Tensor, depth: torch.Tensor | None,
                span: float) -> None:
    """``<name>.png``, ``<name>_depth.png`` and the ground truth beside them (``_gt``, ``_depth_gt``)."""
    from ..guard import out_path
    from ..visual import write_png

    name = split.names[i]
    write_png(out_path(render_dir, name, ".png"), to_uint8(out["rgb"]))
    write_png(out_path(render_dir, name, "_gt.png"), to_uint8(target))
    if depth is None:
        return
    gt = split.depths[i] if split.depths is not None else None
    mask = split.masks[i] if split.masks is not None else None
    valid = out["alpha"][..., 0] > 0.5 if "alpha" in out else torch.ones_like(depth[..., 0], dtype=torch.bool)
    pred, gt_img, _ = depth_display(depth[..., 0], gt, mask, valid, span)
    write_png(out_path(render_dir, name, "_depth.png"), pred)
    if gt_img is not None:
        write_png(out_path(render_dir, name, "_depth_gt.png"), gt_img)


def mean_metrics(rows: Iterable[dict[str, Any]]) -> dict[str, float]:
    """NaN-aware means of every numeric column of ``rows`` (``nan`` when no view has a value)."""
    rows = list(rows)
    keys = [k for k in (rows[0] if rows else {}) if isinstance(rows[0][k], (int, float)) and k not in ("depth_mae",)]
    out = {}
    for k in keys:
        vals = [float(r[k]) for r in rows if k in r and isinstance(r[k], (int, float)) and math.isfinite(float(r[k]))]
        out[k] = float(np.mean(vals)) if vals else math.nan
    out.pop("depth_mae_pct", None)  # split-level depth error is the pooled median, set by the caller
    return out


def write_views_csv(path: str | Path, rows: list[dict[str, Any]]) -> Path:
    """Per-view metrics as CSV (columns: union of the rows' keys, first-seen order)."""
    cols: list[str] = []
    for r in rows:
        cols += [k for k in r if k not in cols]
    from ..files import atomic_open

    path = Path(path)
    with atomic_open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols, restval="")
        w.writeheader()
        w.writerows(rows)
    return path
