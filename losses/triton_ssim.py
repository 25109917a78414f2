"""The SSIM map of the ``dssim`` loss as four Triton kernels (two forward, two backward), for CUDA.

On a GPU the PyTorch SSIM (:func:`arcsem.imageops.ssim_map`: five grouped convolutions and the arithmetic around
them) issues some 70 operators a training step, forward and backward, each a call the host makes before the GPU can
run it; these kernels replace them by four launches. The arithmetic is the fused C++ kernel's (losses/cpp/ssim.cpp):
a separable Gaussian blur of x, y, x^2, y^2 and xy with zero padding, along a row (W) and then along a column (H);
backward, with ``G = dL/dS`` and the partials ``a, b, c`` of S in the blurs of x, x^2 and xy,
``dL/dx = blur(G a) + 2 x blur(G b) + y blur(G c)`` (the zero-padded symmetric blur is its own transpose). The
row pass of the backward forms ``G a, G b, G c`` at each of its taps' pixels rather than storing them first.

One program covers ``BLOCK`` values of one image row (``W * ch`` values, channels last). The PyTorch function stays
the reference (tests/test_fused_losses.py: float64 equal to round-off, through Triton's interpreter on the CPU).
"""
from __future__ import annotations

import torch
import triton
import triton.language as tl
from torch import Tensor

from arcsem.errors import ConfigError
from arcsem.imageops import C1, C2, gaussian_window
from arcsem.tritonsupport import available, constants, tl_dtype

__all__ = ["triton_ssim_map"]

BLOCK = 256  # values of a row a program; 8 warps of 32 lanes


@triton.jit
def _row_pass_forward(x, y, g, h, L, n, CH: tl.constexpr, K: tl.constexpr, BLOCK: tl.constexpr):
    """``h[q, row, j] = sum_k g[k] f_q(row, j + (k - K//2) CH)`` for ``f = x, y, x^2, y^2, xy`` (zero outside)."""
    row, blk = tl.program_id(0), tl.program_id(1)
    j = blk * BLOCK + tl.arange(0, BLOCK)
    inside = j < L
    base = row * L
    s0 = tl.zeros([BLOCK], dtype=x.dtype.element_ty)
    s1, s2, s3, s4 = s0, s0, s0, s0
    for k in tl.static_range(K):
        pos = j + (k - K // 2) * CH
        m = inside & (pos >= 0) & (pos < L)
        a = tl.load(x + base + pos, mask=m, other=0.0)
        b = tl.load(y + base + pos, mask=m, other=0.0)
        gk = tl.load(g + k)
        s0 += gk * a
        s1 += gk * b
        s2 += gk * a * a
        s3 += gk * b * b
        s4 += gk * a * b
    at = base + j
    tl.store(h + at, s0, mask=inside)
    tl.store(h + n + at, s1, mask=inside)
    tl.store(h + 2 * n + at, s2, mask=inside)
    tl.store(h + 3 * n + at, s3, mask=inside)
    tl.store(h + 4 * n + at, s4, mask=inside)


@triton.jit
def _terms(mx, my, sxx, syy, sxy, c1, c2):
    """``S = (a1 a2) / (b1 b2)`` of a pixel's blurs (cpp/ssim.cpp's ``ssim_terms``)."""
    a1 = 2 * mx * my + c1
    a2 = 2 * (sxy - mx * my) + c2
    b1 = mx * mx + my * my + c1
    b2 = (sxx - mx * mx) + (syy - my * my) + c2
    return a1, a2, b1, b2


@triton.jit
def _column_pass_forward(h, g, prm, smap, stats, H, L, n, K: tl.constexpr, BLOCK: tl.constexpr):
    """The blurs along the column (within the row's image), then the SSIM map; the blurs kept for the backward."""
    row, blk = tl.program_id(0), tl.program_id(1)
    j = blk * BLOCK + tl.arange(0, BLOCK)
    inside = j < L
    r = row % H
    v0 = tl.zeros([BLOCK], dtype=h.dtype.element_ty)
    v1, v2, v3, v4 = v0, v0, v0, v0
    for k in tl.static_range(K):
        rr = r + k - K // 2 + tl.zeros([BLOCK], dtype=tl.int32)  # a block: a scalar condition in a mask fails
        m = inside & (rr >= 0) & (rr < H)
        at = (row + k - K // 2) * L + j
        gk = tl.load(g + k)
        v0 += gk * tl.load(h + at, mask=m, other=0.0)
        v1 += gk * tl.load(h + n + at, mask=m, other=0.0)
        v2 += gk * tl.load(h + 2 * n + at, mask=m, other=0.0)
        v3 += gk * tl.load(h + 3 * n + at, mask=m, other=0.0)
        v4 += gk * tl.load(h + 4 * n + at, mask=m, other=0.0)
    a1, a2, b1, b2 = _terms(v0, v1, v2, v3, v4, tl.load(prm), tl.load(prm + 1))
    at = row * L + j
    tl.store(smap + at, (a1 * a2) / (b1 * b2), mask=inside)
    tl.store(stats + at, v0, mask=inside)
    tl.store(stats + n + at, v1, mask=inside)
    tl.store(stats + 2 * n + at, v2, mask=inside)
    tl.store(stats + 3 * n + at, v3, mask=inside)
    tl.store(stats + 4 * n + at, v4, mask=inside)


@triton.jit
def _row_pass_backward(gmap, stats, g, prm, h, L, n, CH: tl.constexpr, K: tl.constexpr, BLOCK: tl.constexpr):
    """``h[q] = row blur of G a, G b, G c`` (the partials of S in the blurs of x, x^2, xy, times ``G = dL/dS``)."""
    row, blk = tl.program_id(0), tl.program_id(1)
    j = blk * BLOCK + tl.arange(0, BLOCK)
    inside = j < L
    base = row * L
    c1, c2 = tl.load(prm), tl.load(prm + 1)
    s0 = tl.zeros([BLOCK], dtype=gmap.dtype.element_ty)
    s1, s2 = s0, s0
    for k in tl.static_range(K):
        pos = j + (k - K // 2) * CH
        m = inside & (pos >= 0) & (pos < L)
        at = base + pos
        mx = tl.load(stats + at, mask=m, other=0.0)
        my = tl.load(stats + n + at, mask=m, other=0.0)
        sxx = tl.load(stats + 2 * n + at, mask=m, other=0.0)
        syy = tl.load(stats + 3 * n + at, mask=m, other=0.0)
        sxy = tl.load(stats + 4 * n + at, mask=m, other=0.0)
        G = tl.load(gmap + at, mask=m, other=0.0)  # zero outside: the pixel adds nothing
        a1, a2, b1, b2 = _terms(mx, my, sxx, syy, sxy, c1, c2)
        S = (a1 * a2) / (b1 * b2)
        gk = tl.load(g + k)
        s0 += gk * G * (2 * my * (a2 - a1) / (b1 * b2) - 2 * mx * S * (1 / b1 - 1 / b2))
        s1 += gk * G * (-S / b2)
        s2 += gk * G * (2 * a1 / (b1 * b2))
    at = base + j
    tl.store(h + at, s0, mask=inside)
    tl.store(h + n + at, s1, mask=inside)
    tl.store(h + 2 * n + at, s2, mask=inside)


@triton.jit
def _column_pass_backward(h, g, x, y, gx, H, L, n, K: tl.constexpr, BLOCK: tl.constexpr):
    """``dL/dx = v0 + 2 x v1 + y v2`` with ``v`` the column blurs of the row pass's sums."""
    row, blk = tl.program_id(0), tl.program_id(1)
    j = blk * BLOCK + tl.arange(0, BLOCK)
    inside = j < L
    r = row % H
    v0 = tl.zeros([BLOCK], dtype=h.dtype.element_ty)
    v1, v2 = v0, v0
    for k in tl.static_range(K):
        rr = r + k - K // 2 + tl.zeros([BLOCK], dtype=tl.int32)  # a block: a scalar condition in a mask fails
        m = inside & (rr >= 0) & (rr < H)
        at = (row + k - K // 2) * L + j
        gk = tl.load(g + k)
        v0 += gk * tl.load(h + at, mask=m, other=0.0)
        v1 += gk * tl.load(h + n + at, mask=m, other=0.0)
        v2 += gk * tl.load(h + 2 * n + at, mask=m, other=0.0)
    at = row * L + j
    xv = tl.load(x + at, mask=inside, other=0.0)
    yv = tl.load(y + at, mask=inside, other=0.0)
    tl.store(gx + at, v0 + 2 * xv * v1 + yv * v2, mask=inside)


def _grid(x: Tensor) -> tuple[int, int]:
    B, H, W, ch = x.shape
    return B * H, triton.cdiv(W * ch, BLOCK)


class _SSIMMapTriton(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x: Tensor, y: Tensor, window: Tensor) -> Tensor:
        _, H, W, ch = x.shape
        L, n = W * ch, x.numel()
        prm = constants(x, (C1, C2))
        h = torch.empty(5, n, dtype=x.dtype, device=x.device)
        smap, stats = torch.empty_like(x), torch.empty(5, n, dtype=x.dtype, device=x.device)
        _row_pass_forward[_grid(x)](x, y, window, h, L, n, CH=ch, K=window.numel(), BLOCK=BLOCK, num_warps=8)
        _column_pass_forward[_grid(x)](h, window, prm, smap, stats, H, L, n, K=window.numel(), BLOCK=BLOCK,
                                       num_warps=8)
        ctx.save_for_backward(x, y, window, stats)
        return smap

    @staticmethod
    def backward(ctx, g_map: Tensor):
        x, y, window, stats = ctx.saved_tensors
        _, H, W, ch = x.shape
        L, n = W * ch, x.numel()
        h = torch.empty(3, n, dtype=x.dtype, device=x.device)
        gx = torch.empty_like(x)
        _row_pass_backward[_grid(x)](g_map.contiguous(), stats, window, constants(x, (C1, C2)), h, L, n, CH=ch,
                                     K=window.numel(), BLOCK=BLOCK, num_warps=8)
        _column_pass_backward[_grid(x)](h, window, x, y, gx, H, L, n, K=window.numel(), BLOCK=BLOCK, num_warps=8)
        return gx, None, None


def triton_ssim_map(x: Tensor, y: Tensor, size: int = 11, sigma: float = 1.5) -> Tensor:
    """:func:`arcsem.imageops.ssim_map` on the Triton kernels: ``[C, H, W, ch]`` x2 -> ``[C, H, W, ch]``.

    Differentiable in ``x`` only (``y`` is the target); float32 or float64 CUDA tensors (CPU ones under
    ``TRITON_INTERPRET=1``)."""
    if x.shape != y.shape or x.ndim != 4:
        raise ValueError(f"ssim_map: expected two [C,H,W,ch] tensors, got {tuple(x.shape)} and {tuple(y.shape)}")
    why = available(x.device)
    if why is not None:
        raise ConfigError(f"dssim.impl=triton {why}")
    tl_dtype(x)  # float32 / float64 only
    g = gaussian_window(size, sigma, x.dtype, x.device)
    return _SSIMMapTriton.apply(x.contiguous(), y.detach().to(x.dtype).contiguous(), g)
