"""The VGG trunk of TCM/CCM, forward and backward (to the image, as stage 2 runs it), with its weights in NCHW
against channels-last layout, on a render-shaped input (``[1, H, W, 3]`` permuted: channels-last strides).

    .venv/bin/python benchmarks/vgg_layout.py [--sizes 48x72 96x144] [--repeats 30] [--threads 2]

Prints per size the median milliseconds of each layout (the two alternated in rounds of ``--repeats``) and the
largest difference of their features, relative to the features' largest magnitude.
"""
from __future__ import annotations

import argparse
import statistics
import time

import torch


def _step(vgg, x: torch.Tensor) -> list[torch.Tensor]:
    xi = x.detach().clone().requires_grad_(True)
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
    layouts = {"nchw": torch.contiguous_format, "channels_last": torch.channels_last}
    for size in a.sizes:
        H, W = (int(v) for v in size.split("x"))
        x = torch.rand(1, H, W, 3)
        times: dict[str, list[float]] = {k: [] for k in layouts}
        feats = {}
        for _ in range(a.rounds):
            for name, fmt in layouts.items():
                vgg.trunk.to(memory_format=fmt)
                feats[name] = _step(vgg, x)  # (a warm-up)
                for _ in range(a.repeats):
                    t = time.perf_counter()
                    _step(vgg, x)
                    times[name].append(time.perf_counter() - t)
        scale = max(float(f.abs().max()) for f in feats["nchw"])
        diff = max(float((f - g).abs().max()) for f, g in zip(feats["nchw"], feats["channels_last"]))
        med = {k: 1e3 * statistics.median(v) for k, v in times.items()}
        print(f"{size}: NCHW weights {med['nchw']:.1f} ms, channels-last {med['channels_last']:.1f} ms "
              f"({med['nchw'] / med['channels_last']:.2f}x); features differ by {diff / scale:.1e} of their largest")


if __name__ == "__main__":
    main()
