"""How much the surface spread loses to stage 1's geometry: the spread on the model's depth against the true depth.

The surface spread (:mod:`arcsem.colorize.surface`) builds its graph over every training view's specimen pixels,
unprojected with the stage-1 model's depth, and scribbles the references' colours on it. On a built-in scene (true
depth and normals) this scores, without training, the spread's colour against the true colour on the non-reference
training views' specimen pixels outside the references' coverage (true depth, as the metrics), and how much of that
outside it reaches, with the graph's depth and normals taken from:

* ``model``: the stage-1 model (what a run does);
* ``true``: the dataset;
* ``refs true``: the dataset for the references (their scribbles), the model for the other views;
* ``refs model``: the model for the references, the dataset for the other views;

and the model depth's error against the true depth on the specimen pixels, in pixel footprints (percentiles, and the
share beyond 10 footprints). The spread's settings are the run's (``colorize.surface``)::

    .venv/bin/python benchmarks/spread_geometry.py RUN_DIR [RUN_DIR ...] [--references one three]

RUN_DIR: a run folder (its config.yaml; the stage-1 model found as stage 2 finds it) of a scene with depth maps.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))  # match_outside beside it (benchmarks/ is no package)
import match_outside


def _db(pred, gt, sel) -> float:
    return -10 * math.log10(float(((pred - gt)[sel] ** 2).mean())) if bool(sel.any()) else float("nan")


def mixed(model: torch.Tensor, true: torch.Tensor, ridx: list[int], refs_from: str) -> torch.Tensor:
    """``model`` ``[N, ...]`` with the views ``ridx`` (``refs_from="true"``) or all other views (``"model"``) taken
    from ``true``."""
    out = true.clone() if refs_from == "model" else model.clone()
    out[ridx] = model[ridx] if refs_from == "model" else true[ridx]
    return out


def depth_error(model: torch.Tensor, true: torch.Tensor, masks: torch.Tensor, fx: torch.Tensor) -> dict:
    """Percentiles 50/90/99 of ``|model - true|`` in pixel footprints (``true / fx``) and the share beyond 10, over
    ``masks [N, H, W]`` where both depths exist (``fx [N]``)."""
    ok = masks & (model > 0) & (true > 0)
    err = ((model - true).abs() / (true / fx[:, None, None]))[ok].numpy()
    return {"p50": float(np.percentile(err, 50)), "p90": float(np.percentile(err, 90)),
            "p99": float(np.percentile(err, 99)), "beyond10": float((err > 10).mean())}


def _scene_name(run: Path, cfg) -> str:
    """The run's ``dataset`` choice (its ``.hydra/hydra.yaml``), else the dataset's ``kind``."""
    import yaml

    hy = run / ".hydra" / "hydra.yaml"
    choice = (yaml.safe_load(hy.read_text()) or {}).get("hydra", {}).get("runtime", {}).get("choices", {}).get(
        "dataset") if hy.is_file() else None
    return str(choice or cfg.dataset.get("kind", "?"))


def score(run: Path, refs_spec: str) -> str:
    from arcsem.colorize import inputs as prep
    from arcsem.colorize.coverage import coverage_masks
    from arcsem.colorize.surface import surface_colors

    r = match_outside.open_run(run, refs_spec)
    cfg, cc, split, refs = r.cfg, r.cc, r.split, r.refs
    if split.depths is None or split.normals is None or split.colors is None or split.masks is None:
        return f"# {run.name}: the scene has no true depth, normals, colour or masks"
    masks, ridx, gt = split.masks.bool(), refs.indices.tolist(), split.colors.float()
    covered = coverage_masks(split.cameras[ridx], split.depths[ridx], masks[ridx], split.cameras, split.depths, masks)
    outside = masks & ~covered
    outside[ridx] = False
    grey = split.images.float().mean(-1)
    md, mn = prep.SurfaceGeometry(r.backbone, split).value
    td, tn = split.depths.float(), split.normals.float()
    err = depth_error(md, td, masks, split.cameras.K[:, 0, 0].float())
    line = (f"| {_scene_name(run, cfg)} ({run.name}) | {refs_spec} | {int(outside.sum())} | "
            f"{err['p50']:.1f} / {err['p90']:.1f} / {err['p99']:.1f} / {err['beyond10']:.2f} |")
    for depth, normal in ((md, mn), (td, tn), (mixed(md, td, ridx, "true"), mixed(mn, tn, ridx, "true")),
                          (mixed(md, td, ridx, "model"), mixed(mn, tn, ridx, "model"))):
        cols, ok, _ = surface_colors(split.cameras, depth, masks, grey, normal, ridx, refs.images.float(), cc.surface)
        sel = outside & ok
        line += f" {float(sel.sum() / outside.sum()):.2f} / {_db(cols, gt, sel):.2f} |"
    return line


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--references", nargs="+", default=["one", "three"])
    args = ap.parse_args()
    print("| scene (run) | references | px outside | model depth error, footprints: p50 / p90 / p99 / share > 10 | "
          "spread reach / PSNR: model | true | refs true, rest model | refs model, rest true |")
    print("|---|---|---:|---|---|---|---|---|")
    for run in args.runs:
        for refs in args.references:
            print(score(run, refs), flush=True)


if __name__ == "__main__":
    main()
