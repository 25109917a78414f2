"""Stage-2 (colourisation) loss plugins: ``reference_l1``, ``pseudo_color``, ``tcm``, ``ccm``.

They read their targets from ``batch.extras``, which the stage-2 batch hook
(:func:`arcsem.colorize.stage2.ColorTargets.__call__`) fills once per batch from caches:

* ``is_reference`` ``[C]`` bool; ``reference`` ``[C,H,W,3]`` the artist colours (zeros elsewhere);
* ``pseudo`` ``[C,H,W,3]`` and ``pseudo_valid`` ``[C,H,W]`` bool;
* ``tcm_guidance``: per feature block ``[C,D_b,h_b,w_b]``; ``tcm_space`` the TCM loss space (images
  ``[C,H,W,3]`` -> per block ``[C,D_b,h_b,w_b]``: VGG, or cell-mean colours); ``tcm_downscale``;
* ``ccm_target`` ``[C,hc,wc,3]``, ``ccm_valid`` ``[C,hc,wc]``; ``ccm_downscale``.

Reference views are supervised by ``reference_l1`` only (paper weight 20); the other three terms
skip them. A term with no view to act on in a batch returns a zero that keeps the graph.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import Tensor

from arcsem.colorize.guidance import downscale, patch_means
from arcsem.errors import ConfigError
from arcsem.plugins import LOSSES, Batch, Loss, RenderOutput

__all__ = ["CCM", "TCM", "PseudoColor", "ReferenceL1", "ccm_distance", "masked_l1", "tcm_distance"]


def masked_l1(pred: Tensor, target: Tensor, valid: Tensor) -> Tensor:
    """Mean ``|pred - target|`` over channels and the pixels where ``valid [..]`` (pred ``[..., 3]``)."""
    n = valid.sum()
    if n == 0:
        return pred.sum() * 0.0
    return ((pred - target).abs() * valid[..., None]).sum() / (n * pred.shape[-1])


def tcm_distance(feats: list[Tensor], guidance: list[Tensor]) -> Tensor:
    """``sum_blocks mean_locations (1 - cos(F, G))`` for per-block features ``[C, D, h, w]``."""
    total = feats[0].new_zeros(())
    for f, g in zip(feats, guidance):
        total = total + (1.0 - torch.nn.functional.cosine_similarity(f, g, dim=1, eps=1e-8)).mean()
    return total


def ccm_distance(render_means: Tensor, target: Tensor, valid: Tensor) -> Tensor:
    """``mean over valid cells of ||mean(render patch) - target||^2``; means ``[C, hc, wc, 3]``."""
    n = valid.sum()
    if n == 0:
        return render_means.sum() * 0.0
    return (((render_means - target) ** 2).sum(-1) * valid).sum() / n


def _extras(batch: Batch, key: str, who: str):
    ex = batch.extras or {}
    if key not in ex:
        raise ConfigError(f"loss '{who}' needs batch.extras['{key}']: it runs in stage 2 (stage=color) only")
    return ex[key]


@LOSSES.register("reference_l1")
class ReferenceL1(Loss):
    """L1 to the artist colour on reference views (whole image); paper weight 20."""

    batch_modes: ClassVar[frozenset[str]] = frozenset({"image"})

    @dataclass
    class Config:
        weight: float = 20.0
        start_step: int = 0

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        is_ref = _extras(batch, "is_reference", self.name).to(out["rgb"].device)
        ref = _extras(batch, "reference", self.name)
        valid = is_ref[:, None, None].expand(out["rgb"].shape[:3])
        return masked_l1(out["rgb"], ref, valid)


@LOSSES.register("pseudo_color")
class PseudoColor(Loss):
    """``mean |C_pseudo - C_render|`` over pixels of non-reference views that have a pseudo-colour."""

    batch_modes: ClassVar[frozenset[str]] = frozenset({"image"})

    @dataclass
    class Config:
        weight: float = 1.0  # lambda_pc
        start_step: int = 0

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        is_ref = _extras(batch, "is_reference", self.name)
        valid = _extras(batch, "pseudo_valid", self.name) & ~is_ref[:, None, None]
        return masked_l1(out["rgb"], _extras(batch, "pseudo", self.name), valid)


@LOSSES.register("tcm")
class TCM(Loss):
    """Template-based correspondence: ``1 - cos`` between the render and the guidance in the TCM loss space
    (VGG features, the paper; or cell-mean colours: ``colorize.tcm_space``)."""

    batch_modes: ClassVar[frozenset[str]] = frozenset({"image"})

    @dataclass
    class Config:
        weight: float = 1.0  # lambda_tcm (paper 1)
        start_step: int = 0

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        keep = ~_extras(batch, "is_reference", self.name)
        if not bool(keep.any()):
            return out["rgb"].sum() * 0.0
        space = _extras(batch, "tcm_space", self.name)
        img = downscale(out["rgb"][keep], int(_extras(batch, "tcm_downscale", self.name)))
        guide = [g[keep] for g in _extras(batch, "tcm_guidance", self.name)]
        return tcm_distance(space(img), guide)


@LOSSES.register("ccm")
class CCM(Loss):
    """Coarse colour matching: squared distance of patch-mean colours to the matched reference patches."""

    batch_modes: ClassVar[frozenset[str]] = frozenset({"image"})

    @dataclass
    class Config:
        weight: float = 1.0  # lambda_cc (Ref-NPR 5; ArCSEM's command line 0; paper: used)
        start_step: int = 0

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        cell = int(_extras(batch, "ccm_downscale", self.name))
        valid = _extras(batch, "ccm_valid", self.name) & ~_extras(batch, "is_reference", self.name)[:, None, None]
        return ccm_distance(patch_means(out["rgb"], cell), _extras(batch, "ccm_target", self.name), valid)
