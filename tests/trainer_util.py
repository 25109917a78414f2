"""Builders shared by the trainer tests: a tiny pinhole scene, loop settings, the 2DGS/3DGS loss mix."""
from __future__ import annotations

import torch

from arcsem.cameras import Cameras, look_at
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
