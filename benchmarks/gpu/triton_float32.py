"""Float32 gradients against float64 on a trained model: the PyTorch rasteriser and the Triton kernels side by side.

Loads a stage-1 2DGS run of ``experiment=demo`` (``--run``, its ``checkpoints/last.pt``), renders its first
training view (scaled by ``--scale``) with every output weighted by a fixed random cotangent, and reports, for each
parameter, max |g32 - g64| / max |g64| of the PyTorch path in float32 and of the Triton kernels in float32, both
against the PyTorch path in float64, and the two float32 gradients against each other::

    .venv/bin/arcsem experiment=demo stage=gray hydra.run.dir=/tmp/demo_gray
    TRITON_INTERPRET=1 python benchmarks/gpu/triton_float32.py --run /tmp/demo_gray --scale 0.25
        # on the CPU through Triton's interpreter: ~28 minutes at 72x48 px; on a GPU: --device cuda, seconds

Prints one line a comparison.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from stage1_profile import compose

OUTPUTS = ("rgb", "alpha", "depth", "normal", "median_depth", "distortion")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", required=True, help="a finished stage-1 run of experiment=demo (2DGS)")
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--device", default="cpu")
    a = ap.parse_args()
    from arcsem.data import load_scene
    from arcsem.runs import load_stage1
    from arcsem.train.stage1 import prepare_scene, train_config

    cfg = compose(["experiment=demo", f"device={a.device}"])
    scene = prepare_scene(load_scene(cfg.dataset), train_config(cfg))
    bb, _ = load_stage1(Path(a.run) / "checkpoints" / "last.pt", load_scene(cfg.dataset), cfg)
    cams = scene.train.cameras[[0]].scaled(a.scale).to(device=a.device)
    print(f"{bb.num_primitives()} primitives, {cams.width}x{cams.height} px", flush=True)
    grads, cot = {}, None
    for name, rasterizer, dtype in [("torch float64", "torch", torch.float64), ("torch float32", "torch", torch.float32),
                                    ("triton float32", "triton", torch.float32)]:
        bb.cfg = dataclasses.replace(bb.cfg, rasterizer=rasterizer)
        model = bb.to(dtype)
        for p in model.parameters():
            p.grad = None
        t0 = time.perf_counter()
        out = model.render(cams.to(dtype=dtype))
        if cot is None:
            g = torch.Generator().manual_seed(1)
            cot = {k: torch.rand(out[k].shape, generator=g, dtype=torch.float64).to(a.device) for k in OUTPUTS if k in out}
        sum((out[k] * cot[k].to(dtype)).sum() for k in cot).backward()
        grads[name] = {n: p.grad.double() for n, p in model.named_parameters() if p.grad is not None}
        print(f"{name}: {time.perf_counter() - t0:.1f} s", flush=True)

    def rel(a: dict, b: dict) -> str:
        return ", ".join(f"{n} {((a[n] - g).abs().max() / g.abs().max().clamp_min(1e-30)).item():.2e}"
                         for n, g in b.items())

    print("torch float32 against float64:", rel(grads["torch float32"], grads["torch float64"]))
    print("triton float32 against float64:", rel(grads["triton float32"], grads["torch float64"]))
    print("triton float32 against torch float32:", rel(grads["triton float32"], grads["torch float32"]))


if __name__ == "__main__":
    main()
