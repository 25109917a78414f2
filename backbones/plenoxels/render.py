"""Volume rendering of a sparse SH voxel grid (pure functions; Fridovich-Keil et al. 2022).

Rays ``o + t d`` use the camera convention of :mod:`arcsem.cameras`: ``d`` has unit camera-space z,
so ``t`` is the z-depth. Samples are the midpoints of segments of ``step_size`` voxels (in world
length) that partition ``[t_near, t_far]`` of the scene box exactly (the last one is shortened), so a
density that is linear between segment ends is integrated exactly.

Density is ReLU(trilinear) in units of 1 / normalised length, where the normalised length makes the
box's longest half-side 1 (``scale`` = half the longest side): the optical depth of a segment of
world length ``l`` is ``sigma * l / scale`` (svox2 likewise measures density in its normalised
world). Colour is ``max(SH . basis(d) + 0.5, 0)``, optionally transformed per sample by ACT before
compositing. Front-to-back compositing: ``w_i = T_i (1 - exp(-tau_i))``; samples whose transmittance
``T_i`` is below ``stop_thresh`` are masked out (early stop).

Distortion (the ``distortion`` loss; 2DGS's term, Mip-NeRF 360's with squared distances): ``sum_{i<j} w_i w_j
(m_i - m_j)^2`` over a ray's samples, ``m = t / scale`` in the normalised length. It equals ``(A M2 - M1^2) /
scale^2`` with ``A = sum w``, ``M1 = sum w u``, ``M2 = sum w u^2`` for any shift of ``u = t - t0``: here
``t0 = t_near``, so the moments stay small (no cancellation of large ``t^2`` terms in float32).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from ..sh import sh_basis
from .grid import cell_occupancy, corners, occupied_coords, trilinear, voxel_size

__all__ = ["GridData", "box_scale", "composite", "distortion", "ray_aabb", "render_grid", "sample_segments"]


@dataclass
class GridData:
    """What the renderer needs of a grid.

    Attributes:
        index: ``[X, Y, Z]`` int32 row of each grid point or -1.
        density: ``[M]`` raw density (ReLU applied when rendering).
        sh: ``[M, K, 3]`` SH coefficients, ``K = (degree + 1)^2``.
        bounds: ``[2, 3]`` scene box (grid points span it, vertices included).
        cell_occ: ``[X, Y, Z]`` bool from :func:`cell_occupancy` (computed if None).
        coords: ``[M, 3]`` long grid coordinates of the rows (:func:`occupied_coords`; computed when the
            fused kernel needs them).
    """

    index: Tensor
    density: Tensor
    sh: Tensor
    bounds: Tensor
    cell_occ: Tensor | None = None
    coords: Tensor | None = None

    def __post_init__(self) -> None:
        if self.cell_occ is None:
            self.cell_occ = cell_occupancy(self.index)

    @property
    def reso(self) -> list[int]:
        return list(self.index.shape)


def box_scale(bounds: Tensor) -> float:
    """Normalisation length: half of the longest side of ``bounds [2, 3]``."""
    return float((bounds[1] - bounds[0]).max() / 2)


def ray_aabb(rays_o: Tensor, rays_d: Tensor, bounds: Tensor) -> tuple[Tensor, Tensor]:
    """Entry and exit ``t`` of rays ``[R, 3]`` in the box ``[2, 3]``; ``t_near >= 0``; a miss has ``t_far <= t_near``."""
    inv = 1.0 / torch.where(rays_d.abs() < 1e-12, torch.full_like(rays_d, 1e-12), rays_d)
    t0, t1 = (bounds[0] - rays_o) * inv, (bounds[1] - rays_o) * inv
    t_near = torch.minimum(t0, t1).amax(-1).clamp_min(0)
    t_far = torch.maximum(t0, t1).amin(-1)
    return t_near, t_far


def sample_segments(t_near: Tensor, t_far: Tensor, dt: Tensor) -> tuple[Tensor, Tensor]:
    """Segments of length ``dt [R]`` partitioning ``[t_near, t_far]`` ``[R]``.

    Returns:
        t_mid ``[R, S]`` segment midpoints and delta ``[R, S]`` segment lengths (0 = padding),
        ``S`` the largest number of segments of any ray.
    """
    n = torch.ceil(((t_far - t_near) / dt).clamp_min(0) - 1e-6).long()  # tolerance: exact multiples
    S = int(n.max()) if n.numel() else 0
    k = torch.arange(S, device=t_near.device, dtype=t_near.dtype)
    t0 = t_near[:, None] + k[None] * dt[:, None]
    delta = torch.minimum((t_far[:, None] - t0).clamp_min(0), dt[:, None].expand(-1, S))
    delta = torch.where(k[None] < n[:, None], delta, torch.zeros_like(delta))
    return t0 + 0.5 * delta, delta


def _occupied_samples(grid: GridData, rays_o, rays_d, t_mid, delta) -> tuple[Tensor, Tensor]:
    """Flat sample ids ``[P]`` (into ``[R*S]``) that fall into cells with an occupied corner, and their grid coords."""
    S = t_mid.shape[1]
    vs = voxel_size(grid.bounds, grid.reso)
    go, gd = (rays_o - grid.bounds[0]) / vs, rays_d / vs
    cand = torch.nonzero(delta.reshape(-1) > 0).squeeze(1)
    ray = cand // S
    g = go[ray] + t_mid.reshape(-1)[cand, None] * gd[ray]
    hi = torch.tensor(grid.reso, device=g.device, dtype=g.dtype) - 1
    g = torch.minimum(g.clamp_min(0), hi)
    _, Y, Z = grid.reso
    b = g.floor().long()
    lin = (b[:, 0] * Y + b[:, 1]) * Z + b[:, 2]
    keep = grid.cell_occ.reshape(-1)[lin]
    return cand[keep], g[keep]


def render_grid(
    grid: GridData,
    rays_o: Tensor,
    rays_d: Tensor,
    *,
    sh_degree: int = 2,
    step_size: float = 0.5,
    stop_thresh: float = 1e-4,
    background: Tensor | None = None,
    act=None,
    image_ids: Tensor | None = None,
    return_samples: bool = False,
    impl: str = "torch",
    sparse_grad: bool = True,
) -> dict[str, Tensor]:
    """Render rays through a sparse SH voxel grid.

    Args:
        grid: the grid (see :class:`GridData`).
        rays_o, rays_d: ``[R, 3]`` origins and directions (unit camera z: ``t`` is z-depth).
        sh_degree: SH degree used (``(sh_degree+1)^2 <= K``).
        step_size: sample spacing in voxels (of the smallest voxel side).
        stop_thresh: samples with transmittance below this are masked (early stop).
        background: ``[3]`` colour composited behind (default black).
        act: optional object with ``apply(colors [A, 3], image_ids [A]) -> [A, 3]`` applied per sample.
        image_ids: ``[R]`` long training-image index per ray (for ACT; -1 = novel view).
        return_samples: also return ``samples`` = (rows ``[A, 8]``, trilinear weights ``[A, 8]``,
            rendering weights ``[A]``) of the composited samples (for pruning; PyTorch path).
        impl: ``"torch"`` (reference) or ``"cpp"`` (fused kernel of :mod:`.fused`, CPU).
        sparse_grad: with ``impl="cpp"``, density and SH get sparse COO gradients (the rows the rays
            touched); False: dense, as the PyTorch path's.
    Returns:
        ``rgb [R, 3]``, ``alpha [R, 1]`` (= sum of weights), ``depth [R, 1]`` (expected z-depth
        ``sum(w t) / alpha``, 0 where alpha = 0), ``distortion [R, 1]`` (module docstring).
    """
    R, dev, dt_ = rays_o.shape[0], rays_o.device, grid.density.dtype
    bg = torch.zeros(3, dtype=dt_, device=dev) if background is None else torch.as_tensor(background, dtype=dt_, device=dev)
    step = step_size * float(voxel_size(grid.bounds, grid.reso).min())
    if impl == "cpp" and not return_samples:
        return _render_fused(grid, rays_o, rays_d, step, sh_degree, stop_thresh, bg, act, image_ids, sparse_grad)
    t_near, t_far = ray_aabb(rays_o, rays_d, grid.bounds)
    dnorm = rays_d.norm(dim=-1)
    t_mid, delta = sample_segments(t_near, t_far, step / dnorm)
    S = t_mid.shape[1]
    sel, g = _occupied_samples(grid, rays_o, rays_d, t_mid, delta)
    ray = sel // S
    rows, wtri = corners(grid.index, g)
    sigma = torch.relu(trilinear(grid.density[:, None], rows, wtri)[:, 0])
    tau = sigma * (delta.reshape(-1)[sel] * dnorm[ray] / box_scale(grid.bounds))
    cum = torch.zeros(R * S, dtype=tau.dtype, device=dev).scatter(0, sel, tau).reshape(R, S).cumsum(1)
    T = torch.exp(-(cum.reshape(-1)[sel] - tau))
    active = ((T >= stop_thresh) & (sigma > 0)).nonzero().squeeze(1)
    ray_a, w = ray[active], (T * (1 - torch.exp(-tau)))[active]
    K = (sh_degree + 1) ** 2
    M = grid.sh.shape[0]
    coef = trilinear(grid.sh[:, :K].reshape(M, K * 3), rows[active], wtri[active]).reshape(-1, K, 3)
    basis = sh_basis(sh_degree, rays_d).to(coef.dtype)  # [R, K]
    col = torch.relu((basis[ray_a, :, None] * coef).sum(1) + 0.5)
    if act is not None:
        ids = image_ids if image_ids is not None else torch.full((R,), -1, dtype=torch.long, device=dev)
        col = act.apply(col, ids[ray_a])
    zeros = torch.zeros(R, dtype=w.dtype, device=dev)
    alpha = zeros.index_add(0, ray_a, w)
    rgb = torch.zeros(R, 3, dtype=w.dtype, device=dev).index_add(0, ray_a, w[:, None] * col)
    rgb = rgb + (1 - alpha)[:, None] * bg
    t_a = t_mid.reshape(-1)[sel[active]]
    wt = zeros.index_add(0, ray_a, w * t_a)
    u = t_a - t_near[ray_a]
    mom = torch.stack([zeros.index_add(0, ray_a, w * u), zeros.index_add(0, ray_a, w * u * u)], -1)
    depth = torch.where(alpha > 0, wt / alpha.clamp_min(1e-10), zeros)
    out = {"rgb": rgb, "alpha": alpha[:, None], "depth": depth[:, None],
           "distortion": distortion(alpha, mom, box_scale(grid.bounds))}
    if return_samples:
        out["samples"] = (rows[active], wtri[active], w.detach())
    return out


def _render_fused(grid: GridData, rays_o, rays_d, step, sh_degree, stop_thresh, bg, act, image_ids, sparse_grad) -> dict:
    """:func:`render_grid` through the fused C++ kernel (same outputs, CPU)."""
    from .fused import live_masks, march

    R = rays_o.shape[0]
    act_w = act_b = None
    if act is not None:
        ids = image_ids if image_ids is not None else torch.full((R,), -1, dtype=torch.long)
        act_w, act_b = (t.to(grid.density.dtype).expand(R, 3) for t in act.transforms(ids))
    if grid.coords is None:
        grid.coords = occupied_coords(grid.index)
    live = live_masks(grid.index, grid.coords, grid.density)
    rgb, alpha, wt, mom = march(grid.density, grid.sh, grid.index, live, grid.bounds, rays_o, rays_d,
                           step=step, scale=box_scale(grid.bounds), stop=stop_thresh, degree=sh_degree,
                           act_w=act_w, act_b=act_b, sparse_grad=sparse_grad)
    depth = torch.where(alpha > 0, wt / alpha.clamp_min(1e-10), torch.zeros_like(wt))
    return {"rgb": rgb + (1 - alpha)[:, None] * bg, "alpha": alpha[:, None], "depth": depth[:, None],
            "distortion": distortion(alpha, mom, box_scale(grid.bounds))}


def distortion(alpha: Tensor, mom: Tensor, scale: float) -> Tensor:
    """``[R, 1]`` distortion ``(A M2 - M1^2) / scale^2`` of rays with weight sums ``alpha [R]`` and moments ``mom [R, 2]``
    (``sum w u``, ``sum w u^2``, ``u`` in world length; module docstring)."""
    return ((alpha * mom[:, 1] - mom[:, 0] ** 2) / scale**2)[:, None]


def composite(rgb: Tensor, alpha: Tensor, front: Tensor | None, back: Tensor, act=None,
              image_ids: Tensor | None = None) -> Tensor:
    """``front + (1 - front_alpha) (rgb + (1 - alpha) back)``: the grid's ``rgb [R, 3]``, ``alpha [R, 1]``
    between a background's premultiplied ``front [R, 4]`` (or None) and ``back [R, 3]``.

    With ``act``, the background's colours are transformed like the grid's samples: ``back`` as a colour,
    ``front`` (premultiplied) as ``W c + b a`` clamped to ``[0, a]``.
    """
    if act is not None:
        ids = image_ids if image_ids is not None else torch.full((rgb.shape[0],), -1, dtype=torch.long)
        back = act.apply(back, ids)
        if front is not None:
            W, b = act.transforms(ids)
            a = front[:, 3:]
            front = torch.cat([torch.minimum((W * front[:, :3] + b * a).clamp_min(0), a), a], -1)
    out = rgb + (1 - alpha) * back.to(rgb)
    if front is not None:
        out = front[:, :3].to(rgb) + (1 - front[:, 3:].to(rgb)) * out
    return out
