"""Stage-2 (colourisation) loss plugins: ``reference_l1``, ``pseudo_color``, ``tcm``, ``ccm``.

They read their targets from ``batch.color`` (:class:`arcsem.plugins.ColorTargets`), which the stage-2 batch
hook fills once per batch from caches, and declare ``needs = {"color"}``: they can only be terms of
``colorize.losses``. Reference views are supervised by ``reference_l1`` only (paper weight 20); the other three
terms skip them. A term with no view to act on in a batch returns a zero that keeps the graph.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import Tensor

from arcsem.errors import ConfigError
from arcsem.imageops import downscale, patch_means
from arcsem.plugins import LOSSES, Batch, ColorTargets, Loss, RenderOutput

__all__ = ["CCM", "TCM", "PseudoColor", "ReferenceL1", "ccm_distance", "masked_l1", "tcm_distance"]


def masked_l1(pred: Tensor, target: Tensor, valid: Tensor) -> Tensor:
    """Mean ``|pred - target|`` over channels and the pixels where ``valid [..]`` (pred ``[..., 3]``); 0 (keeping the
    graph) where no pixel is valid. Computed without reading anything back from the device."""
    n = valid.sum() * pred.shape[-1]
    return ((pred - target).abs() * valid[..., None]).sum() / n.clamp_min(1)


def tcm_distance(feats: list[Tensor], guidance: list[Tensor], views: Tensor | None = None,
                 valid: list[Tensor] | None = None) -> Tensor:
    """``sum_blocks mean_locations (1 - cos(F, G))`` for per-block features ``[C, D, h, w]``, over the views where
    ``views [C]`` (bool; default all; none: 0, keeping the graph) and the locations where ``valid`` (per block
    ``[C, h, w]`` bool: the matches that passed the guard; default all; a view with none adds 0)."""
    keep = torch.ones(feats[0].shape[0], dtype=torch.bool, device=feats[0].device) if views is None else views
    total = feats[0].new_zeros(())
    for b, (f, g) in enumerate(zip(feats, guidance)):
        d = 1.0 - torch.nn.functional.cosine_similarity(f, g, dim=1, eps=1e-8)  # [C, h, w]
        if valid is None:
            per_view = d.flatten(1).mean(1)  # [C]
        else:
            m = valid[b].to(d.dtype)
            per_view = (d * m).flatten(1).sum(1) / m.flatten(1).sum(1).clamp_min(1)
        total = total + (per_view * keep).sum() / keep.sum().clamp_min(1)
    return total


def ccm_distance(render_means: Tensor, target: Tensor, valid: Tensor) -> Tensor:
    """``mean over valid cells of ||mean(render patch) - target||^2``; means ``[C, hc, wc, 3]`` (none valid: 0)."""
    return (((render_means - target) ** 2).sum(-1) * valid).sum() / valid.sum().clamp_min(1)


def _targets(batch: Batch, who: str, *fields: str) -> ColorTargets:
    """``batch.color``, checked to hold ``fields`` (a stage-2 loss used elsewhere stops with a clear error)."""
    t = batch.color
    if t is None:
        raise ConfigError(f"loss '{who}' needs the colourisation targets: it runs in stage 2 (stage=color) only")
    missing = [f for f in fields if getattr(t, f) is None]
    if missing:
        raise ConfigError(f"loss '{who}' needs {', '.join(missing)} (TCM/CCM guidance), which this stage-2 run has not")
    return t


@LOSSES.register("reference_l1")
class ReferenceL1(Loss):
    """L1 to the artist colour on reference views (whole image); paper weight 20."""

    batch_modes: ClassVar[frozenset[str]] = frozenset({"image"})
    needs: ClassVar[frozenset[str]] = frozenset({"color"})

    @dataclass
    class Config:
        weight: float = 20.0
        start_step: int = 0

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        t = _targets(batch, self.name)
        valid = t.is_reference.to(out["rgb"].device)[:, None, None].expand(out["rgb"].shape[:3])
        return masked_l1(out["rgb"], t.reference, valid)


@LOSSES.register("pseudo_color")
class PseudoColor(Loss):
    """``mean |C_pseudo - C_render|`` over pixels of non-reference views that have a pseudo-colour."""

    batch_modes: ClassVar[frozenset[str]] = frozenset({"image"})
    needs: ClassVar[frozenset[str]] = frozenset({"color"})

    @dataclass
    class Config:
        weight: float = 1.0  # lambda_pc
        start_step: int = 0

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        t = _targets(batch, self.name)
        return masked_l1(out["rgb"], t.pseudo, t.pseudo_valid & ~t.is_reference[:, None, None])


@LOSSES.register("tcm")
class TCM(Loss):
    """Template-based correspondence: ``1 - cos`` between the render and the guidance in the TCM loss space
    (VGG features, the paper; or cell-mean colours: ``colorize.tcm_space``)."""

    batch_modes: ClassVar[frozenset[str]] = frozenset({"image"})
    needs: ClassVar[frozenset[str]] = frozenset({"color"})

    @dataclass
    class Config:
        weight: float = 1.0  # lambda_tcm (paper 1)
        start_step: int = 0

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        t = _targets(batch, self.name, "tcm_guidance", "tcm_space")
        if t.references_only or t.tcm_idle:  # nothing to pull (the other views have no guarded match): 0, its
            return out["rgb"].sum() * 0.0   # graph kept, without the feature pass
        img = downscale(out["rgb"], int(t.tcm_downscale))  # mixed batches: reference views masked out below
        return tcm_distance(t.tcm_space(img), t.tcm_guidance, ~t.is_reference, t.tcm_valid)


@LOSSES.register("ccm")
class CCM(Loss):
    """Coarse colour matching: squared distance of patch-mean colours to the matched reference patches."""

    batch_modes: ClassVar[frozenset[str]] = frozenset({"image"})
    needs: ClassVar[frozenset[str]] = frozenset({"color"})

    @dataclass
    class Config:
        weight: float = 1.0  # lambda_cc (Ref-NPR 5; ArCSEM's command line 0; paper: used)
        start_step: int = 0

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        t = _targets(batch, self.name, "ccm_target", "ccm_valid")
        if t.references_only or t.ccm_idle:
            return out["rgb"].sum() * 0.0
        valid = t.ccm_valid & ~t.is_reference[:, None, None]
        return ccm_distance(patch_means(out["rgb"], int(t.ccm_downscale)), t.ccm_target, valid)
