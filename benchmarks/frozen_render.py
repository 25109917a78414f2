"""Stage 2's recorded renders against compositing, on a trained Gaussian run: per view, the recording's time and
memory, the largest difference of the two renders, and one step's render + colour gradient each way.

    python benchmarks/frozen_render.py RUN_DIR [--rasterizer cpp|torch] [--views 0 7 15] [--threads 2]

``--rasterizer`` picks the fused kernels' record (cpp) or the PyTorch path's (torch, the one CUDA uses; on the CPU
it shows what the PyTorch fallback gains). Times are medians of ``--repeats`` calls; prints one line per view.
"""
from __future__ import annotations

import argparse
import statistics
import time
import warnings


def _median_ms(f, n: int) -> float:
    f()
    ts = []
    for _ in range(n):
        t = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t)
    return 1e3 * statistics.median(ts)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run")
    ap.add_argument("--rasterizer", default="cpp", choices=("cpp", "torch"))
    ap.add_argument("--views", type=int, nargs="+", default=[0, 7, 15])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=9)
    a = ap.parse_args()
    import torch

    warnings.filterwarnings("ignore")
    torch.set_num_threads(a.threads)
    from arcsem.runs import load_run

    m = load_run(a.run, colored=False)
    bb = m.backbone.eval()
    bb.set_act(None)
    bb.cfg.rasterizer = a.rasterizer
    for p in bb.parameters():  # stage 2: only the colours train
        p.requires_grad_(False)
    colour = [bb.model.sh_dc, bb.model.sh_rest]
    for p in colour:
        p.requires_grad_(True)
    for v in a.views:
        cams = m.scene.train.cameras[v:v + 1]
        t = time.perf_counter()
        op = bb.colour_operator(cams)
        build = time.perf_counter() - t
        ref, out = bb.render(cams)["rgb"], op()["rgb"]
        g = torch.randn_like(ref)
        slow = _median_ms(lambda cams=cams, g=g: torch.autograd.grad((bb.render(cams)["rgb"] * g).sum(), colour),
                          max(3, a.repeats // 3) if a.rasterizer == "torch" else a.repeats)
        fast = _median_ms(lambda op=op, g=g: torch.autograd.grad((op()["rgb"] * g).sum(), colour), a.repeats)
        print(f"view {v} ({a.rasterizer}, {a.threads} threads): recorded in {build:.2f} s, {op.nbytes / 1e6:.0f} MB, "
              f"max |difference| {float((ref - out).abs().max()):.1e}; render + colour gradient {slow:.1f} ms "
              f"compositing, {fast:.1f} ms recorded ({slow / fast:.1f}x)")


if __name__ == "__main__":
    main()
