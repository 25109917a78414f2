"""Signed distance function of a procedural pollen grain (echinate, tricolpate, oblate), and its albedo.

World axes of the synthetic scene: ``z`` is up and is the grain's polar axis; the grain is centred
at the origin; the optional substrate is the plane ``z = Grain.substrate_z`` below it. The grain
size (equatorial body diameter) is ``2`` world units.

Construction (all vectorised torch, any float dtype, deterministic per seed):

* body: oblate ellipsoid with radii ``radii`` (approximate distance ``k0 (k0 - 1) / k1``, exact on
  the surface), minus three meridional furrows (colpi: Gaussian grooves in the distance to the
  furrow's meridian plane, tapered towards the poles), plus a small sinusoidal surface relief;
* spines: round cones (base radius ``spine_r0``, tip radius ``spine_r1``) standing on the body
  along its normals, united with the body by a polynomial smooth minimum (exactly ``min`` once
  the two distances differ by more than ``blend``). Spines are spaced so that their dilated
  angular extents ("reach cones") are disjoint; per point only the one spine whose reach cone
  contains the point's direction is evaluated: the others cannot change the smooth minimum.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch
from torch import Tensor

__all__ = [
    "Grain",
    "body_sdf",
    "ellipsoid",
    "fibonacci_sphere",
    "furrow_profile",
    "grain_albedo",
    "grain_sdf",
    "make_grain",
    "nearest_spine",
    "round_cone",
    "smooth_min",
    "spine_cos_reach",
]


@dataclass
class Grain:
    """Parameters of one grain (all lengths in world units; tensors float64 on CPU).

    Attributes:
        radii: ``[3]`` ellipsoid radii of the body.
        spine_dirs: ``[S, 3]`` unit directions (from the centre) of the spine bases.
        spine_base: ``[S, 3]`` base points on the ellipsoid; ``spine_axis``: ``[S, 3]`` unit normals.
        spine_len: ``[S]`` spine lengths (base to tip centre).
        furrow_dirs: ``[F, 3]`` unit horizontal directions of the furrows (colpi).
        relief_phase: ``[3]`` phases of the surface relief.
    """

    radii: Tensor
    spine_dirs: Tensor
    spine_base: Tensor
    spine_axis: Tensor
    spine_len: Tensor
    furrow_dirs: Tensor
    relief_phase: Tensor
    spine_cos: Tensor | None = None  # [S] cached spine_cos_reach (set by make_grain)
    spine_nn: Tensor | None = None   # [S] angle to the nearest other spine direction (set by make_grain)
    spine_r0: float = 0.075    # spine base radius
    spine_r1: float = 0.01     # spine tip radius
    blend: float = 0.04        # smooth-min width of the spine/body union
    furrow_depth: float = 0.07
    furrow_width: float = 0.11
    relief_amp: float = 0.006
    relief_freq: float = 22.0
    substrate_z: float = -1.0
    size: float = 2.0          # grain size (equatorial body diameter), the unit of tolerances

    @property
    def bound_radius(self) -> float:
        """Radius of a sphere around the origin that contains the whole grain."""
        return float(self.radii.max() + self.spine_len.max() + self.spine_r1 + 0.05)

    @property
    def aabb(self) -> Tensor:
        """``[2, 3]`` box (min, max) that contains the grain."""
        tips = self.spine_base + self.spine_axis * (self.spine_len[:, None] + self.spine_r1)
        ext = torch.maximum(tips.abs().amax(0), self.radii) + 0.02
        return torch.stack([-ext, ext])

    def to(self, dtype: torch.dtype) -> Grain:
        """A copy with every tensor in ``dtype`` (float32 for fast rendering)."""
        conv = {k: v.to(dtype) for k, v in vars(self).items() if isinstance(v, Tensor)}
        return replace(self, **conv)

    def sdf(self, p: Tensor) -> Tensor:
        """Signed distance ``[N]`` of points ``p [N, 3]`` (negative inside)."""
        return grain_sdf(self, p)[0]

    def albedo(self, p: Tensor) -> Tensor:
        """RGB albedo ``[N, 3]`` of surface points (:func:`grain_albedo`)."""
        return grain_albedo(self, p)


def fibonacci_sphere(n: int) -> np.ndarray:
    """``[n, 3]`` unit vectors spread evenly over the sphere (the Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = math.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z**2)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


def make_grain(seed: int = 0, n_spines: int = 30) -> Grain:
    """A grain with up to ``n_spines`` spines away from 3 furrows; deterministic for ``seed``.

    Spines are picked greedily in random order so that their reach cones (see
    :func:`spine_cos_reach`) are disjoint: each point is within reach of at most one spine, which
    keeps :func:`grain_sdf` to one cone evaluation per point and equal to the union of all spines.
    """
    rng = np.random.default_rng(seed)
    radii = np.array([1.0, 1.0, 0.75])
    phi0 = rng.uniform(0, 2 * math.pi / 3)
    fphi = phi0 + np.arange(3) * 2 * math.pi / 3
    furrows = np.stack([np.cos(fphi), np.sin(fphi), np.zeros(3)], -1)
    cand = fibonacci_sphere(8 * n_spines) @ _rotation(rng).T
    side = np.cross(np.array([0.0, 0.0, 1.0]), furrows)  # [3, 3] normals of the meridian planes
    near = (np.abs(cand @ side.T) < 0.25) & (cand @ furrows.T > 0) & (np.abs(cand[:, 2]) < 0.8)[:, None]
    cand = cand[~near.any(1)]
    t = lambda a: torch.as_tensor(a, dtype=torch.float64)
    base = cand / np.linalg.norm(cand / radii, axis=-1, keepdims=True)
    axis = base / radii**2
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    g = Grain(
        radii=t(radii), spine_dirs=t(cand), spine_base=t(base), spine_axis=t(axis),
        spine_len=t(rng.uniform(0.17, 0.22, len(cand))), furrow_dirs=t(furrows),
        relief_phase=t(rng.uniform(0, 2 * math.pi, 3)),
    )
    half = torch.arccos(spine_cos_reach(g)).numpy()
    slack = half.max() - half.min() + 0.02  # makes the in-reach spine also the nearest in angle
    keep: list[int] = []
    for i in rng.permutation(len(cand)):
        ang = np.arccos(np.clip(cand[keep] @ cand[i], -1, 1))
        if np.all(ang > half[keep] + half[i] + slack):
            keep.append(int(i))
        if len(keep) == n_spines:
            break
    keep_t = torch.as_tensor(sorted(keep))
    g = replace(g, spine_dirs=g.spine_dirs[keep_t], spine_base=g.spine_base[keep_t],
                spine_axis=g.spine_axis[keep_t], spine_len=g.spine_len[keep_t])
    g.spine_cos = spine_cos_reach(g)
    cosnn = g.spine_dirs @ g.spine_dirs.T - 3 * torch.eye(len(keep), dtype=torch.float64)
    g.spine_nn = torch.arccos(cosnn.amax(-1).clamp(-1, 1))
    return g


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def ellipsoid(p: Tensor, radii: Tensor) -> Tensor:
    """Approximate signed distance ``[N]`` to an ellipsoid ``radii [3]`` (exact zero set)."""
    k0 = (p / radii).norm(dim=-1)
    k1 = (p / radii**2).norm(dim=-1).clamp_min(1e-9)
    return k0 * (k0 - 1) / k1


def round_cone(p: Tensor, a: Tensor, b: Tensor, r0: float, r1: float) -> Tensor:
    """Signed distance ``[...]`` to the convex hull of sphere ``(a, r0)`` and sphere ``(b, r1)``.

    ``p [..., 3]``, ``a, b [..., 3]`` (broadcast). Reduced to 2-D (axial ``y``, radial ``x``): the
    side line touches both circles with outward normal ``(cos al, sin al)``, ``sin al = (r0-r1)/l``.
    """
    axis = b - a
    length = axis.norm(dim=-1)
    u = axis / length[..., None]
    q = p - a
    y = (q * u).sum(-1)
    x = (q - y[..., None] * u).norm(dim=-1)
    sin_a = (r0 - r1) / length
    cos_a = (1 - sin_a**2).clamp_min(0).sqrt()
    tang = -x * sin_a + y * cos_a
    side = x * cos_a + y * sin_a - r0
    d0 = torch.sqrt(x**2 + y**2) - r0
    d1 = torch.sqrt(x**2 + (y - length) ** 2) - r1
    return torch.where(tang < 0, d0, torch.where(tang > length * cos_a, d1, side))


def smooth_min(a: Tensor, b: Tensor, k: float) -> Tensor:
    """Polynomial smooth minimum; equals ``min(a, b)`` where ``|a - b| >= k``."""
    h = (0.5 + 0.5 * (b - a) / k).clamp(0, 1)
    return b + (a - b) * h - k * h * (1 - h)


def furrow_profile(g: Grain, p: Tensor) -> Tensor:
    """``[N]`` in [0, 1]: 1 on the floor of a furrow, 0 away from them."""
    fd = g.furrow_dirs.to(p)
    side = torch.cross(torch.tensor([0.0, 0.0, 1.0], dtype=p.dtype).expand_as(fd), fd, dim=-1)
    lateral = p @ side.T                                   # [N, F]
    front = ((p @ fd.T) / 0.3).clamp(0, 1)                 # only the half-plane of the furrow
    zc = (p[:, 2].abs() / g.radii[2].item()).clamp(0, 1)
    taper = 1 - _smoothstep(0.6, 0.85, zc)
    prof = torch.exp(-((lateral / g.furrow_width) ** 2)) * front**2 * (3 - 2 * front)
    return prof.amax(-1) * taper


def _smoothstep(e0: float, e1: float, x: Tensor) -> Tensor:
    t = ((x - e0) / (e1 - e0)).clamp(0, 1)
    return t * t * (3 - 2 * t)


def body_sdf(g: Grain, p: Tensor) -> Tensor:
    """Signed distance ``[N]`` of the body (ellipsoid + furrows + relief), no spines."""
    d = ellipsoid(p, g.radii.to(p))
    d = d + g.furrow_depth * furrow_profile(g, p)
    ph = g.relief_phase.to(p)
    f = g.relief_freq
    rel = torch.sin(f * p[:, 0] + ph[0]) * torch.sin(f * p[:, 1] + ph[1]) * torch.sin(f * p[:, 2] + ph[2])
    return d + g.relief_amp * rel


def spine_cos_reach(g: Grain, margin: float = 0.03) -> Tensor:
    """``[S]`` cosine of the half-angle (seen from the origin) of each spine dilated by the blend.

    A point whose direction is farther than that from ``spine_dirs[j]`` cannot be within
    ``blend + margin`` of spine ``j``: the dilated spine lies in the hull of two balls (around its
    base and its tip), whose angular extents bound the hull's.
    """
    start = g.spine_base - g.spine_axis * 0.03
    tip = g.spine_base + g.spine_axis * g.spine_len[:, None]
    rho = g.spine_r0 + g.blend + margin
    ang = []
    for e in (start, tip):
        c = (e * g.spine_dirs).sum(-1) / e.norm(dim=-1)
        ang.append(torch.arccos(c.clamp(-1, 1)) + torch.arcsin((rho / e.norm(dim=-1)).clamp(max=1)))
    return torch.cos(torch.maximum(*ang))


def nearest_spine(g: Grain, p: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The spine nearest in direction to ``p [N, 3]``, its distance, and a lower bound of the
    distance to every other spine.

    Returns the spine index ``j [N]`` (largest cosine; :func:`make_grain` spaces the spines so that
    a point in a reach cone has that spine as its nearest), the round-cone distance ``[N]``
    (``inf`` where ``j`` cannot reach the point) and ``[N]`` ``cap + |p| sin(gap)``, with ``gap``
    the angle from ``p`` to any other spine direction (at least ``max(a_j, nn_j - a_j)``; ``a_j``
    if ``j`` itself is out of reach) minus the widest reach angle: spines lie in their reach
    cones, ``cap = blend + 0.03`` inside.
    """
    r = p.norm(dim=-1).clamp_min(1e-9)
    cos, j = (p @ g.spine_dirs.to(p).T).max(-1)
    ang = torch.arccos((cos / r).clamp(-1, 1))
    reach_cos = g.spine_cos if g.spine_cos is not None else spine_cos_reach(g)
    inside = ang < torch.arccos(reach_cos.to(p))[j]
    nn = g.spine_nn.to(p)[j]
    near_ang = torch.where(inside, torch.maximum(ang, nn - ang), ang)  # ang: j itself is out of reach
    gap = (near_ang - torch.arccos(reach_cos.min()).item()).clamp(0, math.pi / 2)
    others = g.blend + 0.03 + r * torch.sin(gap)
    base, axis = g.spine_base.to(p)[j], g.spine_axis.to(p)[j]
    tip = base + axis * g.spine_len.to(p)[j][:, None]
    d = round_cone(p, base - axis * 0.03, tip, g.spine_r0, g.spine_r1)
    return j, torch.where(inside, d, torch.full_like(d, float("inf"))), others


def grain_sdf(g: Grain, p: Tensor) -> tuple[Tensor, Tensor]:
    """Signed distance ``[N]`` and body distance ``[N]`` at ``p [N, 3]``.

    ``smooth_min(body, spine j)`` with the one spine ``j`` that can reach the point, then capped by
    a lower bound of the distance to every other spine (see :func:`nearest_spine`; also at least
    ``d_body - height``, spines standing at most ``height`` above the body). Exact wherever the
    distance is below ``blend + 0.03`` (the surface), a safe lower bound elsewhere (for tracing).
    """
    d_body = body_sdf(g, p)
    _, d_spine, others = nearest_spine(g, p)
    d = smooth_min(d_body, d_spine.clamp(max=1e3), g.blend)
    height = float(g.spine_len.max()) + g.spine_r1 + 0.05
    return torch.minimum(d, torch.maximum(others, d_body - height)), d_body


# The grain's ground-truth colour (albedo); :mod:`arcsem.synthetic.albedo` turns it into pixels.
RED = (0.80, 0.10, 0.07)
YELLOW = (0.96, 0.78, 0.16)
SPINE = (1.00, 0.93, 0.62)
OUTLINE = (0.16, 0.07, 0.03)
FURROW = (0.10, 0.55, 0.58)


def _rgb(c, ref: Tensor) -> Tensor:
    return torch.tensor(c, dtype=ref.dtype, device=ref.device)


def _mix(a: Tensor, b: Tensor, w: Tensor) -> Tensor:
    return a + (b - a) * w[:, None]


def grain_albedo(g: Grain, p: Tensor) -> Tensor:
    """RGB albedo ``[N, 3]`` in [0, 1] of grain surface points ``p [N, 3]``, in an artist's spirit: the body red
    around the poles (the centre of the top view) fading to yellow towards the equator; spines pale yellow,
    with a dark outline around each spine base; furrows (colpi) teal."""
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
