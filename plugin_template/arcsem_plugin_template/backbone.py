"""A tiny backbone: one learnable colour everywhere, fully opaque, at a constant depth.

It implements the hooks a backbone must (``render``, ``param_groups``) and one it may
(``learning_rates``); every other hook keeps the default of :class:`arcsem.plugins.Backbone`."""
from __future__ import annotations

import torch
from torch import nn

from arcsem.configs import GroupSchedule
from arcsem.plugins import Backbone

from .config import ConstantConfig

__all__ = ["ConstantBackbone"]


class ConstantBackbone(Backbone):
    """Renders one learnable colour: ``rgb [C,H,W,3]``, ``alpha`` 1, ``depth`` = ``Config.depth``."""

    provides = frozenset({"rgb", "alpha", "depth"})
    Config = ConstantConfig

    def __init__(self, cfg: ConstantConfig, scene=None, **runtime):
        super().__init__(cfg, scene)
        self.color = nn.Parameter(torch.full((3,), float(cfg.value)))

    def render(self, cams, **kw):
        C, H, W = len(cams), cams.height, cams.width
        ones = torch.ones(C, H, W, 1, device=self.color.device)
        return {"rgb": ones * self.color, "alpha": ones, "depth": ones * self.cfg.depth}

    def param_groups(self, stage):
        return {"color": [self.color]}  # the same group in stage 1 (grey) and stage 2 (colour)

    def learning_rates(self, stage):
        return {"color": GroupSchedule(lr=self.cfg.lr)}  # constant; GroupSchedule(lr, lr_final) decays
