"""SEM-like secondary-electron shading, detector shadowing, exposure drift and scan noise.

All functions are pure; shapes are in the docstrings. Grey values are in ``[0, 1]``.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

__all__ = ["DETECTOR_CAM", "ShadingConfig", "detector_shadow", "drift_and_noise", "ellipsoid_shadow", "exposure_drift", "sem_grey"]

# Everhart-Thornley style side detector, fixed in the microscope (= camera) frame (OpenCV axes):
# to the right of the image, above it and towards the beam source.
DETECTOR_CAM = (0.7, -0.5, -0.5)


@dataclass
class ShadingConfig:
    """Parameters of the synthetic SEM contrast."""

    gain: float = 0.3            # yield of a surface facing the beam, before tone mapping
    max_secant: float = 6.0      # clamp of 1 / cos(tilt) at grazing angles
    edge_gain: float = 0.35      # extra brightness at high curvature (edges, spine tips)
    edge_scale: float = 0.03     # Laplacian of the SDF (1 / length) mapped to edge weight 1
    ambient: float = 0.45        # share of electrons collected regardless of the detector's direction
    substrate_gain: float = 0.3  # the substrate emits less than the specimen
    background: float = 0.02     # grey where a ray hits nothing


def sem_grey(normal: Tensor, view: Tensor, det: Tensor, lap: Tensor, shadow: Tensor, cfg: ShadingConfig) -> Tensor:
    """Grey level ``[N]`` of surface points.

    Args:
        normal: ``[N, 3]`` unit world normals. view: ``[N, 3]`` unit ray directions (camera -> point);
            the beam comes along ``view``, so ``tilt = angle(normal, -view)``.
        det: ``[N, 3]`` unit directions to the detector. lap: ``[N]`` SDF Laplacian (curvature).
        shadow: ``[N]`` in [0, 1], 1 = the detector sees the point.
    Secondary-electron yield ``~ 1 / cos(tilt)`` (clamped), edge brightening from curvature,
    detector term ``ambient + (1 - ambient) * shadow * facing``; tone-mapped ``1 - exp(-x)``.
    """
    cos_tilt = (-(normal * view).sum(-1)).clamp(min=1.0 / cfg.max_secant)
    secant = 1.0 / cos_tilt
    facing = 0.4 + 0.6 * (normal * det).sum(-1).clamp(min=0)
    collect = cfg.ambient + (1 - cfg.ambient) * shadow * facing
    edge = cfg.edge_gain * (lap * cfg.edge_scale).clamp(0, 1)
    raw = cfg.gain * secant * collect + edge
    return 1 - torch.exp(-1.3 * raw)


def detector_shadow(sdf: Callable[[Tensor], Tensor], p: Tensor, normal: Tensor, det: Tensor,
                    steps: int = 10, reach: float = 2.5, k: float = 10.0) -> Tensor:
    """Soft visibility ``[N]`` in [0, 1] of points ``p [N, 3]`` from the detector directions ``det [N, 3]``.

    A short march of ``steps`` SDF steps from ``p + 0.01 normal`` towards ``det`` keeps the
    penumbra estimate ``min(k * sdf / t)`` (1 = unoccluded).
    """
    start = p + 0.01 * normal
    t = torch.full_like(p[:, 0], 0.02)
    vis = torch.ones_like(t)
    for _ in range(steps):
        d = sdf(start + t[:, None] * det)
        vis = torch.minimum(vis, (k * d / t).clamp(0, 1))
        t = t + d.clamp(0.03, 0.4)
        if bool((t > reach).all()):
            break
    return vis


def ellipsoid_shadow(p: Tensor, det: Tensor, radii: Tensor, soft: float = 0.12) -> Tensor:
    """Visibility ``[N]`` from the detector of points ``p [N, 3]`` (e.g. on the substrate) shadowed by
    the ellipsoid ``radii [3]`` at the origin, analytically: in coordinates scaled by ``1/radii``
    the ellipsoid is the unit sphere and the shadow ray a line; the closest approach ``m`` of the
    line (ahead of ``p``) gives ``smoothstep(1 - soft, 1 + soft, m)``. Cheap stand-in for a march.
    """
    q, e = p / radii, det / radii
    t = (-(q * e).sum(-1) / (e * e).sum(-1)).clamp_min(0)
    m = (q + t[:, None] * e).norm(dim=-1)
    x = ((m - (1 - soft)) / (2 * soft)).clamp(0, 1)
    return x * x * (3 - 2 * x)


def exposure_drift(rng: np.random.Generator, drift: float) -> tuple[float, float]:
    """An image's ``(contrast, brightness)``: log-normal contrast (sigma ``drift``), normal brightness
    (sigma ``drift / 2``); the first two draws of ``rng`` (so the truth can be recomputed from the seed)."""
    return float(np.exp(rng.normal(0.0, drift))), float(rng.normal(0.0, 0.5 * drift))


def drift_and_noise(grey: np.ndarray, rng: np.random.Generator, drift: float, noise: float,
                    row_jitter: float) -> np.ndarray:
    """Observed image ``[H, W]`` from a clean one: contrast/brightness drift, then scan noise.

    ``drift`` scales the per-image contrast (log-normal) and brightness (normal) changes;
    ``noise`` the per-pixel Gaussian noise; ``row_jitter`` a per-scan-line brightness offset.
    """
    contrast, brightness = exposure_drift(rng, drift)
    out = grey * contrast + brightness  # an affine change, as ACT models it
    out = out + rng.normal(0.0, row_jitter, size=(grey.shape[0], 1))
    out = out + rng.normal(0.0, noise, size=grey.shape)
    return np.clip(out, 0.0, 1.0)
