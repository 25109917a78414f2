"""The trainer, stage 2 and the exports call only the hooks that :class:`arcsem.plugins.Backbone` declares.

A minimal backbone records every attribute that code in ``arcsem`` (outside ``arcsem.plugins``) reads on it
during a whole ``stage=all`` run (training, checkpoints, evaluation, export, colourisation); each must be a
name of the base class (its declared hooks, or ``nn.Module``'s API).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass

import cv2
import numpy as np
import torch
from conftest import write_transforms_scene
from omegaconf import OmegaConf, open_dict
from test_config import compose_with
from torch import nn

from arcsem import app
from arcsem.plugins import BACKBONES, Backbone

SEEN: set[str] = set()


@BACKBONES.register("_recording")
class Recording(Backbone):
    """A grey plane at a learnable depth with a learnable colour; records what arcsem asks of it."""

    provides = frozenset({"rgb", "alpha", "depth"})

    @dataclass
    class Config:
        lr_color: float = 1e-2  # the base class's default learning_rates() reads lr_<group>
        lr_depth: float = 1e-3

    def __init__(self, cfg, scene=None, **runtime):
        super().__init__(cfg, scene)
        self.color = nn.Parameter(torch.full((3,), 0.5))
        self.plane = nn.Parameter(torch.tensor(4.0))

    def __getattribute__(self, name):
        caller = sys._getframe(1).f_globals.get("__name__", "")
        if caller.startswith("arcsem") and not caller.startswith("arcsem.plugins") and not name.startswith("__"):
            SEEN.add(name)
        return super().__getattribute__(name)

    def render(self, cams, **kw):
        ones = torch.ones(len(cams), cams.height, cams.width, 1, device=self.color.device)
        return {"rgb": ones * self.color, "alpha": ones, "depth": ones * self.plane}

    def param_groups(self, stage):
        return {"color": [self.color], "depth": [self.plane]} if stage == "geometry" else {"color": [self.color]}


def test_a_whole_run_uses_only_declared_hooks(tmp_path):
    scene = write_transforms_scene(tmp_path / "scene", n=3, w=24, h=16)
    cv2.imwrite(str(tmp_path / "view_01.png"), np.full((16, 24, 3), (0, 0, 200), np.uint8))
    cfg = compose_with("dataset=transforms", f"dataset.path={scene.parent}", "stage=all", "act=none",
                       "train.width=null", "train.steps=3", "train.eval.lpips=false", "train.progress=false",
                       "colorize.steps=2", "colorize.progress=false", "colorize.eval.lpips=false",
                       "colorize.losses.tcm.weight=0", "colorize.losses.ccm.weight=0",
                       f"colorize.references={tmp_path / 'view_01.png'}", f"cache_dir={tmp_path / 'cache'}")
    with open_dict(cfg):
        cfg.backbone = OmegaConf.create({"name": "_recording"})
        cfg.train.losses = OmegaConf.create({"l1": {"weight": 0.8}, "dssim": {"weight": 0.2}})  # not 2DGS's
    SEEN.clear()
    metrics = app.run(cfg, run_dir=tmp_path / "run")
    assert metrics["status"] == "complete" and metrics["completed_stages"] == ["gray", "color"]
    declared = set(dir(Backbone)) | set(Backbone.__annotations__)  # name: ClassVar[str] is declared too
    assert {"render", "param_groups", "learning_rates", "set_act", "export_suffix", "colour_operator"} <= SEEN  # it did look
    assert SEEN <= declared, f"called but not declared on Backbone: {sorted(SEEN - declared)}"
