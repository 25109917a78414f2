"""The stage-2 colour targets scored before any training: 2-D pseudo-colours against the surface spread.

For a stage-1 run and a reference set, builds what stage 2 would train towards on the non-reference training views
(:func:`arcsem.colorize.pseudocolor.pseudo_colors` and :func:`arcsem.colorize.surface.surface_colors`, the model's
depth) and scores it against the dataset's true colour: PSNR over the specimen pixels inside and outside the 2-D
pseudo-colours' coverage (coverage decided on the true depth, as :mod:`arcsem.colorize.coverage`), and how much of
each part has a target. No training, so a grid of settings costs seconds each::

    .venv/bin/python benchmarks/colour_targets.py RUN_DIR [--references one three five] [--set grey_scale=0.05 ...]

RUN_DIR: a stage-1 run folder (its config.yaml names the dataset). One line per reference set.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from omegaconf import OmegaConf

from arcsem.colorize.coverage import coverage_masks
from arcsem.colorize.pseudocolor import pseudo_colors, render_depths
from arcsem.colorize.references import load_references
from arcsem.colorize.surface import surface_colors
from arcsem.configs import SurfaceConfig
from arcsem.data import load_scene
from arcsem.metrics import psnr
from arcsem.runs import load_stage1
from arcsem.train.sampling import resize_scene
from arcsem.visual import render_layers


def _psnr(pred, gt, m) -> float:
    N, H, W = m.shape
    return psnr(pred.reshape(N * H, W, 3), gt.reshape(N * H, W, 3), m.reshape(N * H, W)) if bool(m.any()) else float("nan")


def score(run: Path, refs_spec: str, surface: SurfaceConfig) -> dict:
    cfg = OmegaConf.load(run / "config.yaml")
    scene = load_scene(cfg.dataset)
    backbone, _ = load_stage1(run / "checkpoints" / "last.pt", scene, cfg)
    refs = load_references(scene, refs_spec)
    scene = resize_scene(scene, float(cfg.train.get("downscale", 1.0)), cfg.train.get("width"))
    split = scene.train
    refs.images = torch.nn.functional.interpolate(refs.images.permute(0, 3, 1, 2).float(),
                                                  size=(split.cameras.height, split.cameras.width),
                                                  mode="area").permute(0, 2, 3, 1)
    masks = split.masks.bool()
    ridx = refs.indices.tolist()
    depth = render_depths(backbone, split)
    t0 = time.perf_counter()
    p2d, v2d = pseudo_colors(split.cameras, depth, masks, ridx, refs.images, progress=False)
    t_pseudo = time.perf_counter() - t0
    layers = [render_layers(backbone, split.cameras[i:i + 1]) for i in range(len(split))]
    d = torch.cat([torch.where(x["valid"], x["depth"], torch.zeros_like(x["depth"])) for x in layers])
    n = torch.cat([x["normal"] for x in layers])
    t0 = time.perf_counter()
    ps, vs, figs = surface_colors(split.cameras, d, masks, split.images.float().mean(-1), n, ridx, refs.images, surface)
    t_surface = time.perf_counter() - t0
    others = [i for i in range(len(split)) if i not in set(ridx)]
    gt, m = split.colors[others], masks[others]
    cov = coverage_masks(split.cameras[ridx], split.depths[ridx], masks[ridx], split.cameras[others],
                         split.depths[others], m)
    out = {"references": refs_spec, "surface": surface.__dict__, "nodes": figs["nodes"], "t_pseudo_s": t_pseudo,
           "t_surface_s": t_surface}
    fill = vs[others] & ~v2d[others]
    comb = torch.where(fill[..., None], ps[others], p2d[others])
    for part, pm in (("in", m & cov), ("out", m & ~cov)):
        tot = max(int(pm.sum()), 1)
        for name, col, val in (("pseudo", p2d[others], v2d[others]), ("surface", ps[others], vs[others]),
                               ("combined", comb, v2d[others] | fill)):
            out[f"{name}_{part}_psnr"] = _psnr(col, gt, pm & val)
            out[f"{name}_{part}_reach"] = int((pm & val).sum()) / tot
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--references", nargs="+", default=["one", "three", "five"])
    ap.add_argument("--set", nargs="*", default=[], help="SurfaceConfig fields, key=value")
    args = ap.parse_args()
    kw = {k: type(getattr(SurfaceConfig(), k))(v) for k, v in (s.split("=", 1) for s in args.set)}
    for spec in args.references:
        print(json.dumps(score(args.run, spec, SurfaceConfig(**kw))), flush=True)


if __name__ == "__main__":
    main()
