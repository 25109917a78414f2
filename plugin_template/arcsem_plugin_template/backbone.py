"""A tiny backbone: one learnable colour everywhere, fully opaque, at a constant depth.

Enough to exercise the plugin machinery (entry point, Config validation, YAML search path)."""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from arcsem.plugins import BACKBONES, Backbone

__all__ = ["ConstantBackbone"]


@BACKBONES.register("constant")
class ConstantBackbone(Backbone):
    """Renders one learnable colour: ``rgb [C,H,W,3]``, ``alpha`` 1, ``depth`` = ``Config.depth``."""

    provides = frozenset({"rgb", "alpha", "depth"})

    @dataclass
    class Config:
        value: float = 0.5  # initial grey level in [0, 1]
        depth: float = 1.0  # z-depth reported for every pixel
        lr: float = 1e-2  # learning rate of the colour

    def __init__(self, cfg: Config, scene=None, **runtime):
        super().__init__(cfg, scene)
        self.color = nn.Parameter(torch.full((3,), float(cfg.value)))

    def render(self, cams, **kw):
        C, H, W = len(cams), cams.height, cams.width
        ones = torch.ones(C, H, W, 1, device=self.color.device)
        return {"rgb": ones * self.color, "alpha": ones, "depth": ones * self.cfg.depth}

    def param_groups(self, stage):
        return {"color": [self.color]}
