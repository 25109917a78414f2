"""Regulariser loss plugins.

* ``tv``: total variation of a voxel grid (Plenoxels). The backbone computes the weighted TV on its random voxel
  subset (``lambda_tv`` on density, ``lambda_tv_sh`` on SH, both in the backbone's Config, svox2 defaults) and
  returns it as ``out["tv"]`` (a scalar, 0 when no gradients are taken); this loss passes it on, so the trainer's
  ``weight`` (default 1) scales both terms together.
* ``opacity_beta``: the beta-distribution prior of Neural Volumes (Lombardi et al. 2019; svox2's ``lambda_beta``)
  on each ray's opacity ``a = out["alpha"]`` (for Plenoxels the grid's, before the background):
  ``mean log(a + eps) + log(1 - a + eps)``, lowest at 0 and 1. A ray either meets the specimen or passes to the
  background; the prior keeps the grid from turning translucent where a background can copy what it shows.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from arcsem.plugins import LOSSES, Batch, Loss, RenderOutput

__all__ = ["TV", "OpacityBeta"]


@LOSSES.register("tv")
class TV(Loss):
    """``out["tv"]``: the backbone's weighted TV of density and SH on a random 1% of its voxels."""

    requires = frozenset({"tv"})

    @dataclass
    class Config:
        weight: float = 1.0
        start_step: int = 0

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        tv = out.get("tv")
        if tv is None:
            ref = out["rgb"]
            return torch.zeros((), dtype=ref.dtype, device=ref.device)
        return tv


@LOSSES.register("opacity_beta")
class OpacityBeta(Loss):
    """``mean log(a + eps) + log(1 - a + eps)`` over the rays' opacities ``out["alpha"]`` (module docstring)."""

    requires = frozenset({"alpha"})

    @dataclass
    class Config:
        weight: float = 1e-3
        start_step: int = 0
        eps: float = 1e-3  # keeps the log finite at opacity 0 and 1 (its slope there: ~1 / eps)

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        a, eps = out["alpha"], float(self.cfg.eps)
        return (torch.log(a + eps) + torch.log(1.0 - a + eps)).mean()
