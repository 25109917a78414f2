"""Trainer overhead per step: ``arcsem.train.train`` vs a bare loop doing the same work.

The backbone is a trivial learned image (render cost ~0), so the ratio is an upper bound on what the
loop adds (schedules, sampler, hooks, finite checks of loss/gradients/parameters, history).

    .venv/bin/python benchmarks/bench_trainer.py [--width 192 --height 128 --steps 200 --repeats 5]
"""
from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import dataclass

import torch
from torch import nn

from arcsem.cameras import Cameras, look_at
from arcsem.plugins import BACKBONES, Backbone
from arcsem.scene import Split
from arcsem.train import LoopConfig, build_losses, train


@BACKBONES.register("_bench_image")
class BenchImage(Backbone):
    provides = frozenset({"rgb", "alpha", "depth"})

    @dataclass
    class Config:
        lr_image: float = 0.01

    def __init__(self, cfg, scene=None, h: int = 128, w: int = 192):
        super().__init__(cfg)
        self.logits = nn.Parameter(torch.zeros(h, w, 3))

    def render(self, cams, **kw):
        rgb = torch.sigmoid(self.logits)[None].expand(len(cams), -1, -1, -1)
        one = torch.ones_like(rgb[..., :1])
        return {"rgb": rgb, "alpha": one, "depth": one}

    def param_groups(self, stage):
        return {"image": [self.logits]}


def split(n: int, w: int, h: int) -> Split:
    ang = torch.linspace(-0.5, 0.5, n)
    eye = torch.stack([4 * torch.sin(ang), torch.zeros(n), -4 * torch.cos(ang)], -1)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0]))
    K = torch.tensor([[200.0, 0, w / 2], [0, 200.0, h / 2], [0, 0, 1]]).repeat(n, 1, 1)
    cams = Cameras(w2c, K, w, h, image_ids=torch.arange(n))
    return Split([f"v{i}" for i in range(n)], cams, torch.rand(n, h, w, 3))


def bare(bb, sp, losses, steps):
    opt = torch.optim.Adam([bb.logits], lr=0.01, eps=1e-15)
    for s in range(steps):
        i = s % len(sp)
        from arcsem.plugins import Batch
        batch = Batch(sp.cameras[i : i + 1], sp.images[i : i + 1], torch.tensor([i]))
        out = bb.render(batch.cameras)
        total, _ = losses(out, batch, s)
        opt.zero_grad(set_to_none=True)
        total.backward()
        opt.step()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--width", type=int, default=192)
    ap.add_argument("--height", type=int, default=128)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    sp = split(8, a.width, a.height)
    losses = build_losses({"l1": {"weight": 0.8}, "dssim": {"weight": 0.2}}, BenchImage.provides)
    t_loop, t_bare = [], []
    for _ in range(a.repeats):
        bb = BenchImage(BenchImage.Config(), h=a.height, w=a.width)
        t = time.perf_counter()
        train(bb, sp, losses, LoopConfig(steps=a.steps, progress=False, log_every=50, checkpoint_every=0))
        t_loop.append((time.perf_counter() - t) / a.steps * 1e3)
        bb = BenchImage(BenchImage.Config(), h=a.height, w=a.width)
        t = time.perf_counter()
        bare(bb, sp, losses, a.steps)
        t_bare.append((time.perf_counter() - t) / a.steps * 1e3)
    ml, mb = statistics.median(t_loop), statistics.median(t_bare)
    print(f"{a.width}x{a.height}, {a.steps} steps x {a.repeats} repeats, {a.threads} thread(s)")
    print(f"arcsem.train.train : median {ml:.2f} ms/step  (runs: {', '.join(f'{x:.2f}' for x in t_loop)})")
    print(f"bare loop          : median {mb:.2f} ms/step  (runs: {', '.join(f'{x:.2f}' for x in t_bare)})")
    print(f"ratio train/bare   : {ml / mb:.2f}x  (overhead {ml - mb:+.2f} ms/step)")


if __name__ == "__main__":
    main()
