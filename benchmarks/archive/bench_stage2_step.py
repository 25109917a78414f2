"""Stage-2 training step vs stage-1 step: same backbone, same resolution, same Gaussians.

Stage 1: l1 0.8 + dssim 0.2, all geometry groups. Stage 2: reference_l1 + pseudo_color + TCM + CCM
(VGG16 at 1/4 resolution; random weights here if the ImageNet file is missing: same cost), colour
groups only. Pseudo-colours and guidance are prepared before timing (they are computed once per run).

    .venv/bin/python benchmarks/archive/bench_stage2_step.py [--width 128 --height 96 --steps 20 --backbone gs2d]
"""
from __future__ import annotations

import argparse
import copy
import dataclasses
import statistics
import warnings

import torch

from arcsem.colorize.analytic import analytic_scene
from arcsem.colorize.guidance import Guidance
from arcsem.colorize.pseudocolor import pseudo_colors
from arcsem.colorize.references import load_references
from arcsem.colorize.stage2 import ColorTargets
from arcsem.colorize.vgg import get_vgg
from arcsem.plugins import BACKBONES
from arcsem.train import LoopConfig, build_losses, train


def step_times(bb0, scene, stage, losses, hook, steps):
    """Mean step time of ``steps`` steps on a fresh copy of ``bb0`` (after 2 warm-up steps)."""
    bb = copy.deepcopy(bb0)
    train(bb, scene.train, losses, LoopConfig(steps=2, stage=stage, progress=False, checkpoint_every=0),
          batch_hook=hook)
    bb = copy.deepcopy(bb0)
    loop = LoopConfig(steps=steps, stage=stage, progress=False, checkpoint_every=0, resume="never")
    res = train(bb, scene.train, losses, loop, batch_hook=hook)
    return res.time_s / max(res.steps, 1)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--height", type=int, default=96)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--backbone", default="gs2d")
    ap.add_argument("--points", type=int, default=20000)
    a = ap.parse_args()
    warnings.simplefilter("ignore")
    torch.manual_seed(0)
    scene = dataclasses.replace(analytic_scene(16, 2, a.width, a.height), points=None, point_colors=None)
    bb = BACKBONES.build({"name": a.backbone, "random_init_points": a.points}, scene=scene)
    refs = load_references(scene, "five")
    split = scene.train
    pseudo, valid = pseudo_colors(split.cameras, split.depths, split.masks, refs.indices.tolist(), refs.images,
                                  progress=False)
    vgg = get_vgg("vgg16")
    guid = Guidance(vgg, vgg, split.images, refs.indices.tolist(), refs.images, 4, 16)
    for i in range(len(split)):
        guid.matches(i)
    hook = ColorTargets(refs, pseudo, valid, guid, vgg, 4, 16)
    l1 = build_losses({"l1": {"weight": 0.8}, "dssim": {"weight": 0.2}}, bb.provides, bb.batch_mode)
    l2 = build_losses({"reference_l1": {"weight": 20}, "pseudo_color": {"weight": 1}, "tcm": {"weight": 1},
                       "ccm": {"weight": 5}}, bb.provides, bb.batch_mode)
    s1, s2 = [], []
    for _ in range(a.repeats):
        s1.append(step_times(bb, scene, "geometry", l1, None, a.steps))
        s2.append(step_times(bb, scene, "color", l2, hook, a.steps))
    m1, m2 = statistics.median(s1), statistics.median(s2)
    print(f"{a.backbone}, {a.width}x{a.height}, {len(bb.model) if hasattr(bb, 'model') else '?'} primitives, "
          f"{a.steps} steps x {a.repeats} repeats (median of per-step means)")
    print(f"  stage 1 step: {1000 * m1:.1f} ms  (runs {', '.join(f'{1000 * x:.1f}' for x in s1)})")
    print(f"  stage 2 step: {1000 * m2:.1f} ms  (runs {', '.join(f'{1000 * x:.1f}' for x in s2)})")
    print(f"  ratio stage 2 / stage 1: {m2 / m1:.2f}x  (features: {vgg.label()})")


if __name__ == "__main__":
    main()
