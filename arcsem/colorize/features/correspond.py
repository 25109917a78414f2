"""Pixel correspondences between two views from depth and cameras (the geometry known after stage 1).

A pixel of view ``a`` with depth ``z`` is unprojected (:meth:`arcsem.cameras.Cameras.unproject_points`)
and projected into view ``b``; it corresponds to the pixel it lands on if that pixel lies in the image,
has a depth, and sees the same surface: ``|depth_b - z_b| <= tol`` pixel footprints (occlusion test).
"""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["correspondences", "downscale_geometry"]


def downscale_geometry(depths: Tensor, masks: Tensor, factor: int) -> tuple[Tensor, Tensor]:
    """Depth ``[N, H, W]`` and masks to ``H // f x W // f`` by taking each cell's centre pixel (no mixing of
    depths across silhouettes); ``f = 1``: unchanged."""
    if factor == 1:
        return depths, masks
    h, w = depths.shape[1] // factor, depths.shape[2] // factor
    ys = torch.arange(h) * factor + factor // 2
    xs = torch.arange(w) * factor + factor // 2
    return depths[:, ys][:, :, xs], masks[:, ys][:, :, xs]


def _footprint(cam, z: Tensor) -> Tensor:
    fx = cam.K[0, 0, 0].to(z.dtype)
    return torch.full_like(z, 1.0) / fx if cam.is_ortho else z.abs() / fx


def correspondences(cams, depths: Tensor, masks: Tensor, a: int, b: int, pixels: Tensor,
                    tol: float = 3.0) -> tuple[Tensor, Tensor, Tensor]:
    """Where pixels of view ``a`` land in view ``b``.

    Args:
        cams: ``N`` cameras (of the ``H x W`` depth maps). depths: ``[N, H, W]`` z-depth, <= 0 = none.
        masks: ``[N, H, W]`` bool. pixels: ``[P, 2]`` long ``(x, y)`` pixel indices of view ``a``.
        tol: occlusion tolerance in pixel footprints of view ``b`` at the projected depth.
    Returns:
        ``uv_a [M, 2]``, ``uv_b [M, 2]`` float pixel coordinates (pixel centres at ``+0.5``) of the ``M``
        pixels that correspond, and their indices ``[M]`` into ``pixels``.
    """
    H, W = depths.shape[1:]
    x, y = pixels[:, 0], pixels[:, 1]
    z = depths[a, y, x].double()
    ok = (z > 0) & masks[a, y, x]
    uv_a = torch.stack([x.double() + 0.5, y.double() + 0.5], -1)
    pts = cams[a].to(dtype=torch.float64).unproject_points(uv_a[None], z[None])[0]
    uv_b, z_b = cams[b].to(dtype=torch.float64).project(pts)
    uv_b, z_b = uv_b[0], z_b[0]
    xb, yb = uv_b[:, 0].floor().long(), uv_b[:, 1].floor().long()
    ok &= (xb >= 0) & (xb < W) & (yb >= 0) & (yb < H)
    xb, yb = xb.clamp(0, W - 1), yb.clamp(0, H - 1)
    d_b = depths[b, yb, xb].double()
    ok &= (d_b > 0) & masks[b, yb, xb] & ((d_b - z_b).abs() <= tol * _footprint(cams[b], z_b))
    idx = ok.nonzero()[:, 0]
    return uv_a[idx].float(), uv_b[idx].float(), idx
