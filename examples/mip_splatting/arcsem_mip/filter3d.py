"""Mip-Splatting's 3-D smoothing filter, as functions.

Each Gaussian ``k`` is seen by the training cameras at most at a sampling rate ``nu_k`` (pixels per world
unit: ``f / z`` for a pinhole at depth ``z``, ``fx`` for an orthographic camera; the highest over the cameras
whose image contains its centre). Detail finer than that was never observed, so the Gaussian is convolved
with an isotropic 3-D Gaussian of variance ``s / nu_k^2`` (``s`` in pixels^2): ``Sigma + (s / nu_k^2) I``,
and its opacity is scaled by ``sqrt(det Sigma / det(Sigma + (s / nu_k^2) I))`` so that its integral stays
the same. For the axis-aligned scales of a Gaussian both are per-axis operations.
"""
from __future__ import annotations

import torch
from torch import Tensor

from arcsem.cameras import Cameras

__all__ = ["apply_filter", "filter_variance"]


def filter_variance(means: Tensor, cams: Cameras, s: float) -> Tensor:
    """``[N]`` filter variances ``s / nu_k^2`` of centres ``means [N, 3]`` seen by ``cams``; a centre no camera
    sees gets the largest variance of the others (1 if none is seen)."""
    means = means.detach()
    cams = cams.to(device=means.device, dtype=means.dtype)
    uv, z = cams.project(means)  # [C, N, 2] pixels, [C, N] depth
    inside = (uv[..., 0] >= 0) & (uv[..., 0] <= cams.width) & (uv[..., 1] >= 0) & (uv[..., 1] <= cams.height)
    fx = cams.K[:, 0, 0][:, None]  # [C, 1]
    if cams.is_ortho:
        rate = fx.expand_as(z)
    else:
        inside &= z > 1e-6
        rate = fx / z.clamp_min(1e-6)
    nu = torch.where(inside, rate, torch.zeros_like(rate)).amax(0)  # [N]
    seen = nu > 0
    var = torch.where(seen, s / nu.clamp_min(1e-12) ** 2, torch.zeros_like(nu))
    fallback = var[seen].max() if bool(seen.any()) else torch.ones((), dtype=var.dtype, device=var.device)
    return torch.where(seen, var, fallback)


def apply_filter(scales: Tensor, opacities: Tensor, variance: Tensor) -> tuple[Tensor, Tensor]:
    """Scales ``[N, 3]`` and opacities ``[N]`` of the Gaussians convolved with variances ``[N]`` (see the
    module docstring): ``sqrt(scales^2 + v)`` and ``opacity * sqrt(prod(scales^2) / prod(scales^2 + v))``."""
    sq = scales * scales
    filtered = sq + variance[:, None]
    ratio = torch.exp(0.5 * (torch.log(sq).sum(-1) - torch.log(filtered).sum(-1)))
    return filtered.sqrt(), opacities * ratio
