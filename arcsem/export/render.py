"""``stage=render``: orbit videos of a finished run (grey, colour, depth, normal), H.264 MP4.

``arcsem stage=render render.run=outputs/2026-11-24/10-00-00`` loads the run's models
(:mod:`.runs`), renders an orbit (:mod:`arcsem.orbit`) and writes into this job's own folder:

* ``orbit_gray.mp4``: the stage-1 model with the mean ACT;
* ``orbit_color.mp4``: the stage-2 (coloured) model, where the run has one;
* ``orbit_depth.mp4``: the surface depth (turbo colour map, one range for the whole video: near
  red, far blue; background white), and ``orbit_normal.mp4``: camera-space normals.

The videos are H.264 in ``yuv420p`` (what browsers play), odd sizes padded to even.
The ``render`` config block (``conf/config.yaml``) is validated against :class:`RenderConfig`.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from ..configs import RENDER_LAYERS as LAYERS
from ..configs import RenderConfig
from ..errors import ConfigError

__all__ = ["LAYERS", "RenderConfig", "render_config", "render_orbit", "run_render_stage"]

def render_config(raw: Any) -> RenderConfig:
    """A validated :class:`~arcsem.configs.RenderConfig` (unknown keys, layers, fps and orbit values are errors); a
    run reads its own once: :attr:`arcsem.runconfig.RunConfig.render`."""
    from ..runconfig import validated

    return validated(RenderConfig, raw, where="render")


def _frames(backbone, cams, alpha_min: float, geometry: bool, progress: bool, desc: str) -> dict[str, list]:
    """Render every camera: ``rgb`` uint8 frames, and with ``geometry`` depth/valid/normal tensors."""
    from tqdm import tqdm

    from ..visual import render_layers, to_uint8

    out: dict[str, list] = {"rgb": [], "depth": [], "valid": [], "normal": []}
    for k in tqdm(range(len(cams)), desc=desc, disable=not progress, leave=False):
        lay = render_layers(backbone, cams[k:k + 1], alpha_min, normals=geometry)
        out["rgb"].append(to_uint8(lay["rgb"][0]))
        if geometry:
            out["depth"].append(lay["depth"][0])
            out["valid"].append(lay["valid"][0])
            out["normal"].append(lay["normal"][0])
    return out


def _depth_video(frames: dict) -> tuple[list[np.ndarray], list[float]]:
    """Turbo depth frames over one range for the whole video (1st..99th percentile of valid depth)."""
    import torch

    from ..visual import depth_rgb

    vals = torch.cat([d[v] for d, v in zip(frames["depth"], frames["valid"])])
    if vals.numel() == 0:
        lo, hi = 0.0, 1.0
    else:
        lo, hi = (float(x) for x in torch.quantile(vals.double()[:1_000_000], torch.tensor([0.01, 0.99],
                                                                                           dtype=torch.float64)))
    return [depth_rgb(d, v, lo, hi) for d, v in zip(frames["depth"], frames["valid"])], [lo, hi]


def render_orbit(run_dir: str | Path, out_dir: str | Path, rc: RenderConfig, progress: bool = True) -> dict:
    """Render the orbit videos of the run ``run_dir`` into ``out_dir``; returns paths and settings."""
    from ..orbit import orbit_cameras
    from ..runs import has_colour, load_run
    from ..video import write_video
    from ..visual import normal_rgb

    out_dir = Path(out_dir)
    t0 = time.perf_counter()
    grey = load_run(run_dir, colored=False)
    cams = orbit_cameras(grey.scene.train.cameras, grey.scene.bounds, rc.orbit())
    geometry = bool({"depth", "normal"} & set(rc.layers))
    result: dict[str, Any] = {"run": str(run_dir), "frames": len(cams), "fps": rc.fps,
                              "size": [cams.width, cams.height], "camera": cams.model, "videos": {}}
    if "gray" in rc.layers or geometry:
        fr = _frames(grey.backbone, cams, rc.alpha_min, geometry, progress, "render: grey orbit")
        if "gray" in rc.layers:
            result["videos"]["gray"] = str(write_video(out_dir / "orbit_gray", fr["rgb"], rc.fps))
        if "depth" in rc.layers:
            frames, result["depth_range"] = _depth_video(fr)
            result["videos"]["depth"] = str(write_video(out_dir / "orbit_depth", frames, rc.fps))
        if "normal" in rc.layers:
            frames = [normal_rgb(n, cams[k:k + 1], v) for k, (n, v) in enumerate(zip(fr["normal"], fr["valid"]))]
            result["videos"]["normal"] = str(write_video(out_dir / "orbit_normal", frames, rc.fps))
    if "color" in rc.layers:
        if has_colour(run_dir):
            col = load_run(run_dir, colored=True)
            fr = _frames(col.backbone, cams, rc.alpha_min, False, progress, "render: colour orbit")
            result["videos"]["color"] = str(write_video(out_dir / "orbit_color", fr["rgb"], rc.fps))
        else:
            result["note"] = "the run has no coloured (stage-2) model: no colour video"
    result["time_s"] = time.perf_counter() - t0
    return result


def run_render_stage(cfg: Any, scene: Any, run_dir: str | Path) -> dict:
    """``stage=render``: ``render.run`` is the finished run; the videos go into this job's ``run_dir``."""
    from ..runconfig import run_config

    rc = run_config(cfg).render
    if not rc.run:
        raise ConfigError("render.run is not set: add render.run=<a finished run folder>")
    if Path(rc.run).resolve() == Path(run_dir).resolve():
        raise ConfigError(f"render.run ({rc.run}) is this job's own folder; render into a new one")
    return {"render": render_orbit(rc.run, run_dir, rc)}
