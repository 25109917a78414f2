"""Initial Gaussians from a point cloud, or at random inside the scene bounds (official recipe).

* scale: ``sqrt(mean of the squared distances to the 3 nearest neighbours)`` (the official
  ``distCUDA2`` statistic), clamped to ``>= sqrt(1e-7)``, same value on every axis;
* opacity ``init_opacity`` (0.1) -> logit; colour: DC from the point colours, higher SH zero;
* rotation: identity (3DGS) or uniformly random unit quaternions (2DGS, whose official code
  starts from random rotations so that surfels do not all face one axis).
"""
from __future__ import annotations

import math

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from ..sh import num_sh_coeffs, rgb_to_sh

__all__ = ["init_gaussians", "knn_scales", "random_points"]


def knn_scales(points: Tensor, k: int = 3) -> Tensor:
    """``[P]`` root-mean-square distance of each point to its ``k`` nearest other points."""
    p = points.detach().cpu().double().numpy()
    if len(p) < 2:
        return torch.full((len(p),), 0.01, dtype=points.dtype)
    kk = min(k, len(p) - 1)
    d, _ = cKDTree(p).query(p, k=kk + 1, workers=-1)
    d2 = (np.asarray(d).reshape(len(p), -1)[:, 1:] ** 2).mean(1)
    return torch.from_numpy(np.sqrt(np.maximum(d2, 1e-7))).to(points.dtype)


def random_points(bounds: Tensor, n: int, generator: torch.Generator | None = None) -> Tensor:
    """``[n, 3]`` uniform points inside the box ``bounds [2, 3]`` (min, max)."""
    lo, hi = bounds[0].float(), bounds[1].float()
    return lo + (hi - lo) * torch.rand(n, 3, generator=generator)


def init_gaussians(
    points: Tensor,
    colors: Tensor | None = None,
    *,
    num_scales: int = 3,
    sh_degree: int = 3,
    opacity: float = 0.1,
    random_rotations: bool = False,
    generator: torch.Generator | None = None,
) -> dict[str, Tensor]:
    """Raw parameters (see :mod:`.model`) for Gaussians centred on ``points [P, 3]``.

    Args:
        colors: ``[P, 3]`` in [0, 1]; default grey 0.5.
        num_scales: 3 (3DGS) or 2 (2DGS surfels).
    Returns:
        dict with means ``[P,3]``, quats ``[P,4]``, log_scales ``[P,num_scales]``, opacity_logits ``[P]``,
        sh_dc ``[P,1,3]``, sh_rest ``[P,K-1,3]``.
    """
    points = points.float()
    P = len(points)
    if colors is None:
        colors = torch.full((P, 3), 0.5)
    scale = knn_scales(points)
    if random_rotations:
        quats = torch.nn.functional.normalize(torch.randn(P, 4, generator=generator), dim=-1)
    else:
        quats = torch.zeros(P, 4)
        quats[:, 0] = 1
    return {
        "means": points.clone(),
        "quats": quats,
        "log_scales": torch.log(scale)[:, None].repeat(1, num_scales).float(),
        "opacity_logits": torch.full((P,), math.log(opacity / (1 - opacity))),
        "sh_dc": rgb_to_sh(colors.float())[:, None, :],
        "sh_rest": torch.zeros(P, num_sh_coeffs(sh_degree) - 1, 3),
    }
