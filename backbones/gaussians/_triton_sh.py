"""``rasterizer=triton``: the splats' colours as two Triton kernels (forward, backward): spherical harmonics of the
viewing direction, ``+ 0.5``, the clamp at 0, then the image's ACT.

On a GPU the PyTorch colours (:meth:`.model.GaussianModel.colors` with ``impl="torch"``: the basis, its sum, the clamp,
:meth:`arcsem.act.ACT.apply`) issue some 130 operators a training step, forward and backward; these kernels replace
them by two launches. The arithmetic is the fused C++ kernel's (cpp/sh.cpp; backbones/sh.py the reference): one
lane a splat, its ``(degree + 1)^2`` coefficients a row of a ``[BLOCK, 16]`` block, its cameras in a loop, so the
backward sums the cameras' gradients of a splat in registers (no atomics); the ACT gradients (sums over the splats)
are a partial sum a program, added up by one operator. Imported on first use (importing triton takes a second).
"""
from __future__ import annotations

import torch
import triton
import triton.language as tl
from torch import Tensor

from arcsem.tritonsupport import tl_dtype

from ..sh import C0, C1, C2, C3

__all__ = ["sh_colors_triton"]

BLOCK = 32  # splats a program (64: register spills in the backward, sm_90, Triton 3.9)


@triton.jit
def _basis(k, x, y, z):
    """``Y_k(x, y, z)`` and its partial derivatives, ``[BLOCK, 16]`` (``k`` the column), every degree up to 3: the
    coefficients above the active degree are 0 (:func:`_coefficients`), so one compiled kernel serves every degree."""
    x, y, z = x[:, None], y[:, None], z[:, None]
    zero = x * 0.0
    Y = tl.where(k == 0, zero + C0, zero)
    dx, dy, dz = zero, zero, zero
    Y = tl.where(k == 1, -C1 * y, tl.where(k == 2, C1 * z, tl.where(k == 3, -C1 * x, Y)))
    dx = tl.where(k == 3, zero - C1, dx)
    dy = tl.where(k == 1, zero - C1, dy)
    dz = tl.where(k == 2, zero + C1, dz)
    xx, yy, zz = x * x, y * y, z * z
    Y = tl.where(k == 4, C2_0 * x * y, Y)
    Y = tl.where(k == 5, C2_1 * y * z, Y)
    Y = tl.where(k == 6, C2_2 * (2 * zz - xx - yy), Y)
    Y = tl.where(k == 7, C2_3 * x * z, Y)
    Y = tl.where(k == 8, C2_4 * (xx - yy), Y)
    dx = tl.where(k == 4, C2_0 * y, tl.where(k == 6, C2_2 * -2 * x, tl.where(k == 7, C2_3 * z,
                                                                                 tl.where(k == 8, C2_4 * 2 * x, dx))))
    dy = tl.where(k == 4, C2_0 * x, tl.where(k == 5, C2_1 * z, tl.where(k == 6, C2_2 * -2 * y,
                                                                           tl.where(k == 8, C2_4 * -2 * y, dy))))
    dz = tl.where(k == 5, C2_1 * y, tl.where(k == 6, C2_2 * 4 * z, tl.where(k == 7, C2_3 * x, dz)))
    xy, yz, xz = x * y, y * z, x * z
    Y = tl.where(k == 9, C3_0 * y * (3 * xx - yy), Y)
    Y = tl.where(k == 10, C3_1 * xy * z, Y)
    Y = tl.where(k == 11, C3_2 * y * (4 * zz - xx - yy), Y)
    Y = tl.where(k == 12, C3_3 * z * (2 * zz - 3 * xx - 3 * yy), Y)
    Y = tl.where(k == 13, C3_4 * x * (4 * zz - xx - yy), Y)
    Y = tl.where(k == 14, C3_5 * z * (xx - yy), Y)
    Y = tl.where(k == 15, C3_6 * x * (xx - 3 * yy), Y)
    dx = tl.where(k == 9, C3_0 * 6 * xy, dx)
    dy = tl.where(k == 9, C3_0 * (3 * xx - 3 * yy), dy)
    dx = tl.where(k == 10, C3_1 * yz, dx)
    dy = tl.where(k == 10, C3_1 * xz, dy)
    dz = tl.where(k == 10, C3_1 * xy, dz)
    dx = tl.where(k == 11, C3_2 * -2 * xy, dx)
    dy = tl.where(k == 11, C3_2 * (4 * zz - xx - 3 * yy), dy)
    dz = tl.where(k == 11, C3_2 * 8 * yz, dz)
    dx = tl.where(k == 12, C3_3 * -6 * xz, dx)
    dy = tl.where(k == 12, C3_3 * -6 * yz, dy)
    dz = tl.where(k == 12, C3_3 * (6 * zz - 3 * xx - 3 * yy), dz)
    dx = tl.where(k == 13, C3_4 * (4 * zz - 3 * xx - yy), dx)
    dy = tl.where(k == 13, C3_4 * -2 * xy, dy)
    dz = tl.where(k == 13, C3_4 * 8 * xz, dz)
    dx = tl.where(k == 14, C3_5 * 2 * xz, dx)
    dy = tl.where(k == 14, C3_5 * -2 * yz, dy)
    dz = tl.where(k == 14, C3_5 * (xx - yy), dz)
    dx = tl.where(k == 15, C3_6 * (3 * xx - 3 * yy), dx)
    dy = tl.where(k == 15, C3_6 * -6 * xy, dy)
    return Y, dx, dy, dz


# the constants as module globals a kernel reads (Triton folds them)
C2_0, C2_1, C2_2, C2_3, C2_4 = (tl.constexpr(v) for v in C2)
C3_0, C3_1, C3_2, C3_3, C3_4, C3_5, C3_6 = (tl.constexpr(v) for v in C3)
C0, C1 = tl.constexpr(C0), tl.constexpr(C1)


@triton.jit
def _direction(means, origins, n, m, c, ORTHO: tl.constexpr):
    """Unit viewing direction of splats ``n`` from camera ``c`` (``F.normalize``, eps 1e-12) and the length before."""
    o0, o1, o2 = tl.load(origins + 3 * c), tl.load(origins + 3 * c + 1), tl.load(origins + 3 * c + 2)
    if ORTHO:
        v0 = tl.load(means + 3 * n, mask=m, other=0.0) * 0.0 + o0
        v1, v2 = v0 * 0.0 + o1, v0 * 0.0 + o2
    else:
        v0 = tl.load(means + 3 * n, mask=m, other=0.0) - o0
        v1 = tl.load(means + 3 * n + 1, mask=m, other=0.0) - o1
        v2 = tl.load(means + 3 * n + 2, mask=m, other=0.0) - o2
    length = tl.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    den = tl.maximum(length, 1e-12)
    return v0 / den, v1 / den, v2 / den, length


@triton.jit
def _coefficients(dc, rest, n, k, m, R, ch: tl.constexpr, K: tl.constexpr):
    """``[BLOCK, 16]`` coefficients of channel ``ch`` (column 0 the DC term; 0 from column ``K`` on)."""
    first = tl.load(dc + 3 * n[:, None] + ch + k * 0, mask=m[:, None] & (k == 0), other=0.0)
    more = tl.load(rest + (n[:, None] * R + k - 1) * 3 + ch, mask=m[:, None] & (k >= 1) & (k < K), other=0.0)
    return first + more


@triton.jit(do_not_specialize=["N", "K"])  # N changes at each densification, K with the degree: one compilation
def _forward(means, dc, rest, origins, aw, ab, rgb, N, C, R, K, ORTHO: tl.constexpr, ACT: tl.constexpr,
             BLOCK: tl.constexpr):
    n = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    m = n < N
    k = tl.arange(0, 16)[None, :]
    s0 = _coefficients(dc, rest, n, k, m, R, 0, K)
    s1 = _coefficients(dc, rest, n, k, m, R, 1, K)
    s2 = _coefficients(dc, rest, n, k, m, R, 2, K)
    for c in range(C):
        x, y, z, _ = _direction(means, origins, n, m, c, ORTHO)
        Y, _, _, _ = _basis(k, x, y, z)
        for ch in tl.static_range(3):
            s = s0 if ch == 0 else (s1 if ch == 1 else s2)
            v = tl.maximum(tl.sum(Y * s, axis=1) + 0.5, 0.0)
            if ACT:
                v = tl.minimum(tl.maximum(tl.load(aw + 3 * c + ch) * v + tl.load(ab + 3 * c + ch), 0.0), 1.0)
            tl.store(rgb + (c * N + n) * 3 + ch, v, mask=m)


@triton.jit(do_not_specialize=["N", "K"])
def _backward(means, dc, rest, origins, aw, ab, g, g_means, g_dc, g_rest, g_act, N, C, R, K, ORTHO: tl.constexpr,
              ACT: tl.constexpr, BLOCK: tl.constexpr):
    """Gradients of the splats of the block, summed over the cameras in registers; with ACT, the block's sums for the
    cameras' ``w, b`` into ``g_act[program, c, 0:6]``."""
    pid = tl.program_id(0)
    n = pid * BLOCK + tl.arange(0, BLOCK)
    m = n < N
    k = tl.arange(0, 16)[None, :]
    s0 = _coefficients(dc, rest, n, k, m, R, 0, K)
    s1 = _coefficients(dc, rest, n, k, m, R, 1, K)
    s2 = _coefficients(dc, rest, n, k, m, R, 2, K)
    gs0, gs1, gs2 = s0 * 0.0, s1 * 0.0, s2 * 0.0
    gv0 = tl.sum(s0, axis=1) * 0.0
    gv1, gv2 = gv0, gv0
    for c in range(C):
        x, y, z, length = _direction(means, origins, n, m, c, ORTHO)
        Y, dX, dY, dZ = _basis(k, x, y, z)
        gb = Y * 0.0  # sum over the channels of the coefficient times the colour's gradient, per column
        for ch in tl.static_range(3):
            s = s0 if ch == 0 else (s1 if ch == 1 else s2)
            pre = tl.sum(Y * s, axis=1) + 0.5  # the colour before the clamp
            gi = tl.load(g + (c * N + n) * 3 + ch, mask=m, other=0.0)
            if ACT:
                v = tl.maximum(pre, 0.0)
                w = tl.load(aw + 3 * c + ch)
                out = w * v + tl.load(ab + 3 * c + ch)
                gi = tl.where((out >= 0.0) & (out <= 1.0), gi, 0.0)
                tl.store(g_act + (pid * C + c) * 6 + ch, tl.sum(gi * v, axis=0))
                tl.store(g_act + (pid * C + c) * 6 + 3 + ch, tl.sum(gi, axis=0))
                gi = gi * w
            gc = tl.where(pre >= 0.0, gi, 0.0)[:, None]
            if ch == 0:
                gs0 += Y * gc
            elif ch == 1:
                gs1 += Y * gc
            else:
                gs2 += Y * gc
            gb += s * gc
        if not ORTHO:  # (degree 0: every coefficient after the first is 0, so is this)
            gd0 = tl.sum(gb * dX, axis=1)
            gd1 = tl.sum(gb * dY, axis=1)
            gd2 = tl.sum(gb * dZ, axis=1)
            big = length > 1e-12
            dot = tl.where(big, gd0 * x + gd1 * y + gd2 * z, 0.0)  # d = v / max(|v|, eps): (I - d d^T) / |v|
            den = tl.maximum(length, 1e-12)
            gv0 += (gd0 - x * dot) / den
            gv1 += (gd1 - y * dot) / den
            gv2 += (gd2 - z * dot) / den
    tl.store(g_means + 3 * n, gv0, mask=m)
    tl.store(g_means + 3 * n + 1, gv1, mask=m)
    tl.store(g_means + 3 * n + 2, gv2, mask=m)
    for ch in tl.static_range(3):
        gs = tl.where(k < K, gs0 if ch == 0 else (gs1 if ch == 1 else gs2), 0.0)  # 0 above the degree
        tl.store(g_dc + 3 * n[:, None] + ch + k * 0, gs, mask=m[:, None] & (k == 0))
        tl.store(g_rest + (n[:, None] * R + k - 1) * 3 + ch, gs, mask=m[:, None] & (k >= 1) & (k <= R))


class _ShColorsTriton(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, sh_dc, sh_rest, origins, act_w, act_b, ortho: bool, degree: int):
        N, R, C = means.shape[0], sh_rest.shape[1], origins.shape[0]
        has_act = act_w.numel() > 0
        rgb = means.new_empty(C, N, 3)
        _forward[(triton.cdiv(N, BLOCK),)](means, sh_dc, sh_rest, origins, act_w if has_act else means,
                                           act_b if has_act else means, rgb, N, C, R, (degree + 1) ** 2, ORTHO=ortho,
                                           ACT=has_act, BLOCK=BLOCK, num_warps=4)
        ctx.save_for_backward(means, sh_dc, sh_rest, origins, act_w, act_b)
        ctx.ortho, ctx.degree = ortho, degree
        return rgb

    @staticmethod
    def backward(ctx, g):
        means, sh_dc, sh_rest, origins, act_w, act_b = ctx.saved_tensors
        N, R, C = means.shape[0], sh_rest.shape[1], origins.shape[0]
        has_act = act_w.numel() > 0
        grid = (triton.cdiv(N, BLOCK),)
        g_means, g_dc, g_rest = torch.empty_like(means), torch.empty_like(sh_dc), torch.empty_like(sh_rest)
        g_act = means.new_empty(grid[0], C, 6) if has_act else means
        _backward[grid](means, sh_dc, sh_rest, origins, act_w if has_act else means, act_b if has_act else means,
                        g.contiguous(), g_means, g_dc, g_rest, g_act, N, C, R, (ctx.degree + 1) ** 2, ORTHO=ctx.ortho,
                        ACT=has_act, BLOCK=BLOCK, num_warps=4)
        gw = gb = None
        if has_act:
            sums = g_act.sum(0)  # [C, 6]
            gw, gb = sums[:, :3], sums[:, 3:]
        # degree 0 reads no rest coefficient and no direction: no gradient, as the PyTorch path
        lit = ctx.degree > 0
        return (g_means if lit else None), g_dc, (g_rest if lit else None), None, gw, gb, None, None


def sh_colors_triton(means: Tensor, sh_dc: Tensor, sh_rest: Tensor, origins: Tensor, ortho: bool, degree: int,
                     act: tuple[Tensor, Tensor] | None = None) -> Tensor:
    """:func:`.fused.sh_colors` on the Triton kernels (same arguments): ``[C, N, 3]`` colours
    ``max(SH(view direction) + 0.5, 0)``, with ``act = (w, b)`` then ``clamp(w[c] rgb + b[c], 0, 1)``."""
    tl_dtype(means)  # float32 / float64 only
    if not 0 <= degree <= 3 or sh_rest.shape[1] + 1 > 16:
        raise ValueError(f"sh_colors_triton: degree {degree} with {sh_rest.shape[1] + 1} coefficients (at most 3, 16)")
    from .fused import act_rows

    c = lambda t: t.contiguous()
    w, b = act_rows(means, origins, act)
    return _ShColorsTriton.apply(c(means), c(sh_dc), c(sh_rest), c(origins.to(means.dtype)), w, b, bool(ortho),
                                 int(degree))
