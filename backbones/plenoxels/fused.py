"""Fused C++ CPU ray marching (forward + backward), built as a PyTorch JIT extension.

``cpp/render.cpp`` marches one ray per loop iteration (OpenMP over rays) with early termination, no
per-sample buffers, and visits only samples in live cells: :func:`live_masks` marks the cells with a
stored corner of positive density (the only ones where ``ReLU(trilinear)`` is not 0) and, over blocks of
``2^SKIP_SHIFT`` cells per axis, the distance to the nearest live block, and a ray jumps over dead
blocks (``cpp/march.h``). The backward marches
again and scatters gradients into density, SH and the per-ray ACT transform. :func:`arcsem.backbones.plenoxels.render.render_grid` with ``impl="torch"``
is the reference: tests/test_plenoxels.py compares values and gradients of both paths.
The kernels take named argument structs (``cpp/api.h``: ``Rays``, ``VoxelGrid``, ``Field``, ``Marched``), as the
Gaussian kernels do. ``load_extension()`` compiles once through :mod:`arcsem.cext` (the project's one extension loader) and
returns None with one warning when no toolchain is available, so ``rasterizer: auto`` falls back to PyTorch.
"""
from __future__ import annotations

import os
from pathlib import Path

import torch
from torch import Tensor

from arcsem import cext

__all__ = ["EXTENSION", "SKIP_SHIFT", "live_masks", "load_extension", "march", "max_weights", "resolve_impl",
           "struct", "structs"]

EXTENSION = cext.Extension(prefix="arcsem_plenoxels_fused",
                           sources=tuple(Path(__file__).parent / "cpp" / f for f in ("render.cpp", "module.cpp")),
                           what="fused C++ Plenoxels ray marcher")
# Empty-space skipping: blocks of 2^SKIP_SHIFT cells per axis (4: benchmarks/bench_plenoxels.py --shift).
SKIP_SHIFT = int(os.environ.get("ARCSEM_PLX_SKIP_SHIFT", "2"))
_SLOTS: dict[tuple, Tensor] = {}


def load_extension(verbose: bool = False):
    """The compiled module, or None (with one warning) when it cannot be built (:func:`arcsem.cext.load`)."""
    return cext.load(EXTENSION, verbose)


def resolve_impl(impl: str, device: torch.device | str = "cpu") -> str:
    """``rasterizer`` value ``auto|torch|cpp`` -> the path taken (:func:`arcsem.cext.resolve_impl`)."""
    return cext.resolve_impl(impl, EXTENSION, str(device))


def slots(m: int) -> Tensor:
    """``[B, m]`` int32, -1 at rest: each of the backward's ``B`` threads finds the compact slot of a row of a grid
    of ``m`` rows there (``cpp/cell.h``). Kept between calls (two grids at most: the training grid and a test's)."""
    key = (m, max(1, torch.get_num_threads()))
    if key not in _SLOTS:
        while len(_SLOTS) >= 2:
            _SLOTS.pop(next(iter(_SLOTS)))
        _SLOTS[key] = torch.full(key[::-1], -1, dtype=torch.int32)
    return _SLOTS[key]


def struct(kind: str, **fields):
    """The marcher's argument struct ``kind`` (``cpp/api.h``) with its fields set by name."""
    s = getattr(load_extension(), kind)()
    for k, v in fields.items():
        setattr(s, k, v)
    return s


def structs(rays_o: Tensor, rays_d: Tensor, index: Tensor, live: tuple[Tensor, Tensor], bounds: Tensor,
            density: Tensor, sh: Tensor, act_w: Tensor, act_b: Tensor, *, shift: int, step: float, scale: float,
            stop: float, degree: int, act: bool) -> tuple:
    """``(Rays, VoxelGrid, Field)`` of a march (shapes: :func:`march`; ``act_w``/``act_b`` empty without ACT)."""
    rays = struct("Rays", origins=rays_o, directions=rays_d, step=float(step), scale=float(scale), stop=float(stop))
    grid = struct("VoxelGrid", index=index, cell_live=live[0], block_dist=live[1], bounds=bounds, shift=int(shift))
    field = struct("Field", density=density, sh=sh, degree=int(degree), act=bool(act), act_w=act_w, act_b=act_b)
    return rays, grid, field


def _sparse(rows: Tensor, values: Tensor, like: Tensor) -> Tensor:
    """Sparse COO gradient of ``like`` with rows ``rows [n]`` (sorted, unique) and ``values [n, ...]``."""
    return torch.sparse_coo_tensor(rows[None], values, like.shape, is_coalesced=True, check_invariants=False)


def live_masks(index: Tensor, coords: Tensor, density: Tensor, shift: int = SKIP_SHIFT) -> tuple[Tensor, Tensor]:
    """``cell_live [X, Y, Z]`` and ``block_dist [BX, BY, BZ]`` uint8 of ``density [M]`` (rows at ``coords [M, 3]``).

    A cell is live when one of its 8 corners is stored with a positive density; a block of ``2^shift``
    cells per axis (``BX = (X - 2) // 2^shift + 1``) has distance 0 when one of its cells is live, else the
    Chebyshev distance in blocks to the nearest live block (at most 16; ``cpp/live.h``).
    """
    cell, dist = load_extension().live(index.contiguous(), coords, density.detach().contiguous(), int(shift))
    return cell, dist


class _March(torch.autograd.Function):
    @staticmethod
    def forward(ctx, density, sh, act_w, act_b, rays_o, rays_d, index, cell_live, block_dist, bounds, consts):
        shift, step, scale, stop, degree, has_act, _ = consts
        args = structs(rays_o, rays_d, index, (cell_live, block_dist), bounds, density, sh, act_w, act_b, shift=shift,
                       step=step, scale=scale, stop=stop, degree=degree, act=has_act)
        out = load_extension().forward(*args)
        ctx.save_for_backward(density, sh, act_w, act_b, rays_o, rays_d, index, cell_live, block_dist, bounds, out.rgb,
                              out.alpha, out.wt, out.mom)
        ctx.consts = consts
        return out.rgb, out.alpha, out.wt, out.mom

    @staticmethod
    def backward(ctx, g_rgb, g_alpha, g_wt, g_mom):
        density, sh, act_w, act_b, rays_o, rays_d, index, cell_live, block_dist, bounds, rgb, alpha, wt, mom = \
            ctx.saved_tensors
        shift, step, scale, stop, degree, has_act, sparse = ctx.consts
        args = structs(rays_o, rays_d, index, (cell_live, block_dist), bounds, density, sh, act_w, act_b, shift=shift,
                       step=step, scale=scale, stop=stop, degree=degree, act=has_act)
        fwd = struct("Marched", rgb=rgb, alpha=alpha, wt=wt, mom=mom)
        grads = struct("Marched", rgb=g_rgb.contiguous(), alpha=g_alpha.contiguous(), wt=g_wt.contiguous(),
                      mom=g_mom.contiguous())
        g = load_extension().backward(*args, fwd, grads, slots(density.shape[0]))
        gd, gsh = _sparse(g.rows, g.density, density), _sparse(g.rows, g.sh, sh)
        if not sparse:
            gd, gsh = gd.to_dense(), gsh.to_dense()
        return gd, gsh, (g.act_w if has_act else None), (g.act_b if has_act else None), *([None] * 7)


def march(density: Tensor, sh: Tensor, index: Tensor, live: tuple[Tensor, Tensor], bounds: Tensor, rays_o: Tensor,
          rays_d: Tensor, *, step: float, scale: float, stop: float, degree: int, act_w: Tensor | None = None,
          act_b: Tensor | None = None, shift: int = SKIP_SHIFT, sparse_grad: bool = True
          ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Fused march -> ``rgb [R, 3]`` (no background), ``alpha [R]``, ``wt [R]`` (= sum w t), ``mom [R, 2]`` (=
    sum w u, sum w u^2 with ``u = t - t_near``: the moments of :func:`~.render.distortion`).

    The gradients of density and SH are sparse COO tensors over the rows the rays touched (svox2 updates
    only those: :class:`~arcsem.backbones.plenoxels.optim.SparseRMSprop`); dense with ``sparse_grad=False``.

    ``density [M]``, ``sh [M, K, 3]``, ``index [X, Y, Z]`` int32, ``live`` = :func:`live_masks` of this
    density (with the same ``shift``), rays ``[R, 3]``; ``act_w``/``act_b`` ``[R, 3]``: per-ray affine colour
    transform applied (and clamped) per sample.
    """
    has_act = act_w is not None
    dt = density.dtype
    empty = torch.zeros(0, dtype=dt)
    return _March.apply(
        density.contiguous(), sh.contiguous(), act_w.contiguous() if has_act else empty,
        act_b.contiguous() if has_act else empty, rays_o.to(dt).contiguous(), rays_d.to(dt).contiguous(),
        index.contiguous(), live[0], live[1], bounds, (int(shift), step, scale, stop, degree, has_act, sparse_grad),
    )


def max_weights(density: Tensor, index: Tensor, coords: Tensor, bounds: Tensor, rays_o: Tensor, rays_d: Tensor, *,
                step: float, scale: float, stop: float) -> Tensor:
    """``[M]`` largest rendering weight of each stored point over the rays ``[R, 3]`` (for pruning; the
    fused counterpart of :func:`~.upsample.max_weights` over ``render_grid(..., return_samples=True)``)."""
    dens = density.detach().contiguous()
    live = live_masks(index, coords, dens)
    empty = dens.new_zeros(0)
    args = structs(rays_o.to(dens.dtype).contiguous(), rays_d.to(dens.dtype).contiguous(), index.contiguous(), live,
                   bounds, dens, empty, empty, empty, shift=SKIP_SHIFT, step=step, scale=scale, stop=stop, degree=0,
                   act=False)
    return load_extension().max_weights(*args)


if __name__ == "__main__":  # `python -m arcsem.backbones.plenoxels.fused`: build now (make setup does this)
    import time

    t0 = time.perf_counter()
    ok = load_extension() is not None
    print(f"fused C++ Plenoxels ray marcher: {'ready' if ok else 'unavailable, PyTorch path will be used'} "
          f"({time.perf_counter() - t0:.1f} s)")
