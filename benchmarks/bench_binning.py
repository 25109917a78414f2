"""Footprints + tile binning alone (``footprint_bin_3dgs`` / ``footprint_bin_2dgs``) on the shared scene.

The scene of ``bench_peer.py`` (256x256, N Gaussians); the inputs of the binning call are captured from one render,
then the call alone is timed: median of ``--runs`` calls after 3 warm-up calls, for one and two threads. Compare
commits by running it in each checkout (its venv), alternately:

    .venv/bin/python benchmarks/bench_binning.py [--model 3DGS|2DGS] [--sizes 100000]
    (cd /tmp/base && .venv/bin/python /work/main/benchmarks/bench_binning.py)
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_peer import peer_scene


def captured_call(model: str, N: int):
    """The binning function and the arguments one render of the shared scene passes it."""
    from arcsem.backbones.gaussians import fused
    from arcsem.backbones.gs2d.render import render_2dgs
    from arcsem.backbones.gs3d.render import render_3dgs

    name = "footprint_bin_3dgs" if model == "3DGS" else "footprint_bin_2dgs"
    fn, cap = getattr(fused, name), {}

    def spy(*a):
        cap["args"] = a
        return fn(*a)

    (means, quats, scales, opac, _), cams = peer_scene(N)
    setattr(fused, name, spy)
    try:
        with torch.no_grad():
            render = render_3dgs if model == "3DGS" else render_2dgs
            render(means, quats, scales[:, : 3 if model == "3DGS" else 2], opac, torch.rand(N, 3), cams, impl="cpp")
    finally:
        setattr(fused, name, fn)
    return fn, cap["args"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="3DGS", choices=("3DGS", "2DGS"))
    ap.add_argument("--sizes", default="100000")
    ap.add_argument("--runs", type=int, default=15)
    a = ap.parse_args()
    for N in (int(n) for n in a.sizes.split(",")):
        fn, args = captured_call(a.model, N)
        for threads in (1, 2):
            torch.set_num_threads(threads)
            times = []
            for r in range(a.runs + 3):
                t0 = time.perf_counter()
                lists = fn(*args)
                if r >= 3:
                    times.append(time.perf_counter() - t0)
            print(f"{a.model} N={N:,}: {lists.ids.numel():,} pairs, {threads} thread(s): "
                  f"{1e3 * statistics.median(times):.2f} ms", flush=True)


if __name__ == "__main__":
    main()
