"""Time the TCM/CCM feature extractors on 32 grey views at 768x512 (the paper's 3072x2048 views after TCM's
downscale by 4), cold (computed) and warm (from the cache), plus the nearest-feature matching of TCM/CCM.

Views, depth and cameras come from the analytic ellipsoid scene (arcsem.colorize.analytic): closed-form, so
the timing is of the extractors, not of a scene generator. ``learned`` includes its training (fixed number of
steps on crops, so its cost does not grow with the image) and is cached in a temporary folder; the warm run
reads it back. ``daisy`` and ``vgg16`` have no model to cache: their features are computed once per stage-2
run and the matches are cached (``guide_<key>_<view>.npz``); the warm figure is the cached guidance of all
views. Prints the median of ``--repeats`` runs.

Usage::

    .venv/bin/python benchmarks/bench_features.py [--features daisy learned vgg16] [--repeats 3] [--threads 2]
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time

import torch

from arcsem.colorize.analytic import analytic_scene
from arcsem.colorize.features import ColourSpace, SceneContext, build_extractor
from arcsem.colorize.features.base import no_grad_features
from arcsem.colorize.guidance import Guidance
from arcsem.colorize.pseudocolor import cache_key


def features_once(name: str, split, cache: str) -> tuple[float, object]:
    t0 = time.perf_counter()
    ctx = SceneContext(gray=split.images, cameras=split.cameras, masks=split.masks, depths=lambda: split.depths,
                       depth_key=cache_key(split.depths), seed=0, downscale=1, cache_dir=cache)
    ext = build_extractor(name, ctx)
    no_grad_features(ext, split.images)
    return time.perf_counter() - t0, ext


def guidance_once(ext, split, cache: str) -> float:
    """All 32 views' TCM/CCM matches against 5 references (reads the cache when it holds them)."""
    t0 = time.perf_counter()
    g = Guidance(ext, ColourSpace(ext.strides), split.images, [0, 8, 16, 24, 31], split.colors[[0, 8, 16, 24, 31]],
                 tcm_downscale=1, ccm_downscale=4, cache_dir=cache)
    for v in range(len(split)):
        g.matches(v)
    return time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--features", nargs="+", default=["daisy", "learned", "vgg16"])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--width", type=int, default=768)
    ap.add_argument("--height", type=int, default=512)
    ap.add_argument("--matching", action="store_true", help="also time TCM/CCM matching (slow: large products)")
    a = ap.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    split = analytic_scene(32, 1, a.width, a.height).train  # 32 training views (and one held-out, unused)
    print(f"32 views at {a.width}x{a.height}, {torch.get_num_threads()} threads, median of {a.repeats}")
    for name in a.features:
        cold, warm, match = [], [], []
        for _ in range(a.repeats):
            with tempfile.TemporaryDirectory() as cache:
                t, ext = features_once(name, split, cache)
                cold.append(t)
                warm.append(features_once(name, split, cache)[0] if name == "learned" else float("nan"))
                if a.matching:
                    guidance_once(ext, split, cache)
                    match.append(guidance_once(ext, split, cache))
        line = f"  {name:8s} features cold {statistics.median(cold):6.1f} s (runs {', '.join(f'{x:.1f}' for x in cold)})"
        if name == "learned":
            line += f"; warm (model from cache) {statistics.median(warm):.1f} s"
        if match:
            line += f"; cached guidance of 32 views {statistics.median(match):.2f} s"
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
