"""Procedural ground-truth colour ("albedo") of the grain, in an artist's spirit.

* body: red around the poles (the centre of the top view) fading to yellow towards the equator;
* spines: pale yellow, with a dark outline around each spine base;
* furrows (colpi): teal;
* substrate: neutral grey.

The coloured image of a view is ``albedo * (lo + hi * clean SEM grey)`` on a dark background.
"""
from __future__ import annotations

import torch
from torch import Tensor

from .sdf import Grain, _smoothstep, body_sdf, furrow_profile

__all__ = ["BACKGROUND_RGB", "SUBSTRATE_ALBEDO", "colorize", "grain_albedo"]

RED = (0.80, 0.10, 0.07)
YELLOW = (0.96, 0.78, 0.16)
SPINE = (1.00, 0.93, 0.62)
OUTLINE = (0.16, 0.07, 0.03)
FURROW = (0.10, 0.55, 0.58)
SUBSTRATE_ALBEDO = (0.3, 0.3, 0.3)
BACKGROUND_RGB = (0.02, 0.02, 0.02)


def _rgb(c, ref: Tensor) -> Tensor:
    return torch.tensor(c, dtype=ref.dtype, device=ref.device)


def _mix(a: Tensor, b: Tensor, w: Tensor) -> Tensor:
    return a + (b - a) * w[:, None]


def grain_albedo(g: Grain, p: Tensor) -> Tensor:
    """RGB albedo ``[N, 3]`` in [0, 1] of grain surface points ``p [N, 3]``."""
    q = p / g.radii.to(p)
    polar = (q[:, 2].abs() / q.norm(dim=-1).clamp_min(1e-9)).clamp(0, 1)  # |cos| of the polar angle
    body = _mix(_rgb(YELLOW, p).expand(len(p), 3), _rgb(RED, p).expand(len(p), 3), _smoothstep(0.25, 0.95, polar))
    body = _mix(body, _rgb(FURROW, p).expand(len(p), 3), _smoothstep(0.25, 0.6, furrow_profile(g, p)))
    # spines: how far the point stands out of the body; outline: ring around the nearest base
    height = body_sdf(g, p)
    col = _mix(body, _rgb(SPINE, p).expand(len(p), 3), _smoothstep(0.015, 0.05, height))
    base = g.spine_base.to(p)
    dist = torch.cdist(p, base).min(-1).values
    ring = torch.exp(-(((dist - 1.15 * g.spine_r0) / 0.022) ** 2)) * (1 - _smoothstep(0.02, 0.06, height))
    return _mix(col, _rgb(OUTLINE, p).expand(len(p), 3), 0.85 * ring)


def colorize(albedo: Tensor, grey: Tensor, lo: float = 0.25, hi: float = 1.1) -> Tensor:
    """Coloured pixels ``[N, 3]``: ``albedo [N, 3]`` modulated by the clean SEM grey ``[N]``."""
    return (albedo * (lo + hi * grey)[:, None]).clamp(0, 1)
