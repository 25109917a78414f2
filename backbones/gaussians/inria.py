"""The folder layout that the common 3DGS viewers load (the INRIA reference code's output layout).

::

    <folder>/point_cloud/iteration_<N>/point_cloud.ply   Gaussians, 3 scales (ply.py's layout)
    <folder>/cameras.json                                the training cameras
    <folder>/cfg_args                                    SH degree (read by the SIBR viewer)

``cameras.json`` holds one entry per camera, as the reference code writes it: ``id``,
``img_name``, ``width``, ``height``, ``position`` (camera centre, world), ``rotation`` (3x3
camera-to-world rotation, rows; OpenCV axes: x right, y down, z forward), ``fx``, ``fy`` (pixels).
Orthographic cameras have no place in that format: they are written as the pinhole camera at the
same place whose pixel footprint at the scene centre is the same (``fx = f_ortho x distance``),
and carry ``"model": "orthographic"`` and their own ``fx_orthographic`` (pixels per unit) besides.

2DGS surfels have two scales. 3-scale viewers get ``scale_2 = log(min(s_0, s_1) / 100)``: a disc
100 times thinner than its smaller axis along the surfel's normal (the rotation's third column),
which such viewers draw as the flat splat it is (their 0.3 px screen-space dilation keeps it
visible edge-on). The native 2-scale file is kept beside it as ``point_cloud_2dgs.ply``.

Colours: the mean ACT (what arcsem renders for novel views) is baked into the SH coefficients, so a
viewer shows the model as arcsem does: ``W (SH + 0.5) + b = SH' + 0.5`` gives ``f_rest' = W f_rest``
and ``f_dc' = W f_dc + (0.5 W + b - 0.5) / C0`` (exact up to the clamping of negative colours).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import torch
from torch import Tensor

from arcsem.cameras import Cameras

from ..sh import C0
from .ply import write_ply

__all__ = ["THIN_RATIO", "bake_act", "camera_entries", "three_scales", "write_viewer_folder"]

THIN_RATIO = 0.01  # third scale of exported 2DGS surfels, relative to the smaller of the two


def three_scales(log_scales: Tensor) -> Tensor:
    """``[N, 2]`` surfel log-scales -> ``[N, 3]`` with a thin third axis (``[N, 3]`` passes through)."""
    if log_scales.shape[1] == 3:
        return log_scales
    thin = log_scales.min(dim=1, keepdim=True).values + math.log(THIN_RATIO)
    return torch.cat([log_scales, thin], 1)


def bake_act(params: dict[str, Tensor], act) -> dict[str, Tensor]:
    """Parameters whose SH colours include the mean ACT ``W, b`` (``act`` None: unchanged)."""
    if act is None:
        return params
    with torch.no_grad():
        W, b = act.transforms(torch.tensor([-1]))
        W, b = W[0].to(params["sh_dc"]).expand(3), b[0].to(params["sh_dc"]).expand(3)
        out = dict(params)
        out["sh_dc"] = params["sh_dc"] * W + (0.5 * W + b - 0.5) / C0
        out["sh_rest"] = params["sh_rest"] * W
    return out


def camera_entries(cams: Cameras, names: list[str], centre: Tensor) -> list[dict]:
    """``cameras.json`` entries of ``cams`` (see the module docstring); ``centre [3]``: the scene centre."""
    c2w = cams.cam_to_world.double()
    entries = []
    for i in range(len(cams)):
        fx, fy = float(cams.K[i, 0, 0]), float(cams.K[i, 1, 1])
        e = {"id": i, "img_name": names[i], "width": cams.width, "height": cams.height,
             "position": c2w[i, :3, 3].tolist(), "rotation": c2w[i, :3, :3].tolist(), "fx": fx, "fy": fy}
        if cams.is_ortho:
            dist = float(((centre.double() - c2w[i, :3, 3]) @ c2w[i, :3, 2]).abs())
            e.update(fx=fx * dist, fy=fy * dist, model="orthographic", fx_orthographic=fx, fy_orthographic=fy)
        entries.append(e)
    return entries


def write_viewer_folder(folder: str | Path, params: dict[str, Tensor], cams: Cameras, names: list[str],
                        centre: Tensor, iteration: int, act=None) -> dict[str, str]:
    """Write the viewer layout into ``folder``; returns ``{"ply", "cameras", "native_ply"?}`` paths.

    ``params``: the raw Gaussian parameters (``GaussianModel.params()``); 2-scale ones also get the
    native file ``point_cloud_2dgs.ply``.
    """
    folder = Path(folder)
    it_dir = folder / "point_cloud" / f"iteration_{int(iteration)}"
    it_dir.mkdir(parents=True, exist_ok=True)
    p = bake_act({k: v.detach().cpu().float() for k, v in params.items()}, act)
    out = {}
    if p["log_scales"].shape[1] == 2:
        write_ply(it_dir / "point_cloud_2dgs.ply", p)
        out["native_ply"] = str(it_dir / "point_cloud_2dgs.ply")
    write_ply(it_dir / "point_cloud.ply", {**p, "log_scales": three_scales(p["log_scales"])})
    out["ply"] = str(it_dir / "point_cloud.ply")
    tmp = folder / ".cameras.json.tmp"
    tmp.write_text(json.dumps(camera_entries(cams, names, centre), indent=1))
    tmp.replace(folder / "cameras.json")
    out["cameras"] = str(folder / "cameras.json")
    degree = math.isqrt(p["sh_rest"].shape[1] + 1) - 1  # as many f_rest_* as the PLY carries
    (folder / "cfg_args").write_text(f"Namespace(sh_degree={degree}, white_background=False)\n")
    return out
