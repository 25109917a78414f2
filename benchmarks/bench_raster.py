"""Benchmark of the PyTorch tile rasteriser (2DGS and 3DGS): speed, dense-reference ratio, peak memory.

    .venv/bin/python benchmarks/bench_raster.py                 # everything (several minutes)
    .venv/bin/python benchmarks/bench_raster.py --part speed    # fwd+bwd medians, 2DGS vs 3DGS
    .venv/bin/python benchmarks/bench_raster.py --part dense    # tiled vs dense reference
    .venv/bin/python benchmarks/bench_raster.py --part memory   # 3072x2048, 200k splats, peak RSS
    .venv/bin/python benchmarks/bench_raster.py --threads 1     # one torch thread (see below)

On a shared, oversubscribed machine torch's worker threads spin while waiting, so with 2 threads the
process CPU time overstates the work; one thread gives the cleanest measure of the work itself.

Scenes: random splats in a unit box seen by a pinhole camera at distance 3 whose field of view the
box fills; scales are log-uniform so that each splat covers a few to tens of pixels at 256 px width
(the 3072x2048 scene uses proportionally smaller splats, a few hundred pixels each). Times are wall
seconds (median of ``--runs``) and the process CPU seconds of the same runs (the machine is shared).
"""
from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time

import torch
from arcsem.backbones.gaussians.raster_scenes import orbit_cameras, random_splats
from arcsem.backbones.gs2d.render import render_2dgs
from arcsem.backbones.gs3d.render import render_3dgs

SCALE_256 = (0.004, 0.025)  # world units; at 256 px width the camera sees ~150 px per unit


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def time_fwd_bwd(fn, dims: int, N: int, W: int, H: int, runs: int, seed: int = 0) -> tuple[float, float]:
    """Median wall and CPU seconds of forward + backward (loss on rgb, depth, alpha)."""
    scale = tuple(x * 256 / W for x in SCALE_256)
    s = random_splats(N, 1, seed=seed, scale=scale, dtype=torch.float32)
    cams = orbit_cameras(1, W, H, dtype=torch.float32)
    walls, cpus = [], []
    for i in range(runs + 1):  # the first run warms up (allocator, thread pool) and is not counted
        p = s.params(dims)
        c0, t0 = _cpu(), time.perf_counter()
        out = fn(*p, cams)
        (out["rgb"].sum() + out["depth"].sum() + out["alpha"].sum()).backward()
        if i:
            walls.append(time.perf_counter() - t0)
            cpus.append(_cpu() - c0)
    return statistics.median(walls), statistics.median(cpus)


def part_speed(runs: int) -> None:
    print("## forward + backward, median of", runs, "runs (wall s / process CPU s)")
    print("| splats | size | 2DGS wall | 2DGS cpu | 3DGS wall | 3DGS cpu | 3DGS/2DGS (wall) |")
    print("|---|---|---|---|---|---|---|")
    cases = [(10_000, 256, 192), (50_000, 256, 192), (100_000, 256, 192), (50_000, 128, 96), (50_000, 512, 384)]
    for N, W, H in cases:
        w2, c2 = time_fwd_bwd(render_2dgs, 2, N, W, H, runs)
        w3, c3 = time_fwd_bwd(render_3dgs, 3, N, W, H, runs)
        print(f"| {N} | {W}x{H} | {w2:.2f} | {c2:.2f} | {w3:.2f} | {c3:.2f} | {w3 / w2:.2f} |", flush=True)


def part_dense(runs: int) -> None:
    from arcsem.backbones.gs2d.reference import render_2dgs_dense
    from arcsem.backbones.gs3d.reference import render_3dgs_dense

    N, W, H = 300, 64, 48
    print(f"## tiled vs dense reference, {N} splats, {W}x{H}, float64, fwd+bwd median of {runs}")
    print("| model | tiled s | dense s | dense/tiled |")
    print("|---|---|---|---|")
    for name, fast, dense, dims in [("2DGS", render_2dgs, render_2dgs_dense, 2),
                                    ("3DGS", render_3dgs, render_3dgs_dense, 3)]:
        s = random_splats(N, 1, seed=0, scale=tuple(x * 4 for x in SCALE_256))
        cams = orbit_cameras(1, W, H)
        res = []
        for fn in (fast, dense):
            ts = []
            for _ in range(runs):
                p = s.params(dims)
                t0 = time.perf_counter()
                out = fn(*p, cams)
                (out["rgb"].sum() + out["depth"].sum()).backward()
                ts.append(time.perf_counter() - t0)
            res.append(statistics.median(ts))
        print(f"| {name} | {res[0]:.3f} | {res[1]:.3f} | {res[1] / res[0]:.1f} |", flush=True)


def memory_child(model: str, N: int, W: int, H: int) -> None:
    """Run in a subprocess: one forward render under no_grad; print JSON with peak RSS."""
    fn, dims = (render_2dgs, 2) if model == "2dgs" else (render_3dgs, 3)
    scale = tuple(x * 256 / W * 2 for x in SCALE_256)  # a few hundred pixels per splat at 3072 px
    s = random_splats(N, 1, seed=0, scale=scale, dtype=torch.float32)
    cams = orbit_cameras(1, W, H, dtype=torch.float32)
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    with torch.no_grad():
        out = fn(*[p.detach() for p in s.params(dims)], cams)
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(json.dumps({"model": model, "N": N, "W": W, "H": H, "wall_s": round(wall, 1),
                      "peak_rss_gb": round(peak / 2**20, 2), "before_render_gb": round(base / 2**20, 2),
                      "mean_alpha": round(out["alpha"].mean().item(), 3)}))


def part_memory(models: list[str]) -> None:
    print("## forward at 3072x2048 with 200,000 splats, torch.no_grad(), peak RSS of a fresh process")
    for model in models:
        cmd = [sys.executable, __file__, "--child", model]
        res = subprocess.run(cmd, capture_output=True, text=True, check=False)
        print(res.stdout.strip() or res.stderr[-2000:], flush=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--part", choices=["all", "speed", "dense", "memory"], default="all")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--memory-models", default="2dgs,3dgs")
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch's default)")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.child:
        memory_child(args.child, 200_000, 3072, 2048)
        return
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, {time.strftime('%Y-%m-%d %H:%M')}")
    if args.part in ("all", "speed"):
        part_speed(args.runs)
    if args.part in ("all", "dense"):
        part_dense(args.runs)
    if args.part in ("all", "memory"):
        part_memory(args.memory_models.split(","))


if __name__ == "__main__":
    main()
