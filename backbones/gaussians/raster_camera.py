"""Camera matrices for the rasterisers, built from :class:`arcsem.cameras.Cameras` (never re-derived).

One 4x4 world -> "pixel" matrix covers both camera models: applied to a homogeneous world point it
gives ``(x w, y w, w, z)``, where ``(x, y)`` is the pixel, ``w`` the homogeneous scale (camera z for
pinhole, 1 for orthographic) and ``z`` the camera depth.
"""
from __future__ import annotations

import torch
from torch import Tensor

from arcsem.cameras import Cameras

__all__ = ["camera_facing_normals", "pixel_projection"]


def pixel_projection(cams: Cameras) -> Tensor:
    """``[C, 4, 4]`` world -> ``(x w, y w, w, z)`` for pinhole and orthographic cameras (kept on the batch:
    :meth:`Cameras.derived`)."""
    return cams.derived("pixel_projection", _pixel_projection)


def _pixel_projection(cams: Cameras) -> Tensor:
    C = len(cams)
    w2c, K = cams.world_to_cam, cams.K
    A = torch.zeros(C, 4, 4, dtype=w2c.dtype, device=w2c.device)
    if cams.is_ortho:
        # x = fx X + s Y + cx, y = fy Y + cy (camera coordinates), w = 1
        A[:, :2, :2] = K[:, :2, :2]
        A[:, :2, 3] = K[:, :2, 2]
        A[:, 2, 3] = 1.0
        A[:, 3, 2] = 1.0
    else:
        A[:, :3, :3] = K
        A[:, 3, 2] = 1.0
    return A @ w2c


def camera_facing_normals(normals: Tensor, means: Tensor, cams: Cameras) -> Tensor:
    """Flip ``[N, 3]`` world normals to face each camera: ``[C, N, 3]``.

    Pinhole: ``n . (p - centre) <= 0``; orthographic: ``n . forward <= 0``.
    """
    if cams.is_ortho:
        view = cams.forward[:, None, :].expand(-1, means.shape[0], -1)
    else:
        view = means[None] - cams.centers[:, None, :]
    sign = torch.where((normals[None] * view).sum(-1, keepdim=True) > 0, -1.0, 1.0).to(normals.dtype)
    return normals[None] * sign
