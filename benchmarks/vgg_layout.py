"""The VGG trunk of TCM/CCM, forward and backward (to the image, as stage 2 runs it), on the two memory layouts its
input arrives in: a render ``[1, H, W, 3]`` (channels last in memory: TCM at ``colorize.tcm_downscale=1``, the
guidance's feature maps) and a downscaled render (NCHW in memory: ``imageops.downscale``'s output, TCM's default).

    .venv/bin/python benchmarks/vgg_layout.py [--sizes 48x72 96x144] [--repeats 30] [--threads 2]

Prints per size the median milliseconds of each input layout (alternated in ``--rounds`` rounds of ``--repeats``)
and the largest difference of their features, relative to the features' largest magnitude. Run it with two
checkouts' Pythons to compare them (the extractor is this checkout's).
"""
from __future__ import annotations

import argparse
import statistics
import time

import torch


def _step(vgg, x: torch.Tensor) -> list[torch.Tensor]:
    xi = x.detach().clone(memory_format=torch.preserve_format).requires_grad_(True)
    feats = vgg(xi)
    sum(f.square().mean() for f in feats).backward()
    return [f.detach() for f in feats]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", nargs="+", default=["48x72", "96x144"])
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    from arcsem.colorize.vgg import VGGFeatures

    torch.manual_seed(0)
    vgg = VGGFeatures("vgg16", load_weights=False)
    for size in a.sizes:
        H, W = (int(v) for v in size.split("x"))
        render = torch.rand(1, H, W, 3)
        inputs = {"render (NHWC memory)": render,
                  "downscaled (NCHW memory)": render.permute(0, 3, 1, 2).contiguous().permute(0, 2, 3, 1)}
        times: dict[str, list[float]] = {k: [] for k in inputs}
        feats = {}
        for _ in range(a.rounds):
            for name, x in inputs.items():
                feats[name] = _step(vgg, x)  # (a warm-up)
                for _ in range(a.repeats):
                    t = time.perf_counter()
                    _step(vgg, x)
                    times[name].append(time.perf_counter() - t)
        f0, f1 = feats.values()
        scale = max(float(f.abs().max()) for f in f0)
        diff = max(float((f - g).abs().max()) for f, g in zip(f0, f1))
        line = ", ".join(f"{k} {1e3 * statistics.median(v):.1f} ms" for k, v in times.items())
        print(f"{size}: {line}; features differ by {diff / scale:.1e} of their largest")


if __name__ == "__main__":
    main()
