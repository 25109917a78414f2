"""Fused C++ CPU ray marching (forward + backward), built as a PyTorch JIT extension.

``cpp/render.cpp`` marches one ray per loop iteration (OpenMP over rays) with early termination and
no per-sample buffers; the backward marches again and scatters gradients into density, SH and the
per-ray ACT transform. :func:`arcsem.backbones.plenoxels.render.render_grid` with ``impl="torch"``
is the reference: tests/test_plenoxels.py compares values and gradients of both paths.
``load_extension()`` compiles once through :mod:`arcsem.cext` (the project's one extension loader) and
returns None with one warning when no toolchain is available, so ``rasterizer: auto`` falls back to PyTorch.
"""
from __future__ import annotations

import os
from pathlib import Path

import torch
from torch import Tensor

from arcsem import cext

__all__ = ["EXTENSION", "load_extension", "march", "resolve_impl"]

EXTENSION = cext.Extension(prefix="arcsem_plenoxels_fused", sources=(Path(__file__).parent / "cpp" / "render.cpp",),
                           what="fused C++ Plenoxels ray marcher")
# The backward gives each extra thread a private gradient buffer (no atomic adds) while they total at most
# this many bytes; larger grids or more threads fall back to atomic adds into one buffer.
PRIVATE_GRAD_BYTES = float(os.environ.get("ARCSEM_PLX_PRIVATE_GRAD_BYTES", str(1 << 30)))


def load_extension(verbose: bool = False):
    """The compiled module, or None (with one warning) when it cannot be built (:func:`arcsem.cext.load`)."""
    return cext.load(EXTENSION, verbose)


def resolve_impl(impl: str, device: torch.device | str = "cpu") -> str:
    """``rasterizer`` value ``auto|torch|cpp`` -> the path taken (:func:`arcsem.cext.resolve_impl`)."""
    return cext.resolve_impl(impl, EXTENSION, str(device))


class _March(torch.autograd.Function):
    @staticmethod
    def forward(ctx, density, sh, act_w, act_b, rays_o, rays_d, index, cell_occ, bounds, consts):
        step, scale, stop, degree, has_act = consts
        args = (rays_o, rays_d, index, cell_occ, density, sh, act_w, act_b, bounds, step, scale, stop, degree, has_act)
        rgb, alpha, wt = load_extension().forward(*args)
        ctx.save_for_backward(density, sh, act_w, act_b, rays_o, rays_d, index, cell_occ, bounds, rgb, alpha, wt)
        ctx.consts = consts
        return rgb, alpha, wt

    @staticmethod
    def backward(ctx, g_rgb, g_alpha, g_wt):
        density, sh, act_w, act_b, rays_o, rays_d, index, cell_occ, bounds, rgb, alpha, wt = ctx.saved_tensors
        step, scale, stop, degree, has_act = ctx.consts
        gd, gsh, gw, gb = load_extension().backward(
            rays_o, rays_d, index, cell_occ, density, sh, act_w, act_b, bounds, step, scale, stop, degree, has_act,
            rgb, alpha, wt, g_rgb.contiguous(), g_alpha.contiguous(), g_wt.contiguous(), PRIVATE_GRAD_BYTES,
        )
        return gd, gsh, (gw if has_act else None), (gb if has_act else None), None, None, None, None, None, None


def march(density: Tensor, sh: Tensor, index: Tensor, cell_occ: Tensor, bounds: Tensor, rays_o: Tensor, rays_d: Tensor,
          *, step: float, scale: float, stop: float, degree: int, act_w: Tensor | None = None,
          act_b: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
    """Fused march -> ``rgb [R, 3]`` (no background), ``alpha [R]``, ``wt [R]`` (= sum w t).

    ``density [M]``, ``sh [M, K, 3]``, ``index [X, Y, Z]`` int32, ``cell_occ [X, Y, Z]`` bool, rays ``[R, 3]``;
    ``act_w``/``act_b`` ``[R, 3]``: per-ray affine colour transform applied (and clamped) per sample.
    """
    has_act = act_w is not None
    dt = density.dtype
    empty = torch.zeros(0, dtype=dt)
    return _March.apply(
        density.contiguous(), sh.contiguous(), act_w.contiguous() if has_act else empty,
        act_b.contiguous() if has_act else empty, rays_o.to(dt).contiguous(), rays_d.to(dt).contiguous(),
        index.contiguous(), cell_occ.contiguous().view(torch.uint8), bounds, (step, scale, stop, degree, has_act),
    )
