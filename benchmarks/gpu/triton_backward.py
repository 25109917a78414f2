"""The Triton compositing backward's reductions side by side, on a trained demo model, one GPU.

Stage 1 of ``experiment=demo device=cuda backbone.rasterizer=triton`` trains ``--steps`` steps (the model then has
the demo's primitive count at that step); then one view is rendered and back-propagated (every output weighted by
a fixed random cotangent) with each of ``triton2d.BACKWARD_SUM``'s reductions and with the PyTorch rasteriser:

* ``fwd_ms``, ``bwd_ms``: the render and its backward (wall, the device synchronised), median of ``--reps`` after
  3 warm-ups;
* ``kernel_ms``: the compositing backward kernel alone (the profiler's device time, mean of ``--reps``);
* ``grad_rel_err``: each parameter gradient against the first reduction's (max |a - b| / max |b|).

    python benchmarks/gpu/triton_backward.py --steps 250 --json out.json

Prints one line a reduction; needs Triton and a CUDA device.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from stage1_profile import compose

OUTPUTS = ("rgb", "alpha", "depth", "normal", "median_depth", "distortion")


def trained(steps: int, overrides: list[str]):
    """The demo's stage-1 model after ``steps`` steps (rasterizer=triton) and its training split."""
    from arcsem.app import seed_everything
    from arcsem.data import load_scene
    from arcsem.train.loop import LoopConfig, train
    from arcsem.train.stage1 import act_config, build_model, prepare_scene, stage1_losses, train_config

    cfg = compose(["experiment=demo", "device=cuda", "backbone.rasterizer=triton", *overrides])
    seed_everything(int(cfg.seed))
    tc = train_config(cfg)
    scene = prepare_scene(load_scene(cfg.dataset), tc)
    backbone, act = build_model(cfg, scene, tc)
    loop = LoopConfig(steps=steps, stage="geometry", batch_views=tc.batch_views, log_every=tc.log_every,
                      checkpoint_every=0, resume="never", seed=int(cfg.seed), progress=False)
    with tempfile.TemporaryDirectory() as tmp:
        train(backbone, scene.train, stage1_losses(cfg, tc, act), loop, optim=tc.optim, ckpt_dir=Path(tmp) / "ck",
              act=act, act_lr=act_config(cfg).lr)
    return backbone, scene.train


def measure(backbone, cams, cot: dict | None, reps: int) -> tuple[dict, dict]:
    """Times of one render and its backward, the compositing kernel's time, the parameter gradients."""
    from torch.profiler import ProfilerActivity, profile

    params = [p for p in backbone.parameters() if p.requires_grad]

    def once():
        for p in params:
            p.grad = None
        out = backbone.render(cams)
        return out

    out = once()
    if cot is None:
        g = torch.Generator().manual_seed(1)
        cot = {k: torch.rand(out[k].shape, generator=g, dtype=out[k].dtype).to(out[k].device)
               for k in OUTPUTS if k in out}
    loss = lambda o: sum((o[k] * cot[k]).sum() for k in cot)
    sync = torch.cuda.synchronize
    fwd, bwd = [], []
    for i in range(reps + 3):
        for p in params:
            p.grad = None
        sync()
        t0 = time.perf_counter()
        out = backbone.render(cams)
        sync()
        t1 = time.perf_counter()
        loss(out).backward()
        sync()
        t2 = time.perf_counter()
        if i >= 3:
            fwd.append(1000 * (t1 - t0))
            bwd.append(1000 * (t2 - t1))
    grads = {n: p.grad.detach().clone() for n, p in backbone.named_parameters() if p.grad is not None}
    with profile(activities=[ProfilerActivity.CUDA]) as prof:
        for _ in range(reps):
            loss(backbone.render(cams)).backward()
        sync()
    dev = lambda e: float(getattr(e, "self_device_time_total", None) or getattr(e, "self_cuda_time_total", 0.0))
    kern = sum(dev(e) for e in prof.key_averages() if e.key.startswith("backward_kernel")) / 1000 / reps
    return {"fwd_ms": round(statistics.median(fwd), 3), "bwd_ms": round(statistics.median(bwd), 3),
            "kernel_ms": round(kern, 3)}, {"grads": grads, "cot": cot}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=250)
    ap.add_argument("--reps", type=int, default=10)
    ap.add_argument("--sums", default="tile_acq,tile,warp,row")
    ap.add_argument("--json", default=None)
    ap.add_argument("overrides", nargs="*")
    a = ap.parse_args()
    if not torch.cuda.is_available():
        sys.exit("error: no CUDA device")
    from arcsem.backbones.gaussians import triton2d

    backbone, split = trained(a.steps, a.overrides)
    cams = split.cameras[[0]].to(device="cuda")
    rows, ref, cot = [], None, None
    for name in [*a.sums.split(","), "torch"]:
        if name == "torch":
            backbone.cfg = dataclasses.replace(backbone.cfg, rasterizer="torch")
        else:
            triton2d.BACKWARD_SUM = name
        t, res = measure(backbone, cams, cot, a.reps)
        cot = res["cot"]
        ref = ref or res["grads"]
        err = max(((res["grads"][n] - g).abs().max() / g.abs().max().clamp_min(1e-30)).item() for n, g in ref.items())
        row = {"sum": name, **t, "grad_rel_err": float(f"{err:.3g}"), "primitives": int(backbone.num_primitives()),
               "device": torch.cuda.get_device_name()}
        print(json.dumps(row), flush=True)
        rows.append(row)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
