"""Operators a stage-1 step dispatches, counted on the CPU: what a GPU's host would issue one by one.

On a GPU the demo's step waits on the host issuing operators (benchmarks/results/gpu/README.md: about 16 us a call),
so their number bounds the steps per second whatever the kernels cost. This counts them on any machine: stage 1 of
``experiment=demo`` through the real trainer, and over ``--window`` steps after ``--skip`` every operator below
autograd (a ``TorchDispatchMode``; the backward pass's too), grouped by the project function that issued it or,
in the backward pass, by the autograd node::

    python benchmarks/gpu/op_count.py -- backbone.rasterizer=torch     # the PyTorch rasteriser (`auto` on CUDA before the Triton kernels)
    TRITON_INTERPRET=1 python benchmarks/gpu/op_count.py --skip 1 --window 2 -- backbone.rasterizer=triton train.width=48
        # the Triton kernels through Triton's CPU interpreter (a launch counts one; slow: ~20 min for 3 steps)
    python benchmarks/gpu/op_count.py --top 30 -- backbone=gs3d backbone.rasterizer=torch
    python benchmarks/gpu/op_count.py --ops loop.py --ops cameras.py      # which operators those sites issue

The profiler on a GPU counts more (``aten_calls_per_step`` in gpu_check.json includes the operators an operator
calls); this count is the dispatcher's below autograd, comparable between commits on the same machine.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import traceback
from collections import Counter
from pathlib import Path

import torch
from torch.utils._python_dispatch import TorchDispatchMode

ROOT = Path(__file__).resolve().parents[2]
PROJECT = ("arcsem", "backbones", "losses")


def _site() -> str:
    node = torch._C._current_autograd_node()
    if node is not None:
        return "backward: " + node.name()
    for f in reversed(traceback.extract_stack()[:-3]):
        p = Path(f.filename)
        if ROOT in p.parents and p.relative_to(ROOT).parts[0] in PROJECT:
            return f"{p.relative_to(ROOT)}:{f.name}"
    return "outside the project"


class OpCount(TorchDispatchMode):
    """Counts every dispatched operator by :func:`_site`; a Triton kernel launch (``rasterizer=triton``) counts as one
    operator, ``triton kernel: <name>``, whatever Triton's CPU interpreter dispatches to run it (:func:`_launches`)."""

    def __init__(self):
        super().__init__()
        self.sites: Counter = Counter()
        self.ops: Counter = Counter()  # (site, operator) -> count
        self.paused = False

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        if not self.paused:
            site = _site()
            self.sites[site] += 1
            self.ops[site, str(func.overloadpacket.__name__)] += 1
        return func(*args, **(kwargs or {}))


def _launches(mode: OpCount):
    """Under ``TRITON_INTERPRET=1``: count each kernel launch once and pause the count while the interpreter copies
    the launch's tensors (on a GPU a launch is one call, not the interpreter's copies). Returns an undo function."""
    try:
        from triton.runtime import interpreter
    except ImportError:
        return lambda: None
    call = interpreter.GridExecutor.__call__

    def counted(self, *args, **kwargs):
        if mode.paused:
            return call(self, *args, **kwargs)
        mode.sites[f"triton kernel: {getattr(self.fn, '__name__', 'kernel')}"] += 1
        mode.paused = True
        try:
            return call(self, *args, **kwargs)
        finally:
            mode.paused = False

    interpreter.GridExecutor.__call__ = counted
    return lambda: setattr(interpreter.GridExecutor, "__call__", call)


def count(overrides: list[str], skip: int, window: int) -> tuple[Counter, Counter, int]:
    """Operators of steps ``skip``..``skip + window`` of stage 1 (the demo job with ``overrides``, on the CPU) by
    site and by ``(site, operator)``, and the model's primitives at the end."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from stage1_profile import compose

    from arcsem.app import seed_everything
    from arcsem.data import load_scene
    from arcsem.train import loop as loop_module
    from arcsem.train.loop import LoopConfig, train
    from arcsem.train.stage1 import act_config, build_model, prepare_scene, stage1_losses, train_config

    cfg = compose(["experiment=demo", "device=cpu", *overrides])
    seed_everything(int(cfg.seed))
    tc = train_config(cfg)
    scene = prepare_scene(load_scene(cfg.dataset), tc)
    backbone, act = build_model(cfg, scene, tc)
    losses = stage1_losses(cfg, tc, act)
    loop = LoopConfig(steps=skip + window, stage="geometry", batch_views=tc.batch_views, log_every=tc.log_every,
                      checkpoint_every=0, resume="never", seed=int(cfg.seed), progress=False)
    mode = OpCount()

    def on_step(s: int) -> None:  # after step s: count steps s+1 .. s+window
        if s == skip:
            mode.__enter__()
        if s == skip + window:
            mode.__exit__(None, None, None)

    periodic = loop_module._periodic  # called after every step with the run
    loop_module._periodic = lambda run, *a: (periodic(run, *a), on_step(run.step))
    undo = _launches(mode)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            train(backbone, scene.train, losses, loop, optim=tc.optim, ckpt_dir=Path(tmp) / "ck", act=act,
                  act_lr=act_config(cfg).lr)
    finally:
        loop_module._periodic = periodic
        undo()
    return mode.sites, mode.ops, int(backbone.num_primitives())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skip", type=int, default=60, help="steps before the counted window")
    ap.add_argument("--window", type=int, default=10, help="steps counted")
    ap.add_argument("--top", type=int, default=20, help="sites listed")
    ap.add_argument("--ops", action="append", default=[], metavar="SITE",
                    help="also list the operators of the sites containing SITE (repeatable)")
    ap.add_argument("overrides", nargs="*")
    a = ap.parse_args()
    sites, ops, prims = count(a.overrides, a.skip, a.window)
    total = sum(sites.values())
    print(f"{total / a.window:.1f} operators a step (steps {a.skip + 1}-{a.skip + a.window}, {prims} primitives)")
    for site, n in sites.most_common(a.top):
        print(f"{n / a.window:8.1f}  {site}")
    for want in a.ops:
        print(f"operators of the sites containing '{want}':")
        for (site, op), n in sorted(ops.items(), key=lambda kv: -kv[1]):
            if want in site:
                print(f"{n / a.window:8.1f}  {site}  {op}")


if __name__ == "__main__":
    main()
