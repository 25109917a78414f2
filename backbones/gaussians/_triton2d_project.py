"""``rasterizer=triton``: the 2DGS projection as two Triton kernels (forward, backward): from the splats to the splat
table of :mod:`.triton2d` and the homographies the footprint kernel reads.

What ``gs2d.render.render_2dgs``'s PyTorch path computes in ~100 operators forward and ~150 backward
(``splat_homographies``, ``camera_facing_normals``, the screen-position shift, ``_splat_columns``), one lane a splat,
its cameras in a loop (the backward sums their gradients in registers: no atomics). The arithmetic is the fused C++
projection's (cpp/project.cpp) in the model's dtype; the PyTorch path is the reference (tests/test_triton2d.py).
Imported on first use (importing triton takes a second).
"""
from __future__ import annotations

import torch
import triton
import triton.language as tl
from torch import Tensor

from arcsem.tritonsupport import tl_dtype

from .triton2d import TABLE

__all__ = ["project_2dgs_triton"]


@triton.jit
def _rotation(n, quats, m):
    """Normalised quaternion (``F.normalize``, eps 1e-12), its norm, and the rotation matrix (``quat_to_rotmat``)."""
    qw = tl.load(quats + 4 * n, mask=m, other=1.0)
    qx = tl.load(quats + 4 * n + 1, mask=m, other=0.0)
    qy = tl.load(quats + 4 * n + 2, mask=m, other=0.0)
    qz = tl.load(quats + 4 * n + 3, mask=m, other=0.0)
    norm = tl.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    d = tl.maximum(norm, 1e-12)
    w, x, y, z = qw / d, qx / d, qy / d, qz / d
    r00, r01, r02 = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    r10, r11, r12 = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    r20, r21, r22 = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    return w, x, y, z, norm, r00, r01, r02, r10, r11, r12, r20, r21, r22


@triton.jit
def _row(Pc, i: tl.constexpr, r00, r10, r20, r01, r11, r21, s0, s1, m0, m1, m2):
    """Row ``i`` of ``H = P S`` (``S = [R[:, 0] s0, R[:, 1] s1, (m, 1)]``)."""
    p0, p1, p2, p3 = tl.load(Pc + 4 * i), tl.load(Pc + 4 * i + 1), tl.load(Pc + 4 * i + 2), tl.load(Pc + 4 * i + 3)
    return ((p0 * r00 + p1 * r10 + p2 * r20) * s0, (p0 * r01 + p1 * r11 + p2 * r21) * s1,
            p0 * m0 + p1 * m1 + p2 * m2 + p3)


@triton.jit
def _facing(r02, r12, r22, m0, m1, m2, view, c, ORTHO: tl.constexpr):
    """``camera_facing_normals``' sign: -1 where the normal (column 2 of R) points away from the camera."""
    v0, v1, v2 = tl.load(view + 3 * c), tl.load(view + 3 * c + 1), tl.load(view + 3 * c + 2)
    if not ORTHO:
        v0, v1, v2 = m0 - v0, m1 - v1, m2 - v2
    return tl.where(r02 * v0 + r12 * v1 + r22 * v2 > 0, -1.0, 1.0)


@triton.jit
def _gs_row(Pc, j: tl.constexpr, gu0, gu1, gu2, gv0, gv1, gv2, gw0, gw1, gw2, gz0, gz1, gz2):
    """Row ``j`` of ``g_S = P^T g_H`` (``g_H``'s rows: the gradients of Tu, Tv, Tw, Tz)."""
    p0, p1, p2, p3 = tl.load(Pc + j), tl.load(Pc + 4 + j), tl.load(Pc + 8 + j), tl.load(Pc + 12 + j)
    return (p0 * gu0 + p1 * gv0 + p2 * gw0 + p3 * gz0, p0 * gu1 + p1 * gv1 + p2 * gw1 + p3 * gz1,
            p0 * gu2 + p1 * gv2 + p2 * gw2 + p3 * gz2)


@triton.jit
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@triton.jit(do_not_specialize=["N"])  # N changes at each densification: one compilation, not one a size class
def project_forward(means, quats, scales, opac, colors, P, view, table, hm, N, C, ORTHO: tl.constexpr,
                    NCOL: tl.constexpr, BLOCK: tl.constexpr):
    n = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    m = n < N
    m0, m1, m2 = tl.load(means + 3 * n, mask=m, other=0.0), tl.load(means + 3 * n + 1, mask=m, other=0.0), \
        tl.load(means + 3 * n + 2, mask=m, other=0.0)
    s0, s1 = tl.load(scales + 2 * n, mask=m, other=0.0), tl.load(scales + 2 * n + 1, mask=m, other=0.0)
    op = tl.load(opac + n, mask=m, other=0.0)
    _, _, _, _, _, r00, r01, r02, r10, r11, r12, r20, r21, r22 = _rotation(n, quats, m)
    for c in range(C):
        Pc = P + 16 * c
        u0, u1, u2 = _row(Pc, 0, r00, r10, r20, r01, r11, r21, s0, s1, m0, m1, m2)
        v0, v1, v2 = _row(Pc, 1, r00, r10, r20, r01, r11, r21, s0, s1, m0, m1, m2)
        w0, w1, w2 = _row(Pc, 2, r00, r10, r20, r01, r11, r21, s0, s1, m0, m1, m2)
        z0, z1, z2 = _row(Pc, 3, r00, r10, r20, r01, r11, r21, s0, s1, m0, m1, m2)
        sg = _facing(r02, r12, r22, m0, m1, m2, view, c, ORTHO)
        e = c * N + n
        out = hm + 12 * e
        tl.store(out + 0, u0, mask=m)
        tl.store(out + 1, u1, mask=m)
        tl.store(out + 2, u2, mask=m)
        tl.store(out + 3, v0, mask=m)
        tl.store(out + 4, v1, mask=m)
        tl.store(out + 5, v2, mask=m)
        tl.store(out + 6, w0, mask=m)
        tl.store(out + 7, w1, mask=m)
        tl.store(out + 8, w2, mask=m)
        tl.store(out + 9, z0, mask=m)
        tl.store(out + 10, z1, mask=m)
        tl.store(out + 11, z2, mask=m)
        a0, a1, a2 = _cross(v0, v1, v2, w0, w1, w2)
        b0, b1, b2 = _cross(w0, w1, w2, u0, u1, u2)
        c0, c1, c2 = _cross(u0, u1, u2, v0, v1, v2)
        row = table + NCOL * e
        tl.store(row + 0, a0, mask=m)
        tl.store(row + 1, a1, mask=m)
        tl.store(row + 2, a2, mask=m)
        tl.store(row + 3, b0, mask=m)
        tl.store(row + 4, b1, mask=m)
        tl.store(row + 5, b2, mask=m)
        tl.store(row + 6, c0, mask=m)
        tl.store(row + 7, c1, mask=m)
        tl.store(row + 8, c2, mask=m)
        tl.store(row + 9, u2 / w2, mask=m)
        tl.store(row + 10, v2 / w2, mask=m)
        tl.store(row + 11, op, mask=m)
        tl.store(row + 12, z0, mask=m)
        tl.store(row + 13, z1, mask=m)
        tl.store(row + 14, z2, mask=m)
        tl.store(row + 15, tl.load(colors + 3 * e, mask=m, other=0.0), mask=m)
        tl.store(row + 16, tl.load(colors + 3 * e + 1, mask=m, other=0.0), mask=m)
        tl.store(row + 17, tl.load(colors + 3 * e + 2, mask=m, other=0.0), mask=m)
        tl.store(row + 18, sg * r02, mask=m)
        tl.store(row + 19, sg * r12, mask=m)
        tl.store(row + 20, sg * r22, mask=m)


@triton.jit(do_not_specialize=["N"])
def project_backward(means, quats, scales, P, view, gtab, g_means, g_quats, g_scales, g_opac, g_colors, g_shift, N, C,
                     ORTHO: tl.constexpr, NCOL: tl.constexpr, BLOCK: tl.constexpr, DT: tl.constexpr):
    n = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    m = n < N
    m0, m1, m2 = tl.load(means + 3 * n, mask=m, other=0.0), tl.load(means + 3 * n + 1, mask=m, other=0.0), \
        tl.load(means + 3 * n + 2, mask=m, other=0.0)
    s0, s1 = tl.load(scales + 2 * n, mask=m, other=0.0), tl.load(scales + 2 * n + 1, mask=m, other=0.0)
    w, x, y, z, norm, r00, r01, r02, r10, r11, r12, r20, r21, r22 = _rotation(n, quats, m)
    zero = tl.zeros([BLOCK], DT)
    g00, g01, g02, g10, g11, g12, g20, g21, g22 = zero, zero, zero, zero, zero, zero, zero, zero, zero
    gm0, gm1, gm2, gs0, gs1, gop = zero, zero, zero, zero, zero, zero
    for c in range(C):
        Pc = P + 16 * c
        u0, u1, u2 = _row(Pc, 0, r00, r10, r20, r01, r11, r21, s0, s1, m0, m1, m2)
        v0, v1, v2 = _row(Pc, 1, r00, r10, r20, r01, r11, r21, s0, s1, m0, m1, m2)
        w0, w1, w2 = _row(Pc, 2, r00, r10, r20, r01, r11, r21, s0, s1, m0, m1, m2)
        e = c * N + n
        row = gtab + NCOL * e
        ga0, ga1, ga2 = tl.load(row + 0, mask=m, other=0.0), tl.load(row + 1, mask=m, other=0.0), \
            tl.load(row + 2, mask=m, other=0.0)
        gb0, gb1, gb2 = tl.load(row + 3, mask=m, other=0.0), tl.load(row + 4, mask=m, other=0.0), \
            tl.load(row + 5, mask=m, other=0.0)
        gc0, gc1, gc2 = tl.load(row + 6, mask=m, other=0.0), tl.load(row + 7, mask=m, other=0.0), \
            tl.load(row + 8, mask=m, other=0.0)
        # a = Tv x Tw, b = Tw x Tu, c = Tu x Tv; g.(p x q): d/dp = q x g, d/dq = g x p
        hu = _cross(gb0, gb1, gb2, w0, w1, w2)
        t = _cross(v0, v1, v2, gc0, gc1, gc2)
        gu0, gu1, gu2 = hu[0] + t[0], hu[1] + t[1], hu[2] + t[2]
        hv = _cross(w0, w1, w2, ga0, ga1, ga2)
        t = _cross(gc0, gc1, gc2, u0, u1, u2)
        gv0, gv1, gv2 = hv[0] + t[0], hv[1] + t[1], hv[2] + t[2]
        hw = _cross(ga0, ga1, ga2, v0, v1, v2)
        t = _cross(u0, u1, u2, gb0, gb1, gb2)
        gw0, gw1, gw2 = hw[0] + t[0], hw[1] + t[1], hw[2] + t[2]
        # the centre (Tu.z / Tw.z, Tv.z / Tw.z)
        gcx, gcy = tl.load(row + 9, mask=m, other=0.0), tl.load(row + 10, mask=m, other=0.0)
        cx, cy = u2 / w2, v2 / w2
        gu2 += gcx / w2
        gv2 += gcy / w2
        gw2 -= (gcx * cx + gcy * cy) / w2
        # the screen-position shift: Tu += sx Tw, Tv += sy Tw (sx = sy = 0 in value)
        tl.store(g_shift + 2 * e, gu0 * w0 + gu1 * w1 + gu2 * w2, mask=m)
        tl.store(g_shift + 2 * e + 1, gv0 * w0 + gv1 * w1 + gv2 * w2, mask=m)
        gz0, gz1, gz2 = tl.load(row + 12, mask=m, other=0.0), tl.load(row + 13, mask=m, other=0.0), \
            tl.load(row + 14, mask=m, other=0.0)
        gop += tl.load(row + 11, mask=m, other=0.0)
        tl.store(g_colors + 3 * e, tl.load(row + 15, mask=m, other=0.0), mask=m)
        tl.store(g_colors + 3 * e + 1, tl.load(row + 16, mask=m, other=0.0), mask=m)
        tl.store(g_colors + 3 * e + 2, tl.load(row + 17, mask=m, other=0.0), mask=m)
        # g_S[j][k] = sum_i P[i][j] g_H[i][k] (rows j of S = [R[:, 0] s0, R[:, 1] s1, m])
        a0, a1, a2 = _gs_row(Pc, 0, gu0, gu1, gu2, gv0, gv1, gv2, gw0, gw1, gw2, gz0, gz1, gz2)
        b0, b1, b2 = _gs_row(Pc, 1, gu0, gu1, gu2, gv0, gv1, gv2, gw0, gw1, gw2, gz0, gz1, gz2)
        d0, d1, d2 = _gs_row(Pc, 2, gu0, gu1, gu2, gv0, gv1, gv2, gw0, gw1, gw2, gz0, gz1, gz2)
        g00, g10, g20 = g00 + a0 * s0, g10 + b0 * s0, g20 + d0 * s0
        g01, g11, g21 = g01 + a1 * s1, g11 + b1 * s1, g21 + d1 * s1
        gs0 += a0 * r00 + b0 * r10 + d0 * r20
        gs1 += a1 * r01 + b1 * r11 + d1 * r21
        gm0, gm1, gm2 = gm0 + a2, gm1 + b2, gm2 + d2
        sg = _facing(r02, r12, r22, m0, m1, m2, view, c, ORTHO)
        g02 += sg * tl.load(row + 18, mask=m, other=0.0)
        g12 += sg * tl.load(row + 19, mask=m, other=0.0)
        g22 += sg * tl.load(row + 20, mask=m, other=0.0)
    # R(w, x, y, z) -> the normalised quaternion, then F.normalize's backward
    gw = 2 * (-z * g01 + y * g02 + z * g10 - x * g12 - y * g20 + x * g21)
    gx = 2 * (y * g01 + z * g02 + y * g10 - 2 * x * g11 - w * g12 + z * g20 + w * g21 - 2 * x * g22)
    gy = 2 * (-2 * y * g00 + x * g01 + w * g02 + x * g10 + z * g12 - w * g20 + z * g21 - 2 * y * g22)
    gz = 2 * (-2 * z * g00 - w * g01 + x * g02 + w * g10 - 2 * z * g11 + y * g12 + x * g20 + y * g21)
    big = norm > 1e-12
    d = tl.maximum(norm, 1e-12)
    dot = tl.where(big, w * gw + x * gx + y * gy + z * gz, 0.0)
    tl.store(g_quats + 4 * n, (gw - w * dot) / d, mask=m)
    tl.store(g_quats + 4 * n + 1, (gx - x * dot) / d, mask=m)
    tl.store(g_quats + 4 * n + 2, (gy - y * dot) / d, mask=m)
    tl.store(g_quats + 4 * n + 3, (gz - z * dot) / d, mask=m)
    tl.store(g_means + 3 * n, gm0, mask=m)
    tl.store(g_means + 3 * n + 1, gm1, mask=m)
    tl.store(g_means + 3 * n + 2, gm2, mask=m)
    tl.store(g_scales + 2 * n, gs0, mask=m)
    tl.store(g_scales + 2 * n + 1, gs1, mask=m)
    tl.store(g_opac + n, gop, mask=m)


BLOCK = 128


class _Project2DTriton(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, opac, colors, leaf, P, view, ortho):
        N, C = means.shape[0], P.shape[0]
        table = means.new_empty(C * N, TABLE)
        hm = means.new_empty(C * N, 12)
        project_forward[(triton.cdiv(N, BLOCK),)](means, quats, scales, opac, colors, P, view, table, hm, N, C,
                                                  ORTHO=ortho, NCOL=TABLE, BLOCK=BLOCK)
        ctx.save_for_backward(means, quats, scales, P, view)
        ctx.ortho, ctx.leaf_shape = ortho, leaf.shape
        ctx.mark_non_differentiable(hm)
        return table, hm

    @staticmethod
    def backward(ctx, g_table, _g_hm):
        means, quats, scales, P, view = ctx.saved_tensors
        N, C = means.shape[0], P.shape[0]
        gm, gq, gs = torch.empty_like(means), torch.empty_like(quats), torch.empty_like(scales)
        gop = means.new_empty(N)
        gcol = means.new_empty(C, N, 3)
        gsh = means.new_empty(C * N, 2)
        project_backward[(triton.cdiv(N, BLOCK),)](means, quats, scales, P, view, g_table.contiguous(), gm, gq, gs, gop,
                                                   gcol, gsh, N, C, ORTHO=ctx.ortho, NCOL=TABLE, BLOCK=BLOCK,
                                                   DT=tl_dtype(means))
        return gm, gq, gs, gop, gcol, gsh.reshape(ctx.leaf_shape), None, None, None


def project_2dgs_triton(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor, leaf: Tensor,
                        P: Tensor, view: Tensor, ortho: bool) -> tuple[Tensor, Tensor]:
    """The splat table ``[C*N, 21]`` (:data:`.triton2d.TABLE`) and the homographies ``[C*N, 12]`` (rows Tu, Tv, Tw,
    Tz; no gradient) of 2-D splats: means ``[N, 3]``, quats ``[N, 4]``, scales ``[N, 2]``, opacities ``[N]``,
    colors ``[C, N, 3]``; leaf ``[C, N, 2]``: the screen-position leaf (a zero shift; its gradient is the screen-position
    gradient); P ``[C, 4, 4]`` (``pixel_projection``); view ``[C, 3]``: camera forward (orthographic) or centre."""
    c = lambda t: t.contiguous()
    return _Project2DTriton.apply(c(means), c(quats), c(scales), c(opacities), c(colors), leaf, c(P.to(means.dtype)),
                                  c(view.to(means.dtype)), bool(ortho))
