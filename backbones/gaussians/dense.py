"""Pieces shared by the dense reference renderers of 2DGS and 3DGS (``gs2d/reference.py``, ``gs3d/reference.py``).

Plain code written for clarity, not speed: the tests compare the fast renderers with those references.
"""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["rotate_by_quat", "tile_mask"]


def rotate_by_quat(quats: Tensor, v: Tensor) -> Tensor:
    """Rotate ``v [3]`` by each unit quaternion ``[N, 4]`` (w, x, y, z): ``q v q*`` -> ``[N, 3]``."""
    q = quats / quats.norm(dim=-1, keepdim=True)
    w, r = q[:, :1], q[:, 1:]
    v = v.expand_as(r)
    t = 2 * torch.cross(r, v, dim=-1)
    return v + w * t + torch.cross(r, t, dim=-1)


def tile_mask(rects: Tensor, W: int, H: int, tile: int) -> Tensor:
    """``[N, 4]`` tile rectangles -> ``[H*W, N]`` bool: the pixel's tile is inside the splat's rectangle."""
    ys, xs = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    tx, ty = (xs.reshape(-1, 1) // tile), (ys.reshape(-1, 1) // tile)
    return (tx >= rects[:, 0]) & (tx < rects[:, 1]) & (ty >= rects[:, 2]) & (ty < rects[:, 3])
