"""``rasterizer=triton``: the 2DGS footprints (``gs2d.render.footprint_2dgs``) as one Triton kernel, no gradient.

One lane an entry (camera, splat), in float64 as the PyTorch function (which is the reference: tests/test_triton2d.py
checks the radii, tile rectangles, pixel boxes and depths equal): the bounding boxes of the 3-sigma disk and of the
disk where ``opacity G >= 1/255`` (``render._conic_box``: the dual conic ``T diag(1, 1, -1/cut2) T^T``), the tile
rectangle (``raster.tile_rects``) and the pixel box (``render._pixel_box``). Its ~140 PyTorch operators a step become
one launch. Launched without floating-point contraction (``enable_fp_fusion=False``): rounded as the PyTorch
operators round, so that ``ceil`` / ``floor`` land where theirs do. Imported on first use (importing triton takes a
second).
"""
from __future__ import annotations

import torch
import triton
import triton.language as tl
from torch import Tensor

from arcsem.tritonsupport import constants

from .raster import Binning

__all__ = ["footprint_bin_2dgs_triton"]

I64_MIN = tl.constexpr(-(2**63))
INF = tl.constexpr(float("inf"))


@triton.jit
def _to_long(v):
    """``v.long()`` as PyTorch does it on the CPU: non-finite -> INT64_MIN (a GPU conversion gives 0 or INT64_MAX)."""
    finite = (v == v) & (tl.abs(v) < INF)  # noqa: PLR0124 (NaN test: Triton has no isnan)
    return tl.where(finite, tl.where(finite, v, 0.0).to(tl.int64), I64_MIN)


@triton.jit
def _conic_box(t0, t1, t2, t3, t4, t5, t6, t7, t8, cut2):
    """``render._conic_box`` of rows ``(t0 t1 t2; t3 t4 t5; t6 t7 t8)``: centre, half extents, valid (d22 < 0)."""
    f2 = -1.0 / cut2
    d00 = t0 * t0 + t1 * t1 + t2 * f2 * t2
    d02 = t0 * t6 + t1 * t7 + t2 * f2 * t8
    d11 = t3 * t3 + t4 * t4 + t5 * f2 * t5
    d12 = t3 * t6 + t4 * t7 + t5 * f2 * t8
    d22 = t6 * t6 + t7 * t7 + t8 * f2 * t8
    valid = d22 < 0
    den = tl.where(valid, d22, 1.0)
    cx = d02 / den
    cy = d12 / den
    qx = cx * cx - d00 / den
    qy = cy * cy - d11 / den
    ex = tl.sqrt(tl.where(qx < 1e-4, 1e-4, qx))  # (clamp_min: NaN stays NaN)
    ey = tl.sqrt(tl.where(qy < 1e-4, 1e-4, qy))
    return cx, cy, ex, ey, valid


@triton.jit
def _tile_range(c, r, ok, tile, lim, big):
    """One axis of ``raster.tile_rects``: ``[lo, hi)`` in tiles, clipped to ``[0, lim]``."""
    c = tl.where(ok, c, 0.0) - 0.5
    lo = _to_long(tl.floor(tl.minimum(tl.maximum((c - r) / tile, -big), big)))
    hi = _to_long(tl.floor(tl.minimum(tl.maximum((c + r + tile - 1) / tile, -big), big)))
    lo = tl.minimum(tl.maximum(lo, 0), lim)
    hi = tl.minimum(tl.maximum(hi, 0), lim)
    return lo, tl.where(ok, hi, lo)


@triton.jit
def _pixel_range(lo, hi, m, lim):
    """One axis of ``render._pixel_box``: inclusive pixel indices whose centres lie in ``[lo, hi]``."""
    a = lo - 0.5
    b = hi - 0.5
    a = tl.where(a != a, a, tl.minimum(tl.maximum(a, -1.0), m))  # noqa: PLR0124 (torch.clamp keeps NaN)
    b = tl.where(b != b, b, tl.minimum(tl.maximum(b, -2.0), m))  # noqa: PLR0124
    return tl.maximum(_to_long(tl.ceil(a)), 0), tl.minimum(_to_long(tl.floor(b)), lim)


@triton.jit(do_not_specialize=["M", "N"])  # the splat counts change at each densification
def footprint_kernel(Hm, op, prm, radius_, rects_, eff_, depth_, M, N, W, H, TX, TY, TILE: tl.constexpr,
                     BLOCK: tl.constexpr):
    s = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    m = s < M
    row = Hm + s * 12
    t0 = tl.load(row + 0, mask=m, other=0.0).to(tl.float64)
    t1 = tl.load(row + 1, mask=m, other=0.0).to(tl.float64)
    t2 = tl.load(row + 2, mask=m, other=0.0).to(tl.float64)
    t3 = tl.load(row + 3, mask=m, other=0.0).to(tl.float64)
    t4 = tl.load(row + 4, mask=m, other=0.0).to(tl.float64)
    t5 = tl.load(row + 5, mask=m, other=0.0).to(tl.float64)
    t6 = tl.load(row + 6, mask=m, other=0.0).to(tl.float64)
    t7 = tl.load(row + 7, mask=m, other=0.0).to(tl.float64)
    t8 = tl.load(row + 8, mask=m, other=1.0).to(tl.float64)
    z = tl.load(row + 11, mask=m, other=0.0).to(tl.float64)
    o = tl.load(op + s % N, mask=m, other=1.0).to(tl.float64)
    near = tl.load(prm)  # float64: Python floats reach Triton as float32
    sigma = tl.load(prm + 1)
    cut2 = 2.0 * tl.log(255.0 * tl.maximum(o, 1e-30))  # raster.effective_cutoff2
    cut2 = cut2 * (1 + 1e-4) + 1e-4
    c3x, c3y, e3x, e3y, ok3 = _conic_box(t0, t1, t2, t3, t4, t5, t6, t7, t8, tl.full([BLOCK], 9.0, tl.float64))
    inf = INF
    ok = ok3 & (z > near) & (tl.abs(e3x) < inf) & (tl.abs(e3y) < inf)
    r = tl.ceil(tl.maximum(tl.maximum(e3x, e3y), 3.0 * sigma))
    radius = tl.where(ok, _to_long(tl.minimum(r, 1e7)), 0)
    big = 4.0 * (W + H + TILE)
    okr = radius > 0
    rf = radius.to(tl.float64)
    tx0, tx1 = _tile_range(c3x, rf, okr, TILE, TX, big)
    ty0, ty1 = _tile_range(c3y, rf, okr, TILE, TY, big)
    cex, cey, eex, eey, oke = _conic_box(t0, t1, t2, t3, t4, t5, t6, t7, t8, tl.maximum(cut2, 1e-6))
    r2d = tl.sqrt(tl.maximum(cut2, 0.0)) * sigma
    cx = t2 / t8
    cy = t5 / t8
    lox = tl.minimum(tl.where(oke, cex - eex, -inf), cx - r2d) - 0.01
    loy = tl.minimum(tl.where(oke, cey - eey, -inf), cy - r2d) - 0.01
    hix = tl.maximum(tl.where(oke, cex + eex, inf), cx + r2d) + 0.01
    hiy = tl.maximum(tl.where(oke, cey + eey, inf), cy + r2d) + 0.01
    mm = (tl.maximum(W, H) + 1).to(tl.float64)
    x0, x1 = _pixel_range(lox, hix, mm, W - 1)
    y0, y1 = _pixel_range(loy, hiy, mm, H - 1)
    x1 = tl.where(cut2 > 0, x1, -1)
    tl.store(radius_ + s, radius, mask=m)
    tl.store(rects_ + 4 * s, tx0, mask=m)
    tl.store(rects_ + 4 * s + 1, tx1, mask=m)
    tl.store(rects_ + 4 * s + 2, ty0, mask=m)
    tl.store(rects_ + 4 * s + 3, ty1, mask=m)
    tl.store(eff_ + 4 * s, x0, mask=m)
    tl.store(eff_ + 4 * s + 1, x1, mask=m)
    tl.store(eff_ + 4 * s + 2, y0, mask=m)
    tl.store(eff_ + 4 * s + 3, y1, mask=m)
    tl.store(depth_ + s, z, mask=m)


@torch.no_grad()
def footprint_2dgs_triton(Hm: Tensor, opacities: Tensor, W: int, H: int, tile: int, near: float,
                          lowpass_sigma: float) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """:func:`gs2d.render.footprint_2dgs` (``Hm [C, N, 4, 3]``, ``opacities [N]``): radius ``[C, N]``, rects and
    effective pixel boxes ``[C, N, 4]`` (long), centre depth ``[C, N]`` (float64)."""
    C, N = Hm.shape[:2]
    M, dev = C * N, Hm.device
    radius = torch.empty(M, dtype=torch.long, device=dev)
    rects = torch.empty(M, 4, dtype=torch.long, device=dev)
    eff = torch.empty(M, 4, dtype=torch.long, device=dev)
    depth = torch.empty(M, dtype=torch.float64, device=dev)
    block = 256
    prm = constants(depth, (near, lowpass_sigma))
    footprint_kernel[(triton.cdiv(M, block),)](Hm.detach().contiguous(), opacities.detach().contiguous(), prm, radius,
                                               rects, eff, depth, M, N, W, H, -(-W // tile), -(-H // tile), TILE=tile,
                                               BLOCK=block, enable_fp_fusion=False)
    return radius.view(C, N), rects.view(C, N, 4), eff.view(C, N, 4), depth.view(C, N)


def footprint_bin_2dgs_triton(Hm: Tensor, opacities: Tensor, W: int, H: int, tile: int, near: float,
                              lowpass_sigma: float) -> tuple[Tensor, Tensor, Tensor, Binning]:
    """The footprints and the tile lists (:func:`raster.bin_tiles`'s, the expansion on a Triton kernel:
    :mod:`._triton2d_bin`): radius, rects, eff ``[C, N, 4]``, binning."""
    from ._triton2d_bin import bin_tiles_triton

    radius, rects, eff, depth = footprint_2dgs_triton(Hm, opacities, W, H, tile, near, lowpass_sigma)
    return radius, rects, eff, bin_tiles_triton(rects, depth, W, H, tile)
