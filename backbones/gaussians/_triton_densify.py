"""``rasterizer=triton``: one step's densification statistics as one Triton kernel, for CUDA.

The PyTorch statistics (:func:`.densify.screen_grad_norms` and :meth:`.densify.DensifyStats.accumulate`) issue some 45
operators a training step; this kernel adds the step to the accumulators in place in one launch. Per (camera ``c``,
splat ``n``) visible in ``c``: ``g_cam = R_c g_n`` (``g``: dL/d mean), ``z`` the camera depth of the mean (1 for an
orthographic camera), ``norm = |(g_cam.x z / fx W / 2, g_cam.y z / fy H / 2)|``; ``grad_sum[n] += norm``,
``count[n] += 1``, ``max_radii[n] = max(max_radii[n], radii[c, n])``. One lane a splat, its cameras in a loop, in the
gradient's dtype as the reference (tests/test_triton2d.py). Imported on first use.
"""
from __future__ import annotations

import triton
import triton.language as tl
from torch import Tensor

__all__ = ["densify_stats_triton"]

BLOCK = 256  # splats a program


@triton.jit(do_not_specialize=["N"])  # N changes at each densification
def _accumulate(g, means, Rt, K, visible, radii, grad_sum, count, max_radii, N, C, half_w, half_h,
                ORTHO: tl.constexpr, BLOCK: tl.constexpr):
    n = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    m = n < N
    g0 = tl.load(g + 3 * n, mask=m, other=0.0)
    g1 = tl.load(g + 3 * n + 1, mask=m, other=0.0)
    g2 = tl.load(g + 3 * n + 2, mask=m, other=0.0)
    total = tl.zeros([BLOCK], dtype=tl.float32)
    seen = tl.zeros([BLOCK], dtype=tl.float32)
    rmax = tl.load(max_radii + n, mask=m, other=0.0)
    for c in range(C):
        vis = tl.load(visible + c * N + n, mask=m, other=0).to(tl.int1)
        gu = tl.load(Rt + 16 * c) * g0 + tl.load(Rt + 16 * c + 1) * g1 + tl.load(Rt + 16 * c + 2) * g2
        gv = tl.load(Rt + 16 * c + 4) * g0 + tl.load(Rt + 16 * c + 5) * g1 + tl.load(Rt + 16 * c + 6) * g2
        if ORTHO:
            z = g0 * 0.0 + 1.0
        else:
            z = (tl.load(Rt + 16 * c + 8) * tl.load(means + 3 * n, mask=m, other=0.0)
                 + tl.load(Rt + 16 * c + 9) * tl.load(means + 3 * n + 1, mask=m, other=0.0)
                 + tl.load(Rt + 16 * c + 10) * tl.load(means + 3 * n + 2, mask=m, other=0.0) + tl.load(Rt + 16 * c + 11))
        u = gu * (z / tl.load(K + 9 * c)) * half_w
        v = gv * (z / tl.load(K + 9 * c + 4)) * half_h
        total += tl.where(vis, tl.sqrt(u * u + v * v).to(tl.float32), 0.0)
        seen += tl.where(vis, 1.0, 0.0)
        rmax = tl.maximum(rmax, tl.where(vis, tl.load(radii + c * N + n, mask=m, other=0).to(tl.float32), 0.0))
    tl.store(grad_sum + n, tl.load(grad_sum + n, mask=m, other=0.0) + total, mask=m)
    tl.store(count + n, tl.load(count + n, mask=m, other=0.0) + seen, mask=m)
    tl.store(max_radii + n, rmax, mask=m)


def densify_stats_triton(stats, grad_means: Tensor, means: Tensor, cams, visible: Tensor, radii: Tensor) -> None:
    """:func:`.fused.densify_stats` on the Triton kernel: add one step to ``stats`` (float32 ``[N]`` accumulators on
    the gradient's device). visible ``[C, N]`` bool, radii ``[C, N]``."""
    dt = grad_means.dtype
    Rt, K = cams.derived(("densify_cameras", dt), lambda c: (c.world_to_cam.to(dt).reshape(-1, 16).contiguous(),
                                                             c.K.to(dt).reshape(-1, 9).contiguous()))
    N, C = grad_means.shape[0], len(cams)
    _accumulate[(triton.cdiv(N, BLOCK),)](
        grad_means.contiguous(), means.detach().to(dt).contiguous(), Rt, K, visible.contiguous(),
        radii.contiguous(), stats.grad_sum, stats.count, stats.max_radii, N, C, cams.width / 2, cams.height / 2,
        ORTHO=bool(cams.is_ortho), BLOCK=BLOCK, num_warps=4)
