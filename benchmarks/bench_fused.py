"""Fused C++ rasteriser vs the PyTorch path: forward + backward, side by side in one process.

    .venv/bin/python benchmarks/bench_fused.py                     # the issue's table (a few minutes)
    .venv/bin/python benchmarks/bench_fused.py --threads 1,2       # the same at 1 and 2 torch threads
    .venv/bin/python benchmarks/bench_fused.py --large             # + 3072x2048 with 200k splats (C++ only)
    .venv/bin/python benchmarks/bench_fused.py --quick             # 50k@256x192 only

Same scenes as ``bench_raster.py`` (random splats in a unit box filling the view, float32, loss on
rgb + depth + alpha). Within a row the implementations are timed alternately (one run of each per
repeat, after one warm-up each), so the ratio is measured under the same machine load; the figures
are medians of ``--runs`` (wall seconds). The PyTorch path is timed at 256x192 only (10k, 50k, 100k
splats; it takes seconds per step); the other sizes are C++ only. ``uptime`` is printed before and
after: on a shared machine quote it with the figures.
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

import torch
from arcsem.backbones.gaussians.fused import load_extension
from arcsem.backbones.gaussians.raster_scenes import orbit_cameras, random_splats
from arcsem.backbones.gs2d.render import render_2dgs
from arcsem.backbones.gs3d.render import render_3dgs

MODELS = {"2DGS": (render_2dgs, 2), "3DGS": (render_3dgs, 3)}
SCALE_256 = (0.004, 0.025)  # world units, as bench_raster.py (a few to tens of pixels at 256 px width)


def _step(fn, params, cams, impl: str) -> float:
    t0 = time.perf_counter()
    out = fn(*params, cams, impl=impl)
    (out["rgb"].sum() + out["depth"].sum() + out["alpha"].sum()).backward()
    return time.perf_counter() - t0


def time_row(model: str, N: int, W: int, H: int, runs: int, impls: tuple[str, ...]) -> dict[str, float]:
    """Median fwd+bwd wall seconds per implementation, timed alternately (warm-up run not counted)."""
    fn, dims = MODELS[model]
    scale = tuple(x * 256 / W for x in SCALE_256)
    s = random_splats(N, 1, seed=0, scale=scale, dtype=torch.float32)
    cams = orbit_cameras(1, W, H, dtype=torch.float32)
    times: dict[str, list[float]] = {i: [] for i in impls}
    for r in range(runs + 1):
        for impl in impls:
            t = _step(fn, s.params(dims), cams, impl)
            if r:
                times[impl].append(t)
    return {i: statistics.median(ts) for i, ts in times.items()}


def _load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f}, {five:.2f}, {fifteen:.2f}"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--threads", default=str(torch.get_num_threads()), help="comma-separated torch thread counts")
    ap.add_argument("--large", action="store_true", help="add 3072x2048 with 200k splats (C++ only)")
    ap.add_argument("--quick", action="store_true", help="50k@256x192 only")
    args = ap.parse_args()
    assert load_extension() is not None, "the C++ extension did not build"
    both = [(50_000, 256, 192), (10_000, 256, 192), (100_000, 256, 192)]
    cpp_only = [(50_000, 128, 96), (50_000, 512, 384)]
    if args.quick:
        both, cpp_only = both[:1], []
    print(f"2-core CPU, shared with other jobs; start: {_load()}")
    print(f"fwd+bwd wall seconds, median of {args.runs} runs (alternating torch / C++), float32")
    print("| model | threads | splats | size | C++ | PyTorch | PyTorch/C++ |")
    print("|---|---|---|---|---|---|---|")
    for nt in (int(t) for t in args.threads.split(",")):
        torch.set_num_threads(nt)
        for model in MODELS:
            for N, W, H in both:
                t = time_row(model, N, W, H, args.runs, ("cpp", "torch"))
                print(f"| {model} | {nt} | {N:,} | {W}x{H} | {t['cpp']:.3f} | {t['torch']:.3f} | "
                      f"{t['torch'] / t['cpp']:.1f}x |", flush=True)
            for N, W, H in cpp_only:
                t = time_row(model, N, W, H, args.runs, ("cpp",))
                print(f"| {model} | {nt} | {N:,} | {W}x{H} | {t['cpp']:.3f} | - | - |", flush=True)
            if args.large:
                t = time_row(model, 200_000, 3072, 2048, min(args.runs, 2), ("cpp",))
                print(f"| {model} | {nt} | 200,000 | 3072x2048 | {t['cpp']:.3f} | - | - |", flush=True)
    print(f"end: {_load()}")


if __name__ == "__main__":
    main()
