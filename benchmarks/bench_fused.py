"""Fused C++ kernels vs the PyTorch rasteriser: forward + backward, side by side in one process.

    .venv/bin/python benchmarks/bench_fused.py                # the issue's table (several minutes)
    .venv/bin/python benchmarks/bench_fused.py --runs 5 --large   # also 3072x2048 (C++ only beyond 512 px)

Same scenes and timer as ``bench_raster.py`` (random splats in a unit box filling the view, loss on
rgb + depth + alpha). For each row the PyTorch and C++ paths are timed alternately, so the ratio is
measured under the same machine load; medians of ``--runs`` after one warm-up each.
"""
from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).parent))
from arcsem.backbones.gaussians.fused import load_extension
from arcsem.backbones.gs2d.render import render_2dgs
from arcsem.backbones.gs3d.render import render_3dgs
from bench_raster import time_fwd_bwd

MODELS = {"2DGS": (render_2dgs, 2), "3DGS": (render_3dgs, 3)}


def row(model: str, N: int, W: int, H: int, runs: int, with_torch: bool) -> str:
    fn, dims = MODELS[model]
    cpp, _ = time_fwd_bwd(functools.partial(fn, impl="cpp"), dims, N, W, H, runs)
    if not with_torch:
        return f"| {model} | {N:,} | {W}x{H} | {cpp:.3f} | - | - |"
    ref, _ = time_fwd_bwd(functools.partial(fn, impl="torch"), dims, N, W, H, runs)
    return f"| {model} | {N:,} | {W}x{H} | {cpp:.3f} | {ref:.3f} | {ref / cpp:.1f}x |"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--large", action="store_true", help="add 3072x2048 (C++ only)")
    args = ap.parse_args()
    assert load_extension() is not None, "the C++ extension did not build"
    print(f"torch threads: {torch.get_num_threads()}; median of {args.runs} runs (wall seconds, fwd+bwd)")
    print("| model | splats | size | C++ | PyTorch | PyTorch/C++ |")
    print("|---|---|---|---|---|---|")
    cases = [(50_000, 256, 192), (10_000, 256, 192), (100_000, 256, 192), (50_000, 128, 96), (50_000, 512, 384)]
    for model in MODELS:
        for N, W, H in cases:
            print(row(model, N, W, H, args.runs, with_torch=True), flush=True)
        if args.large:
            print(row(model, 50_000, 3072, 2048, args.runs, with_torch=False), flush=True)


if __name__ == "__main__":
    main()
