"""A second procedural specimen: a centric diatom frustule with concavities and self-occlusion.

World axes as for the grain (``z`` up = the frustule's axis, centred at the origin, diameter 2 units).
Construction (signed distance, vectorised torch, deterministic per seed):

* body: a rounded cylinder (a pillbox: radius ``radius``, half height ``half_height``) with
  ``n_girdle`` grooves around its side (girdle bands: subtracted tori);
* valve face: a shallow dish (concavity) cut by a large sphere, with a smooth central area and
  ``n_rows`` radial rows of pits (areolae, subtracted spheres) on ``n_rings`` rings;
* marginal spines: ``n_spines`` tubes rising from the rim and bending inwards over the dish (two
  capsules each): they overhang the outer pits, hide one another and cast shadows.

Repeated parts are evaluated by angular domain repetition: a point is rotated into its sector, and
the pits of that sector (disjoint from their sector's borders) and the spines of that sector and its
two neighbours are evaluated, so the distance is exact near the surface and a safe bound elsewhere.

Colours (an artist's choice, each tied to a structure so that a correspondence module can carry
it): dish teal fading to blue towards the rim, pits dark navy, central area pale yellow, spines
orange, rim pale mint, girdle bands alternating lilac and pink, the lower valve grey-green.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch
from torch import Tensor

from .sdf import _smoothstep

__all__ = ["Diatom", "diatom_albedo", "diatom_parts", "make_diatom"]

TEAL, BLUE, NAVY = (0.15, 0.62, 0.60), (0.16, 0.30, 0.78), (0.05, 0.07, 0.30)
CENTRE, SPINE, RIM = (0.97, 0.90, 0.55), (0.95, 0.50, 0.10), (0.75, 0.95, 0.82)
LILAC, PINK, LOWER = (0.70, 0.55, 0.90), (0.95, 0.55, 0.70), (0.45, 0.58, 0.42)


@dataclass
class Diatom:
    """Parameters of one frustule (lengths in world units; ``phase`` rotates the repeated parts)."""

    phase: float = 0.0
    radius: float = 0.95
    half_height: float = 0.30
    rounding: float = 0.10
    dish_depth: float = 0.14
    dish_radius: float = 0.80     # the dish reaches this far from the axis
    n_rows: int = 16              # radial rows of pits
    n_rings: int = 3
    pit_r: float = 0.045
    ring0: float = 0.30
    ring_step: float = 0.15
    n_spines: int = 12
    spine_r: float = 0.045
    n_girdle: int = 3
    groove_r: float = 0.03
    substrate_z: float = -0.6
    size: float = 2.0
    dtype: torch.dtype = torch.float64  # of the tensors it hands out (radii, aabb); its SDF follows the points

    @property
    def radii(self) -> Tensor:
        """``[3]`` an ellipsoid around the body (the substrate's analytic detector shadow)."""
        return torch.tensor([self.radius, self.radius, self.half_height + 0.15], dtype=self.dtype)

    @property
    def bound_radius(self) -> float:
        return float(math.hypot(self.radius, self.half_height + 0.5) + 0.05)

    @property
    def aabb(self) -> Tensor:
        r = self.radius + 0.02
        return torch.tensor([[-r, -r, -self.half_height - 0.02], [r, r, self.half_height + 0.5]], dtype=self.dtype)

    def to(self, dtype: torch.dtype) -> Diatom:
        return replace(self, dtype=dtype)

    def sdf(self, p: Tensor) -> Tensor:
        return diatom_parts(self, p)["sdf"]

    def albedo(self, p: Tensor) -> Tensor:
        return diatom_albedo(self, p)


def make_diatom(seed: int = 0) -> Diatom:
    """A frustule whose repeated parts are rotated by a seed-dependent phase."""
    rng = np.random.default_rng(seed)
    return Diatom(phase=float(rng.uniform(0, 2 * math.pi)))


def _sector(p: Tensor, n: int, phase: float, shift: int = 0) -> tuple[Tensor, Tensor]:
    """``p [N, 3]`` rotated into its angular sector (``n`` sectors; ``shift`` picks a neighbour): the rotated
    point ``[N, 3]`` (the sector's mid-plane is ``y = 0``, ``x > 0``) and the sector index ``[N]``."""
    step = 2 * math.pi / n
    ang = torch.atan2(p[:, 1], p[:, 0]) - phase
    k = torch.round(ang / step) + shift
    a = -(k * step + phase)
    c, s = torch.cos(a), torch.sin(a)
    x = c * p[:, 0] - s * p[:, 1]
    y = s * p[:, 0] + c * p[:, 1]
    return torch.stack([x, y, p[:, 2]], -1), k


def _capsule(p: Tensor, a: Tensor, b: Tensor, r: float) -> Tensor:
    ab = b - a
    t = (((p - a) * ab).sum(-1) / (ab * ab).sum()).clamp(0, 1)
    return (p - a - t[:, None] * ab).norm(dim=-1) - r


def _dish(d: Diatom) -> tuple[float, float]:
    """Centre height and radius of the sphere that cuts the dish."""
    rs = (d.dish_radius**2 + d.dish_depth**2) / (2 * d.dish_depth)
    return d.half_height + rs - d.dish_depth, rs


def _spines(d: Diatom, p: Tensor) -> Tensor:
    """Distance ``[N]`` to the nearest marginal spine (own sector and both neighbours)."""
    h = d.half_height
    pts = torch.tensor([[d.radius - 0.08, 0, h - 0.03], [d.radius - 0.03, 0, h + 0.30],
                        [d.radius - 0.28, 0, h + 0.45]], dtype=p.dtype)
    best = torch.full_like(p[:, 0], float("inf"))
    for shift in (-1, 0, 1):
        q, _ = _sector(p, d.n_spines, d.phase + math.pi / d.n_spines, shift)
        s = torch.minimum(_capsule(q, pts[0], pts[1], d.spine_r), _capsule(q, pts[1], pts[2], 0.8 * d.spine_r))
        best = torch.minimum(best, s)
    return best


def _pits(d: Diatom, p: Tensor) -> Tensor:
    """Distance ``[N]`` to the pit spheres of the point's sector (sitting on the dish surface)."""
    q, _ = _sector(p, d.n_rows, d.phase)
    r = q[:, 0]
    k = torch.round((r - d.ring0) / d.ring_step).clamp(0, d.n_rings - 1)
    rc = d.ring0 + k * d.ring_step
    cz, rs = _dish(d)
    zc = cz - torch.sqrt((rs**2 - rc**2).clamp_min(0))
    centre = torch.stack([rc, torch.zeros_like(rc), zc], -1)
    return (q - centre).norm(dim=-1) - d.pit_r


def diatom_parts(d: Diatom, p: Tensor) -> dict[str, Tensor]:
    """Signed distance ``sdf [N]`` of points ``p [N, 3]`` and its parts (``body``, ``spine``, ``pit``)."""
    rad = p[:, :2].norm(dim=-1)
    q = torch.stack([rad - d.radius + d.rounding, p[:, 2].abs() - d.half_height + d.rounding], -1)
    body = q.clamp_min(0).norm(dim=-1) + q.max(-1).values.clamp_max(0) - d.rounding
    for z in np.linspace(-0.5, 0.5, d.n_girdle) * d.half_height:  # girdle grooves (tori on the side)
        torus = torch.stack([rad - d.radius, p[:, 2] - float(z)], -1).norm(dim=-1) - d.groove_r
        body = torch.maximum(body, -torus)
    cz, rs = _dish(d)
    sphere = (p - torch.tensor([0.0, 0.0, cz], dtype=p.dtype)).norm(dim=-1) - rs
    body = torch.maximum(body, -sphere)
    pit = _pits(d, p)
    body = torch.maximum(body, -pit)
    spine = _spines(d, p)
    return {"sdf": torch.minimum(body, spine), "body": body, "spine": spine, "pit": pit, "radial": rad}


def _rgb(c, ref: Tensor) -> Tensor:
    return torch.tensor(c, dtype=ref.dtype).expand(len(ref), 3)


def _mix(a: Tensor, b: Tensor, w: Tensor) -> Tensor:
    return a + (b - a) * w[:, None]


def diatom_albedo(d: Diatom, p: Tensor) -> Tensor:
    """RGB albedo ``[N, 3]`` in [0, 1] of frustule surface points ``p [N, 3]`` (see the module docstring)."""
    parts = diatom_parts(d, p)
    r, z = parts["radial"], p[:, 2]
    dish = _mix(_rgb(TEAL, p), _rgb(BLUE, p), _smoothstep(0.35, 0.8, r))
    dish = _mix(dish, _rgb(CENTRE, p), 1 - _smoothstep(0.17, 0.23, r))
    dish = _mix(dish, _rgb(NAVY, p), 1 - _smoothstep(-0.004, 0.012, parts["pit"]))
    band = 0.5 + 0.5 * torch.sign(torch.sin(math.pi * (z / d.half_height) * 1.5 + 0.3))
    side = _mix(_rgb(LILAC, p), _rgb(PINK, p), band)
    side = _mix(_rgb(LOWER, p), side, _smoothstep(-0.2, -0.1, z))
    face = _smoothstep(0.06, 0.12, z) * (1 - _smoothstep(0.84, 0.9, r))         # the dish of the upper valve
    col = _mix(side, dish, face)
    col = _mix(col, _rgb(RIM, p), _smoothstep(0.17, 0.23, z) * _smoothstep(0.84, 0.9, r))
    return _mix(col, _rgb(SPINE, p), 1 - _smoothstep(0.0, 0.015, parts["spine"]))
