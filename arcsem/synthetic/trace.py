"""Sphere tracing of a signed distance function along rays, with Newton refinement.

Rays are ``origin + s * u`` with unit directions ``u``; the caller converts ``s`` to camera z-depth
(``Cameras.rays`` directions have unit camera ``z``, so ``z = s / |d|``).
"""
from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

__all__ = ["ray_sphere", "sdf_gradient", "sphere_trace"]

SDF = Callable[[Tensor], Tensor]


def ray_sphere(o: Tensor, u: Tensor, radius: float) -> tuple[Tensor, Tensor, Tensor]:
    """Entry/exit distances ``[N]`` of unit rays ``o, u [N, 3]`` through the sphere ``|x| = radius``
    centred at the origin, and a ``[N]`` bool that is True where the ray meets it in front."""
    b = (o * u).sum(-1)
    c = (o * o).sum(-1) - radius**2
    disc = b * b - c
    hit = disc > 0
    root = disc.clamp_min(0).sqrt()
    t0, t1 = (-b - root).clamp_min(0), -b + root
    return t0, t1, hit & (t1 > 0)


def sphere_trace(
    sdf: SDF, o: Tensor, u: Tensor, t_far: Tensor, *, max_steps: int = 128, relax: float = 0.7,
    eps: float = 2e-4, refine: int = 4, tol: float = 2e-4,
) -> tuple[Tensor, Tensor]:
    """First zero of ``sdf`` along unit rays ``o + t u`` for ``t`` in ``[0, t_far]``.

    Steps ``relax * sdf`` (``relax < 1`` keeps steps safe for a field whose slope exceeds 1, as
    with furrows and relief), at most ``max_steps`` times; rays with ``|sdf| < eps`` are hits.
    Rays still marching at the end (grazing a silhouette) get ``refine`` Newton steps on ``t``
    with a central-difference slope and count as hits only if then ``|sdf| < tol``.

    Args:
        sdf: ``[M, 3] -> [M]``. o, u: ``[N, 3]``. t_far: ``[N]``.
    Returns:
        t ``[N]`` (undefined where no hit) and hit ``[N]`` bool.
    """
    n = o.shape[0]
    t = torch.zeros(n, dtype=o.dtype, device=o.device)
    state = torch.zeros(n, dtype=torch.int8, device=o.device)  # 0 marching, 1 close, 2 missed
    active = torch.arange(n, device=o.device)
    for _ in range(max_steps):
        if active.numel() == 0:
            break
        ta = t[active]
        d = sdf(o[active] + ta[:, None] * u[active])
        close = d.abs() < eps
        ta = torch.where(close, ta, ta + relax * d)
        t[active] = ta
        gone = ta > t_far[active]
        state[active[close]] = 1
        state[active[gone & ~close]] = 2
        active = active[~close & ~gone]
    hit = state == 1
    if active.numel():  # still marching: try Newton on the remaining ones (grazing rays)
        tc, ok = _newton(sdf, o[active], u[active], t[active], refine, tol)
        t[active] = tc
        hit[active] = ok & (tc <= t_far[active]) & (tc >= 0)
    return t, hit


def _newton(sdf: SDF, o: Tensor, u: Tensor, t: Tensor, steps: int, tol: float) -> tuple[Tensor, Tensor]:
    """Newton iterations on ``f(t) = sdf(o + t u)``; returns refined ``t [N]`` and ``|f| < tol``."""
    h = 1e-3
    for _ in range(steps):
        p = o + t[:, None] * u
        f = sdf(torch.cat([p, p + h * u, p - h * u]))
        f0, fp, fm = f.chunk(3)
        slope = (fp - fm) / (2 * h)
        step = torch.where(slope < -1e-2, -f0 / slope.clamp(max=-1e-2), f0)
        t = t + step.clamp(-0.02, 0.02)
    f = sdf(o + t[:, None] * u)
    return t, f.abs() < tol


_TETRA = ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1))


def sdf_gradient(sdf: SDF, p: Tensor, h: float = 2e-3) -> tuple[Tensor, Tensor]:
    """Unit normals ``[N, 3]`` and Laplacian ``[N]`` of ``sdf`` at ``p [N, 3]`` (5 evaluations).

    Tetrahedral stencil ``v_i`` (``|v_i| = 1``, ``sum v_i = 0``, ``sum v_i v_i^T = 4/3 I``):
    ``grad = 3 / (4 h) sum v_i f(p + h v_i)``, ``laplacian = 3 / (2 h^2) (sum f(p + h v_i) - 4 f(p))``.
    The Laplacian of a distance field is the sum of principal curvatures (``2 / r`` on a sphere):
    large at spine tips and ridges, used for edge brightening.
    """
    v = torch.tensor(_TETRA, dtype=p.dtype, device=p.device) / 3**0.5
    pts = torch.cat([p] + [p + h * v[i] for i in range(4)])
    f = sdf(pts).reshape(5, -1)
    grad = (f[1:, :, None] * v[:, None, :]).sum(0) * (3 / (4 * h))
    lap = (f[1:].sum(0) - 4 * f[0]) * (3 / (2 * h**2))
    return torch.nn.functional.normalize(grad, dim=-1), lap
