"""Regulariser loss plugins: ``tv`` (total variation of a voxel grid, Plenoxels) and ``act_prior``
(a Gaussian prior holding each image's ACT near the identity).

The backbone computes the weighted TV on its random voxel subset (``lambda_tv`` on density,
``lambda_tv_sh`` on SH, both in the backbone's Config, svox2 defaults) and returns it as ``out["tv"]``
(a scalar, 0 when no gradients are taken); this loss passes it on, so the trainer's ``weight``
(default 1) scales both terms together.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from arcsem.errors import ConfigError
from arcsem.plugins import LOSSES, Batch, Loss, RenderOutput

__all__ = ["TV", "ACTPrior"]


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


@LOSSES.register("act_prior")
class ACTPrior(Loss):
    """``mean over the batch's images of sum_k (W_ik - 1)^2 + b_ik^2``: ACT pulled towards the identity.

    Only the images in the batch are penalised, so an image's transform feels the prior exactly when
    its data term moves it (the trainer's Adam would otherwise pull unvisited images every step).
    Needs the ACT module (``act=`` at build time; stage 1 passes it). An experiment, in no preset:
    with a 20x ACT rate it stops ACT from taking over view-dependent brightness, but held-out PSNR
    stays below 2DGS without ACT (benchmarks/results/README.md, "What ACT learns").
    """

    @dataclass
    class Config:
        weight: float = 1.0
        start_step: int = 0

    def __init__(self, cfg, act=None, **runtime):
        super().__init__(cfg)
        if act is None:
            raise ConfigError("loss 'act_prior' needs ACT: choose act=paper or act=code, or drop the term")
        self._act = [act]  # a list: not a submodule (the trainer optimises ACT as its own group)

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        act = self._act[0]
        ids = batch.ray_image_ids if batch.ray_image_ids is not None else batch.cameras.image_ids
        ids = ids.long().unique().to(act.weight.device)
        if (ids < 0).any():
            raise ValueError("act_prior: the batch holds novel views (image id -1); ACT exists for training images only")
        return ((act.weight[ids] - 1) ** 2 + act.bias[ids] ** 2).sum(-1).mean()
