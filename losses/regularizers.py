"""Regulariser loss plugin ``tv``: total variation of a voxel grid (Plenoxels).

The backbone computes the weighted TV on its random voxel subset (``lambda_tv`` on density,
``lambda_tv_sh`` on SH, both in the backbone's Config, svox2 defaults) and returns it as ``out["tv"]``
(a scalar, 0 when no gradients are taken); this loss passes it on, so the trainer's ``weight``
(default 1) scales both terms together.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from arcsem.plugins import LOSSES, Batch, Loss, RenderOutput

__all__ = ["TV"]


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
