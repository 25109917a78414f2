"""The official 2DGS normal consistency (:class:`arcsem.losses.geometry.NormalConsistency`) as three Triton kernels
(one forward, two backward), for CUDA.

On a GPU the PyTorch loss (unproject the depth map, central differences, a cross product, normalise, the weighted
mean) issues some hundred operators a training step, forward and backward; these kernels replace them by three
launches and a handful of operators. The arithmetic is the fused C++ kernel's (losses/cpp/normals.cpp): world points
``P = o + D d`` from the depth ``D`` and the rays, given per camera as affine functions of the pixel centre; at an
interior pixel ``c = (P[y+1] - P[y-1]) x (P[x+1] - P[x-1])``, ``n = c / max(|c|, 1e-12)``; the loss is the mean over
the pixels with ``n != 0`` of ``1 - (N . n) alpha`` (``N`` rendered, ``alpha`` detached). The pixel count stays on the
device (no host read). The PyTorch loss stays the reference (tests/test_triton_losses.py).
"""
from __future__ import annotations

import torch
import triton
import triton.language as tl
from torch import Tensor

from arcsem.errors import ConfigError
from arcsem.tritonsupport import available, tl_dtype

__all__ = ["triton_normal_consistency"]

BLOCK = 256  # pixels a program


@triton.jit
def _point(D, o, d, c, y, x, W, m):
    """World point of pixel ``(y, x)`` of camera ``c`` (blocks; ``D`` the camera's depth map): ``o(u, v) + D d(u, v)``,
    ``(u, v)`` the pixel centre, ``o``, ``d`` rows ``(r_u, r_v, r_1)`` of ``[C, 3, 3]``."""
    u = x.to(D.dtype.element_ty) + 0.5
    v = y.to(D.dtype.element_ty) + 0.5
    depth = tl.load(D + y * W + x, mask=m, other=0.0)
    return (tl.load(o + 9 * c, mask=m, other=0.0) * u + tl.load(o + 9 * c + 3, mask=m, other=0.0) * v
            + tl.load(o + 9 * c + 6, mask=m, other=0.0)
            + depth * (tl.load(d + 9 * c, mask=m, other=0.0) * u + tl.load(d + 9 * c + 3, mask=m, other=0.0) * v
                       + tl.load(d + 9 * c + 6, mask=m, other=0.0)),
            tl.load(o + 9 * c + 1, mask=m, other=0.0) * u + tl.load(o + 9 * c + 4, mask=m, other=0.0) * v
            + tl.load(o + 9 * c + 7, mask=m, other=0.0)
            + depth * (tl.load(d + 9 * c + 1, mask=m, other=0.0) * u + tl.load(d + 9 * c + 4, mask=m, other=0.0) * v
                       + tl.load(d + 9 * c + 7, mask=m, other=0.0)),
            tl.load(o + 9 * c + 2, mask=m, other=0.0) * u + tl.load(o + 9 * c + 5, mask=m, other=0.0) * v
            + tl.load(o + 9 * c + 8, mask=m, other=0.0)
            + depth * (tl.load(d + 9 * c + 2, mask=m, other=0.0) * u + tl.load(d + 9 * c + 5, mask=m, other=0.0) * v
                       + tl.load(d + 9 * c + 8, mask=m, other=0.0)))


@triton.jit
def _normal(D, o, d, p, H, W, inside):
    """At pixels ``p`` (a block): the two differences ``dy``, ``dx``, ``c = dy x dx``, ``|c|`` and whether the pixel
    counts (interior, ``|c| > 0``)."""
    x = p % W
    y = (p // W) % H
    c = p // (W * H)
    m = inside & (x > 0) & (x < W - 1) & (y > 0) & (y < H - 1)
    Dc = D + c * H * W
    ax, ay, az = _point(Dc, o, d, c, y + 1, x, W, m)
    bx, by, bz = _point(Dc, o, d, c, y - 1, x, W, m)
    dy0, dy1, dy2 = ax - bx, ay - by, az - bz
    ax, ay, az = _point(Dc, o, d, c, y, x + 1, W, m)
    bx, by, bz = _point(Dc, o, d, c, y, x - 1, W, m)
    dx0, dx1, dx2 = ax - bx, ay - by, az - bz
    c0 = dy1 * dx2 - dy2 * dx1
    c1 = dy2 * dx0 - dy0 * dx2
    c2 = dy0 * dx1 - dy1 * dx0
    length = tl.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    return dy0, dy1, dy2, dx0, dx1, dx2, c0, c1, c2, length, m & (length > 0)


@triton.jit
def _forward(D, o, d, N, A, part, n_pix, H, W, BLOCK: tl.constexpr):
    """Per program: the sum of ``1 - (N . n) alpha`` over its counted pixels and their number -> ``part[pid]``."""
    pid = tl.program_id(0)
    p = pid * BLOCK + tl.arange(0, BLOCK)
    inside = p < n_pix
    _, _, _, _, _, _, c0, c1, c2, length, ok = _normal(D, o, d, p, H, W, inside)
    inv = 1.0 / tl.maximum(length, 1e-12)
    dot = (tl.load(N + 3 * p, mask=ok, other=0.0) * c0 + tl.load(N + 3 * p + 1, mask=ok, other=0.0) * c1
           + tl.load(N + 3 * p + 2, mask=ok, other=0.0) * c2) * inv
    err = tl.where(ok, 1.0 - dot * tl.load(A + p, mask=ok, other=0.0), 0.0)
    tl.store(part + 2 * pid, tl.sum(err, axis=0))
    tl.store(part + 2 * pid + 1, tl.sum(ok.to(err.dtype), axis=0))


@triton.jit
def _backward_normals(D, o, d, N, A, scale, gN, gd, n_pix, H, W, BLOCK: tl.constexpr):
    """``dL/dN = -k alpha n`` and, per pixel, ``dL/d(dy), dL/d(dx)`` (``gd [n_pix, 6]``; zero where not counted);
    ``k = scale[0] / max(scale[1], 1)``: the loss's gradient over the pixel count."""
    pid = tl.program_id(0)
    p = pid * BLOCK + tl.arange(0, BLOCK)
    inside = p < n_pix
    dy0, dy1, dy2, dx0, dx1, dx2, c0, c1, c2, length, ok = _normal(D, o, d, p, H, W, inside)
    k = tl.load(scale) / tl.maximum(tl.load(scale + 1), 1.0)
    w = tl.where(ok, -k * tl.load(A + p, mask=ok, other=0.0), 0.0)
    inv = 1.0 / tl.maximum(length, 1e-12)
    n0, n1, n2 = c0 * inv, c1 * inv, c2 * inv
    tl.store(gN + 3 * p, w * n0, mask=inside)
    tl.store(gN + 3 * p + 1, w * n1, mask=inside)
    tl.store(gN + 3 * p + 2, w * n2, mask=inside)
    g0 = w * tl.load(N + 3 * p, mask=ok, other=0.0)
    g1 = w * tl.load(N + 3 * p + 1, mask=ok, other=0.0)
    g2 = w * tl.load(N + 3 * p + 2, mask=ok, other=0.0)
    # n = c / max(|c|, eps): (I - n n^T) / |c| above eps, I / eps below
    proj = tl.where(length > 1e-12, n0 * g0 + n1 * g1 + n2 * g2, 0.0)
    gc0, gc1, gc2 = (g0 - n0 * proj) * inv, (g1 - n1 * proj) * inv, (g2 - n2 * proj) * inv
    tl.store(gd + 6 * p, dx1 * gc2 - dx2 * gc1, mask=inside)  # c = dy x dx: dL/d(dy) = dx x gc
    tl.store(gd + 6 * p + 1, dx2 * gc0 - dx0 * gc2, mask=inside)
    tl.store(gd + 6 * p + 2, dx0 * gc1 - dx1 * gc0, mask=inside)
    tl.store(gd + 6 * p + 3, gc1 * dy2 - gc2 * dy1, mask=inside)  # dL/d(dx) = gc x dy
    tl.store(gd + 6 * p + 4, gc2 * dy0 - gc0 * dy2, mask=inside)
    tl.store(gd + 6 * p + 5, gc0 * dy1 - gc1 * dy0, mask=inside)


@triton.jit
def _backward_depth(d, gd, gD, n_pix, H, W, BLOCK: tl.constexpr):
    """``dL/dD = dL/dP . d``, ``dL/dP`` gathered from the differences of the four neighbours that use the pixel."""
    pid = tl.program_id(0)
    p = pid * BLOCK + tl.arange(0, BLOCK)
    inside = p < n_pix
    x = p % W
    y = (p // W) % H
    c = p // (W * H)
    up, down = inside & (y > 0), inside & (y < H - 1)
    left, right = inside & (x > 0), inside & (x < W - 1)
    u = x.to(gD.dtype.element_ty) + 0.5
    v = y.to(gD.dtype.element_ty) + 0.5
    out = tl.zeros([BLOCK], dtype=gD.dtype.element_ty)
    for q in tl.static_range(3):
        gp = (tl.load(gd + 6 * (p - W) + q, mask=up, other=0.0) - tl.load(gd + 6 * (p + W) + q, mask=down, other=0.0)
              + tl.load(gd + 6 * (p - 1) + 3 + q, mask=left, other=0.0)
              - tl.load(gd + 6 * (p + 1) + 3 + q, mask=right, other=0.0))
        ray = (tl.load(d + 9 * c + q, mask=inside, other=0.0) * u + tl.load(d + 9 * c + 3 + q, mask=inside, other=0.0)
               * v + tl.load(d + 9 * c + 6 + q, mask=inside, other=0.0))
        out += gp * ray
    tl.store(gD + p, out, mask=inside)


class _NormalConsistencyTriton(torch.autograd.Function):
    @staticmethod
    def forward(ctx, depth: Tensor, normal: Tensor, origins: Tensor, dirs: Tensor, alpha: Tensor) -> Tensor:
        C, H, W = depth.shape
        n = C * H * W
        grid = (triton.cdiv(n, BLOCK),)
        part = torch.empty(grid[0], 2, dtype=depth.dtype, device=depth.device)
        _forward[grid](depth, origins, dirs, normal, alpha, part, n, H, W, BLOCK=BLOCK, num_warps=4)
        total = part.sum(0)  # [error sum, pixels counted]
        ctx.save_for_backward(depth, normal, origins, dirs, alpha, total[1:])
        return total[0] / total[1].clamp_min(1.0)

    @staticmethod
    def backward(ctx, g: Tensor):
        depth, normal, origins, dirs, alpha, count = ctx.saved_tensors
        C, H, W = depth.shape
        n = C * H * W
        grid = (triton.cdiv(n, BLOCK),)
        scale = torch.cat([g.reshape(1).to(depth.dtype), count])
        g_normal, g_depth = torch.empty_like(normal), torch.empty_like(depth)
        gd = torch.empty(n, 6, dtype=depth.dtype, device=depth.device)
        _backward_normals[grid](depth, origins, dirs, normal, alpha, scale, g_normal, gd, n, H, W, BLOCK=BLOCK,
                                num_warps=4)
        _backward_depth[grid](dirs, gd, g_depth, n, H, W, BLOCK=BLOCK, num_warps=4)
        return g_depth, g_normal, None, None, None


def triton_normal_consistency(depth: Tensor, normal: Tensor, alpha: Tensor, cams) -> Tensor:
    """The official 2DGS normal consistency on the Triton kernels (a scalar); the arguments of
    :func:`arcsem.losses.fused.fused_normal_consistency`: ``depth [C, H, W, 1]``, ``normal [C, H, W, 3]``,
    ``alpha [C, H, W, 1]`` (no gradient), the views' :class:`arcsem.cameras.Cameras`."""
    from arcsem.losses.fused import _affine_rays

    why = available(depth.device)
    if why is not None:
        raise ConfigError(f"normal_consistency.impl=triton {why}")
    tl_dtype(depth)  # float32 / float64 only
    origins, dirs = _affine_rays(cams, depth.dtype)
    return _NormalConsistencyTriton.apply(depth[..., 0].contiguous(), normal.to(depth.dtype).contiguous(),
                                          origins.to(depth.device), dirs.to(depth.device),
                                          alpha.detach()[..., 0].to(depth.dtype).contiguous())
