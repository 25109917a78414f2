"""The box the grid spans: the part of the point cloud that the views frame.

A dataset's ``content_aabb`` (the box of all the views show, written by ``arcsem-calibrate``) is taken as given,
else its ``aabb``. Otherwise the scene's box is the point cloud's percentile box,
which on SEM data holds substrate points far outside what the views share, and a grid over it spends its
voxels there. The grid keeps the points that lie inside every training view's frustum (in front of the
camera, projecting into the image; inside at least half of them when fewer than ``min_points`` are in all)
and inside the cameras' box (:func:`arcsem.data.build.bounds_from_cameras`: the point nearest all optical
axes, half-size the largest image footprint there; a grazing view sees the stub far behind the specimen,
inside its frustum but not in that box), and bounds their 0.5-99.5 percentiles, padded by 5 % of the size.
The substrate beyond is the background model's (:mod:`.background`).
"""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["grid_bounds", "points_in_frusta"]


def points_in_frusta(points: Tensor, cameras) -> Tensor:
    """``[C, P]`` bool: point ``p`` lies in front of camera ``c`` and projects into its image."""
    uv, z = cameras.project(points.to(cameras.K.dtype))
    inside = (uv[..., 0] >= 0) & (uv[..., 0] <= cameras.width) & (uv[..., 1] >= 0) & (uv[..., 1] <= cameras.height)
    return inside & (z > 0)


def grid_bounds(scene, min_points: int = 100, pad: float = 0.05) -> Tensor:
    """``[2, 3]`` box of the grid for ``scene`` (see the module docstring); the scene's own box when the
    dataset gives one, when there is no point cloud, or when too few points are seen."""
    if getattr(scene, "content_bounds", None) is not None:
        return scene.content_bounds.float()
    pts = scene.points
    if scene.bounds_source == "given" or pts is None or len(pts) < min_points:
        return scene.bounds.float()
    from arcsem.data.build import bounds_from_cameras

    cams = scene.train.cameras
    box = bounds_from_cameras(cams)
    framed = ((pts >= box[0]) & (pts <= box[1])).all(-1)
    seen = points_in_frusta(pts, cams) & framed
    keep = seen.all(0)
    if int(keep.sum()) < min_points:
        keep = seen.float().mean(0) >= 0.5
    if int(keep.sum()) < min_points:
        return scene.bounds.float()
    p = pts[keep].double()
    q = torch.tensor([0.005, 0.995], dtype=p.dtype)
    lo, hi = torch.quantile(p, q[0], dim=0), torch.quantile(p, q[1], dim=0)
    d = (hi - lo).clamp_min(1e-6) * pad
    return torch.stack([lo - d, hi + d]).float()
