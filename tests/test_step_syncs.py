"""A training step waits for no device: nothing in the steady-state step reads a value back to the host, makes a
tensor from Python data or computes a data-dependent shape, except the PyTorch rasteriser's tile binning (its
lists' sizes depend on the data; gsplat's CUDA binning reads one count too). Checked on the CPU with a dispatch
mode that sees every operator (on a GPU each of these is a host synchronisation; ``device=cuda`` takes the
PyTorch rasteriser, ``rasterizer=torch`` here); the GPU's own count is benchmarks/gpu/stage1_profile.py's."""
from __future__ import annotations

import traceback
from collections import Counter
from pathlib import Path

import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode
from trainer_util import tiny_scene

from arcsem.act import ACT
from arcsem.configs import OptimConfig
from arcsem.plugins import BACKBONES
from arcsem.train import loop as loop_module
from arcsem.train.losses import build_losses

ROOT = Path(__file__).resolve().parents[1]
READS = {"aten._local_scalar_dense.default", "aten.nonzero.default", "aten.masked_select.default",
         "aten._unique2.default", "aten.unique_dim.default", "aten.repeat_interleave.Tensor", "aten.is_nonzero.default",
         "aten.equal.default"}
# where a host read is inherent: the PyTorch rasteriser's binning; ACT checks image ids only where they are host
# tensors (a GPU run's are not)
ALLOWED = ("backbones/gaussians/raster.py", "arcsem/act.py")


class HostReads(TorchDispatchMode):
    """Counts, by the project's source line that issued it, every operator that would wait for a GPU."""

    def __init__(self):
        super().__init__()
        self.sites: Counter = Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        name = str(func)
        bool_index = name.startswith("aten.index.Tensor") and any(
            isinstance(i, torch.Tensor) and i.dtype == torch.bool for i in (args[1] if len(args) > 1 else []))
        python_data = name.startswith("aten.lift_fresh") and out.numel() > 1  # torch.tensor([...]): a transfer on a GPU
        if name in READS or bool_index or python_data:
            self.sites[(name, _site())] += 1
        return out


def _site() -> str:
    for f in reversed(traceback.extract_stack()[:-2]):
        path = Path(f.filename).resolve()
        if ROOT in path.parents and ".venv" not in path.parts and "tests" not in path.parts:
            return f"{path.relative_to(ROOT)}:{f.lineno}"
    return "outside the project"


def _run(kind: str, stage: str, frozen_mb: int = 0, rasterizer: str = "torch"):
    scene = tiny_scene(n=4, w=48, h=32)
    cls = BACKBONES.get(kind)
    act = ACT(len(scene.train)) if stage == "geometry" else None
    bb = cls(cls.Config(rasterizer=rasterizer, random_init_points=300), scene=scene, **({"act": act} if act else {}))
    hook = None
    if stage == "geometry":
        terms = {"l1": {"weight": 0.8}, "dssim": {"weight": 0.2, "impl": "torch"}}
        if kind == "gs2d":
            terms.update(normal_consistency={"weight": 0.1}, distortion={"weight": 1.0})
    else:
        from test_devices import _targets

        hook = _targets("vgg16", "auto", n=4, size=(32, 48))
        terms = {"reference_l1": {"weight": 20}, "pseudo_color": {}, "tcm": {}, "ccm": {}}
    losses = build_losses(terms, bb.provides, backbone=kind, batch_parts=frozenset({"color"}) if hook else frozenset())
    lc = loop_module.LoopConfig(steps=20, stage=stage, check_every=1000, log_every=1000, progress=False,
                                checkpoint_every=0, frozen_mb=frozen_mb)
    run = loop_module._Run(bb, act, scene.train, lc, OptimConfig(), None, None)
    run.restore(1e-3)
    return run, losses, hook


@pytest.mark.parametrize("kind,stage", [("gs2d", "geometry"), ("gs3d", "geometry"), ("gs2d", "color")])
def test_steady_state_step_reads_nothing_back(kind, stage):
    run, losses, hook = _run(kind, stage)
    for s in range(2):  # first steps: optimiser state, caches
        loop_module._step(run, losses, hook, s, record=False)
    mode = HostReads()
    with mode:
        for s in range(2, 5):
            loop_module._step(run, losses, hook, s, record=False)
    stray = {k: n for k, n in mode.sites.items() if not k[1].startswith(ALLOWED)}
    assert not stray, f"host reads in a training step (op, source line: count over 3 steps): {stray}"
    assert any(k[1].startswith(ALLOWED[0]) for k in mode.sites), "the detector saw not even the binning's reads"


def test_stage2_through_recorded_renders_reads_nothing_back():
    """Once every view is recorded (the first epoch), a stage-2 step renders without the rasteriser: not even the
    binning's reads are left (the PyTorch path's record, the one a GPU uses)."""
    run, losses, hook = _run("gs2d", "color", frozen_mb=64)
    for s in range(4):  # the first epoch: each of the 4 views drawn and recorded once
        loop_module._step(run, losses, hook, s, record=False)
    assert len(run.frozen.ops) == 4
    mode = HostReads()
    with mode:
        for s in range(4, 8):
            loop_module._step(run, losses, hook, s, record=False)
    assert not mode.sites, f"host reads in a stage-2 step through recorded renders: {dict(mode.sites)}"
