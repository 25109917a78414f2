"""Shared by the trainer and evaluation tests: a tiny pinhole scene, a tiny image backbone
(``_tiny_image``), loop settings, the 2DGS/3DGS loss mix."""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from arcsem.cameras import Cameras, look_at
from arcsem.plugins import BACKBONES, Backbone
from arcsem.scene import Scene, Split
from arcsem.train.loop import LoopConfig


def tiny_scene(n: int = 4, w: int = 24, h: int = 16, test: int = 2, seed: int = 0) -> Scene:
    """``n`` training + ``test`` held-out pinhole cameras on an arc; images = one smooth pattern x gain."""
    g = torch.Generator().manual_seed(seed)
    ang = torch.linspace(-0.5, 0.5, n + test)
    eye = torch.stack([4 * torch.sin(ang), torch.full_like(ang, -0.5), -4 * torch.cos(ang)], -1)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0]))
    K = torch.tensor([[30.0, 0, w / 2], [0, 30.0, h / 2], [0, 0, 1.0]]).repeat(n + test, 1, 1)
    ids = torch.cat([torch.arange(n), torch.full((test,), -1)])
    cams = Cameras(w2c, K, w, h, "pinhole", image_ids=ids)
    yy, xx = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
    base = (0.3 + 0.4 * xx * yy)[None, ..., None].expand(n + test, h, w, 3)
    gain = 1 + 0.05 * torch.randn(n + test, 1, 1, 1, generator=g)
    clean = base.clone()
    imgs = (base * gain + 0.01 * torch.randn(n + test, h, w, 3, generator=g)).clamp(0, 1)
    masks = torch.zeros(n + test, h, w, dtype=torch.bool)
    masks[:, 3:-3, 4:-4] = True
    depths = torch.where(masks, torch.tensor(2.0), torch.tensor(0.0))
    tr = [i for i in range(n + test) if i < n]
    te = list(range(n, n + test))
    full = Split([f"v{i}" for i in range(n + test)], cams, imgs, masks, depths, clean=clean)
    return Scene("tiny", full.subset(tr), full.subset(te), torch.tensor([[-1.0] * 3, [1.0] * 3]))


def loop(steps, **kw):
    return LoopConfig(steps=steps, progress=False, log_every=10, checkpoint_every=kw.pop("checkpoint_every", 0), **kw)


L1_DSSIM = {"l1": {"weight": 0.8}, "dssim": {"weight": 0.2}}


@BACKBONES.register("_tiny_image")
class TinyImage(Backbone):
    """One learned ``[H,W,3]`` image for every camera; ``gain`` is a second parameter group."""

    provides = frozenset({"rgb", "alpha", "depth"})

    @dataclass
    class Config:
        lr_image: float = 0.05
        lr_gain: float = 0.01

    def __init__(self, cfg, scene=None, act=None):
        super().__init__(cfg)
        h, w = scene.train.cameras.height, scene.train.cameras.width
        self.logits = nn.Parameter(0.1 * torch.randn(h, w, 3))
        self.gain = nn.Parameter(torch.zeros(1))
        self.act = act
        self.register_buffer("hook_calls", torch.zeros(2, dtype=torch.long))

    def render(self, cams, **kw):
        C = len(cams)
        rgb = torch.sigmoid(self.logits + self.gain)[None].expand(C, -1, -1, -1)
        if self.act is not None:
            rgb = self.act.apply(rgb.reshape(C, -1, 3), cams.image_ids).reshape(rgb.shape)
        ones = torch.ones_like(rgb[..., :1])
        return {"rgb": rgb, "alpha": ones, "depth": 2.0 * ones + 0.01 * self.logits[None, ..., :1]}

    def param_groups(self, stage):
        return {"image": [self.logits], "gain": [self.gain]} if stage == "geometry" else {"image": [self.logits]}

    def pre_backward(self, step, out):
        self.hook_calls[0] += 1

    def post_backward(self, step, out, optimizers):
        self.hook_calls[1] += 1
        assert set(optimizers) >= {"image"}

    def num_primitives(self):
        return self.logits.shape[0] * self.logits.shape[1]
