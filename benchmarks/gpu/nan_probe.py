"""Where a non-finite value first appears in a 2DGS + gsplat run, on a GPU.

Default: the CUDA test's 32 x 24 scene, run by benchmarks/gpu_check.sh (part ``probe``) when tests/test_cuda.py's
gsplat 2DGS run fails: trains 20 steps with the finiteness read every step and autograd's anomaly mode, printing
each step's largest gradient per parameter group, so one call says which operation and which step.

``--demo``: stage 1 of ``experiment=demo`` on gsplat (part ``demoprobe``), the finiteness read every step, and
every gradient that enters or leaves gsplat's ``rasterization_2dgs`` watched: the first non-finite ones are
printed with the step, the tensor and, for a splat's gradient, that splat's camera depth, scales and opacity (an
H200 demo run stopped at step 470 with positions not finite). The largest gradients every 100 steps.
No GPU here: it exits with a message.

    python benchmarks/gpu/nan_probe.py [--demo] [OVERRIDE ...]
"""
from __future__ import annotations

import sys
import tempfile
import traceback
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))


def watch_gsplat(state: dict, limit: int = 12) -> None:
    """Hooks on every tensor handed to or returned by ``gsplat.rasterization_2dgs`` printing non-finite gradients."""
    import gsplat

    raster = gsplat.rasterization_2dgs

    def report(name, g, means, scales, opacities, viewmats):
        bad = ~torch.isfinite(g)
        if state["events"] >= limit or not bool(bad.any()):
            return
        state["events"] += 1
        line = f"step {state['step'] + 1}: {name} grad {list(g.shape)}: {int(bad.sum())} not finite"
        if name.startswith("in:") and g.shape[0] == means.shape[0]:
            rows = bad.reshape(len(g), -1).any(-1).nonzero()[:, 0][:4]
            z = means.detach() @ viewmats[0, 2, :3] + viewmats[0, 2, 3]
            line += "; rows " + ", ".join(
                f"{int(r)} (depth {float(z[r]):.4g}, scales {[round(float(v), 5) for v in scales[r, :2]]}, "
                f"opacity {float(opacities[r]):.3g})" for r in rows)
        print(line, flush=True)

    def wrapped(means, quats, scales, opacities, colors, viewmats, Ks, width, height, **kw):
        outs = raster(means, quats, scales, opacities, colors, viewmats, Ks, width, height, **kw)
        named = [("in:means", means), ("in:quats", quats), ("in:scales", scales), ("in:opacities", opacities),
                 ("in:colors", colors)] + list(zip(("out:render", "out:alpha", "out:normal", "out:surf_normal",
                                                   "out:distort", "out:median"), outs[:6]))
        for name, t in named:
            if isinstance(t, torch.Tensor) and t.requires_grad:
                t.register_hook(lambda g, name=name: report(name, g, means, scales, opacities, viewmats))
        return outs

    gsplat.rasterization_2dgs = wrapped


def every_step(loop) -> None:
    """The trainer's finiteness notes read every step (on a GPU: every ``log_every`` steps), so a failure names its
    step and the gradients of that step are still there."""
    init = loop._Health.__init__
    loop._Health.__init__ = lambda self, every: init(self, 1)


def demo(overrides: list[str]) -> int:
    from test_config import compose_with

    from arcsem import app
    from arcsem.train import loop

    tmp = Path(tempfile.mkdtemp())
    cfg = compose_with("experiment=demo", "stage=gray", "device=cuda", "backbone.rasterizer=gsplat",
                       "mesh.enabled=false", "train.progress=false", *overrides)
    state = {"step": 0, "events": 0}
    health_record = loop._Health.record

    def record(self, run, step, terms, params, grads):
        state["step"] = step + 1
        if (step + 1) % 100 == 0:
            big = {g: max((float(t.abs().max()) for t in gs if t is not None and not t.is_sparse), default=0.0)
                   for g, gs in grads.items()}
            print(f"step {step + 1}: largest gradients " + ", ".join(f"{g} {v:.3g}" for g, v in big.items()),
                  flush=True)
        return health_record(self, run, step, terms, params, grads)

    loop._Health.record = record
    every_step(loop)
    watch_gsplat(state)
    try:
        metrics = app.run(cfg, run_dir=tmp / "run")
        print(f"nan_probe --demo: run {metrics['status']}; {state['events']} non-finite gradients at gsplat")
    except Exception:  # noqa: BLE001 - the probe reports whatever stopped the run
        traceback.print_exc(limit=-12)
        print(f"nan_probe --demo: stopped at step {state['step']}; {state['events']} non-finite gradients at gsplat")
    return 0


def main(overrides: list[str]) -> int:
    if not torch.cuda.is_available():
        print("nan_probe: no CUDA device")
        return 0
    if overrides[:1] == ["--demo"]:
        return demo(overrides[1:])
    import cv2
    import numpy as np
    from conftest import write_transforms_scene
    from test_config import compose_with

    from arcsem import app
    from arcsem.train import loop

    tmp = Path(tempfile.mkdtemp())
    scene = write_transforms_scene(tmp / "scene", n=4, w=32, h=24)
    cv2.imwrite(str(tmp / "view_01.png"), np.full((24, 32, 3), (0, 0, 200), np.uint8))
    cfg = compose_with("dataset=transforms", f"dataset.path={scene.parent}", "stage=gray", "backbone=gs2d",
                       "device=cuda", "act=paper", "train.width=null", "train.steps=20", "train.eval.lpips=false",
                       "train.progress=false", f"cache_dir={tmp / 'cache'}",
                       "mesh.enabled=false", "backbone.rasterizer=gsplat", *overrides)
    health_record = loop._Health.record

    def record(self, run, step, terms, params, grads):  # print the largest gradient of each group
        big = {g: max((float(t.abs().max()) for t in gs if t is not None and not t.is_sparse), default=0.0)
               for g, gs in grads.items()}
        print(f"step {step + 1}: " + ", ".join(f"{g} {v:.3g}" for g, v in big.items()))
        return health_record(self, run, step, terms, params, grads)

    loop._Health.record = record
    every_step(loop)
    torch.autograd.set_detect_anomaly(True)
    try:
        metrics = app.run(cfg, run_dir=tmp / "run")
        print("nan_probe: run", metrics["status"])
    except Exception:  # noqa: BLE001 - the probe reports whatever stopped the run
        traceback.print_exc(limit=-12)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
