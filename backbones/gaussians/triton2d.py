"""``rasterizer=triton``: 2DGS rendering on Triton kernels, for CUDA: the compositing here, forward and backward.

On a GPU the PyTorch rasteriser issues ~1,400 operators a step; the host cannot issue them as fast as the GPU runs
them (benchmarks/results/gpu/README.md). ``gs2d.render.render_2dgs(impl="triton")`` runs its steps as five kernels
instead: the projection to a splat table, forward and backward (:mod:`._triton2d_project`), the footprints
(:mod:`._triton2d_footprint`, with the tile binning's expansion to pairs: :mod:`._triton2d_bin`; the depth ranks,
sort and offsets stay PyTorch's) and the compositing below (kernels: :mod:`._triton2d_kernels`).

The compositing's arithmetic and rules are those of the fused C++ kernels (cpp/composite2d.h: official 2DGS
ray-splat intersection, low-pass filter, skip / clamp / early stop, median depth, shifted distortion sums) in the
PyTorch path's frame (absolute pixel centres, the adjugate of ``[Tu; Tv; Tw]``), so the PyTorch path is the reference
(tests/test_triton2d.py, values and gradients).

* Forward: one program per camera-tile, its ``tile x tile`` pixels as one block of lanes, the tile's pairs front to
  back until every pixel has stopped.
* Backward: the same program back to front from the last pair any of its pixels composited, the transmittance
  restored (``T_i = T_{i+1} / (1 - alpha_i)``); each pair's gradient row (21 values: the splat table's columns) is
  summed over the tile's pixels and added atomically into the entry's row.

Triton compiles the kernels for the GPU at first use; under ``TRITON_INTERPRET=1`` they run on CPU tensors
(:mod:`arcsem.tritonsupport`); benchmarks/gpu/triton_compile.py compiles them for a given GPU architecture without
one.
"""
from __future__ import annotations

import torch
from torch import Tensor

from arcsem.tritonsupport import available, constants, tl_dtype

from .config import LOWPASS_SIGMA
from .raster import MAX_ALPHA, MIN_ALPHA, MIN_T

__all__ = ["TABLE", "composite2d_triton"]

TABLE = 21
"""Columns of the splat table (``render._splat_table`` transposed): adjugate a, b, c (9), centre (2), opacity,
depth row ``Tz`` (3), colour (3), normal (3)."""


_KERNELS = None


def _kernels():
    """The two kernels, defined on first use (importing triton costs a second)."""
    global _KERNELS
    if _KERNELS is None:
        from . import _triton2d_kernels as k

        _KERNELS = (k.forward_kernel, k.backward_kernel)
    return _KERNELS


# How the compositing backward sums a pair's 21 gradient columns over a tile's pixels. Its kernel on one view of
# the demo's model at step 250 (79k splats, 288x192, every output weighted; an H200, benchmarks/gpu/triton_backward.py):
# "row", the 21 columns stacked and summed in one block-wide reduction: 11.7 ms; "tile", 21 block-wide reductions:
# 18.4 ms; "warp", a partial sum a warp (shuffles) added atomically by each warp: 20.1 ms (8x the atomic adds);
# "tile_acq", "tile" with acquire-release atomics (the first version): 51.5 ms. Equal up to float rounding.
BACKWARD_SUM = "row"
_SUMS = {"tile_acq": 0, "tile": 1, "warp": 2, "row": 3}


def _reduction(tile: int) -> tuple[int, int]:
    """The backward's ``REDUCE`` and ``NW`` (lane rows of 32) for ``tile``: below 32 lanes, "tile"."""
    block = _block(tile)
    return (_SUMS[BACKWARD_SUM] if block >= 32 else 1), max(1, block // 32)


def _block(tile: int) -> int:
    """Lanes a program: the tile's pixels, rounded up to a power of two (Triton's blocks)."""
    return 1 << max(0, (tile * tile - 1).bit_length())


def _warps(tile: int) -> int:
    """Warps a program: one thread a pixel up to 8 warps (sm_90, 16-px tiles: 48 / 79 registers a thread forward /
    backward, no spills; ``benchmarks/gpu/triton_compile.py``)."""
    return max(1, min(8, _block(tile) // 32))


class _Composite2DTriton(torch.autograd.Function):
    @staticmethod
    def forward(ctx, table, box, offsets, ids, prm, bg, geo, C, H, W, tile, near):
        M = table.shape[0]
        dev, dt = table.device, table.dtype
        TX, TY = -(-W // tile), -(-H // tile)
        img = lambda k: torch.empty(C * H * W, k, dtype=dt, device=dev)
        rgb, nrm = img(3), img(3)
        tf, alpha, wz, depth, med, dist, m1, m2, mref = (torch.empty(C * H * W, dtype=dt, device=dev) for _ in range(9))
        last, medi = (torch.empty(C * H * W, dtype=torch.int32, device=dev) for _ in range(2))
        fwd, _ = _kernels()
        has_bg = bg.numel() == 3
        fwd[(C * TX * TY,)](table, box, offsets, ids, prm, bg if has_bg else table, rgb, nrm, tf, alpha, wz, depth,
                            med, dist, m1, m2, mref, last, medi, H, W, TX, TY, float(near),
                            HAS_BG=has_bg, TILE=tile, BLOCK=_block(tile), DT=tl_dtype(table), NCOL=TABLE,
                            MIN_ALPHA_=MIN_ALPHA, MAX_ALPHA_=MAX_ALPHA, MIN_T_=MIN_T, num_warps=_warps(tile))
        ctx.save_for_backward(table, box, offsets, ids, prm, bg, tf, alpha, wz, m1, m2, mref, last, medi)
        ctx.sizes = (M, C, H, W, tile, float(near), bool(geo))
        ctx.set_materialize_grads(False)
        shape = (C, H, W)
        return (rgb.view(*shape, 3), nrm.view(*shape, 3), alpha.view(*shape, 1), depth.view(*shape, 1),
                med.view(*shape, 1), dist.view(*shape, 1))

    @staticmethod
    def backward(ctx, g_rgb, g_nrm, g_alpha, g_depth, g_med, g_dist):
        table, box, offsets, ids, prm, bg, tf, alpha, wz, m1, m2, mref, last, medi = ctx.saved_tensors
        M, C, H, W, tile, near, geo = ctx.sizes
        TX, TY = -(-W // tile), -(-H // tile)
        grad = torch.zeros(M, TABLE, dtype=table.dtype, device=table.device)
        gs = [g_rgb, g_nrm, g_alpha, g_depth, g_med, g_dist]
        has = [g is not None for g in gs]
        gs = [g.contiguous() if g is not None else table for g in gs]
        _, bwd = _kernels()
        has_bg = bg.numel() == 3
        reduce, nw = _reduction(tile)
        bwd[(C * TX * TY,)](table, box, offsets, ids, prm, bg if has_bg else table, tf, alpha, wz, m1, m2, mref,
                            last, medi, *gs, grad, H, W, TX, TY, near,
                            HAS_BG=has_bg, G_RGB=has[0], G_NRM=has[1], G_ALPHA=has[2], G_DEPTH=has[3], G_MED=has[4],
                            G_DIST=has[5], GEO=geo, TILE=tile, BLOCK=_block(tile), DT=tl_dtype(table), NCOL=TABLE,
                            MAX_ALPHA_=MAX_ALPHA, MIN_ALPHA_=MIN_ALPHA, REDUCE=reduce, NW=nw, num_warps=_warps(tile))
        return grad, None, None, None, None, None, None, None, None, None, None, None


def composite2d_triton(table: Tensor, box: Tensor, offsets: Tensor, ids: Tensor, mcoef: tuple[float, float, float],
                       C: int, H: int,
                       W: int, tile: int, background: Tensor | None = None, near: float = float("-inf"),
                       lowpass_sigma: float = LOWPASS_SIGMA, geometry: bool = True):
    """Composite sorted 2-D Gaussian surfels front to back (the rules of ``fused.composite2d``).

    Args:
        table: ``[M, 21]`` per (camera, splat) entry (:data:`TABLE`); its gradient is returned by backward.
        box: ``[M, 4]`` inclusive pixel box ``(x0, x1, y0, y1)`` outside which the entry's alpha < 1/255;
        offsets: ``[C*TY*TX + 1]`` start of each camera-tile's pairs; ids: ``[P]`` the entry of each pair, sorted
            by camera-tile then depth (:func:`raster.bin_tiles`); mcoef: ``(m0, m1, m2)`` of the distortion's
            normalised depth ``m = m0 + m1 z + m2 / z`` (every camera; Python numbers: no transfer a step);
        background ``[3]`` (a constant) or None;
        near: hits nearer than this are skipped; lowpass_sigma: the screen-space low-pass filter's sigma (px);
        geometry: False when only the colour columns need a gradient (a frozen geometry: the backward skips the rest,
            which it leaves zero).
    Returns:
        rgb ``[C,H,W,3]`` (background composited), normal ``[C,H,W,3]``, alpha, depth (``sum w z / alpha``),
        median depth, distortion ``[C,H,W,1]``.
    """
    if background is not None and background.requires_grad:
        raise ValueError("triton rasteriser: the background is a constant (requires_grad background: use torch)")
    dev = table.device
    why = available(dev)
    if why is not None:
        raise RuntimeError(f"rasterizer=triton {why}")
    box32 = box.detach().clamp(-1, 1 << 30).to(torch.int32).contiguous()
    bg = table.new_empty(0) if background is None else background.detach().to(table).contiguous()
    prm = constants(table, (*mcoef, 1.0 / float(lowpass_sigma) ** 2))
    return _Composite2DTriton.apply(table.contiguous(), box32, offsets.contiguous(), ids.contiguous(), prm, bg,
                                    bool(geometry), int(C), int(H), int(W), int(tile), float(near))
