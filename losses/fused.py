"""Fused C++ kernels of two losses, forward and backward (``losses/cpp/``): the SSIM map of the ``dssim`` loss
(:func:`arcsem.imageops.ssim_map`) and the official 2DGS ``normal_consistency`` loss (:mod:`arcsem.losses.geometry`).

Each replaces some thirty PyTorch ops and their autograd nodes by two passes over the image forward and two
backward; the PyTorch functions stay the reference (tests/test_fused_losses.py: float64 equal to round-off). The
losses take these paths for CPU tensors when the extension builds (their ``impl: auto|torch|cpp``, as the
rasterisers' ``rasterizer``); the SSIM only where the target needs no gradient.
"""
from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor

from arcsem import cext
from arcsem.imageops import gaussian_window
from arcsem.tritonsupport import auto_on

__all__ = ["EXTENSION", "fused_normal_consistency", "fused_ssim_map", "kernel_path", "usable"]

CPP_DIR = Path(__file__).parent / "cpp"
EXTENSION = cext.Extension(prefix="arcsem_losses", sources=tuple(CPP_DIR / n for n in ("ssim.cpp", "normals.cpp",
                                                                                          "module.cpp")),
                           what="fused C++ losses", keys=("dssim.impl", "normal_consistency.impl"),
                           cflags=(*cext.NATIVE_CFLAGS, "-fno-trapping-math"))


def usable(impl: str, key: str, *inputs: Tensor) -> bool:
    """Whether ``impl`` (``auto|torch|cpp``, the config value ``key``) takes the fused path for these float32/64 CPU
    tensors (``ValueError``-free: any other dtype or device takes the PyTorch path)."""
    if impl == "torch" or any(t.dtype not in (torch.float32, torch.float64) for t in inputs):
        return False
    return cext.resolve_impl(impl, EXTENSION, inputs[0].device.type, key=key) == "cpp"


def kernel_path(impl: str, key: str, *inputs: Tensor) -> str:
    """The path a fused loss takes for ``impl`` (``auto|torch|cpp|triton``, the config value ``key``) and its
    ``inputs``: ``cpp`` (this module's kernels, CPU tensors), ``triton`` (:mod:`arcsem.losses.triton_ssim`,
    :mod:`arcsem.losses.triton_normals`; CUDA, ``auto``'s choice where the rasteriser's Triton kernels run) or
    ``torch`` (any other dtype or device)."""
    if any(t.dtype not in (torch.float32, torch.float64) for t in inputs):
        return "torch"
    if impl == "triton" or (impl == "auto" and auto_on(inputs[0].device)):
        return "triton"
    return "cpp" if usable(impl, key, *inputs) else "torch"


def _ext():
    return cext.load(EXTENSION)


class _SSIMMap(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x: Tensor, y: Tensor, window: Tensor) -> Tensor:
        smap, stats = _ext().ssim_forward(x, y, window)
        ctx.save_for_backward(x, y, window, stats)
        return smap

    @staticmethod
    def backward(ctx, g_map: Tensor):
        x, y, window, stats = ctx.saved_tensors
        return _ext().ssim_backward(g_map.contiguous(), x, y, window, stats), None, None


def fused_ssim_map(x: Tensor, y: Tensor, size: int = 11, sigma: float = 1.5) -> Tensor:
    """:func:`arcsem.imageops.ssim_map` on the fused kernel: ``[C, H, W, ch]`` x2 -> ``[C, H, W, ch]``.

    Differentiable in ``x`` only (``y`` is the target)."""
    if x.shape != y.shape or x.ndim != 4:
        raise ValueError(f"ssim_map: expected two [C,H,W,ch] tensors, got {tuple(x.shape)} and {tuple(y.shape)}")
    g = gaussian_window(size, sigma, x.dtype)
    return _SSIMMap.apply(x.contiguous(), y.detach().to(x.dtype).contiguous(), g)


class _NormalConsistency(torch.autograd.Function):
    @staticmethod
    def forward(ctx, depth: Tensor, normal: Tensor, origins: Tensor, dirs: Tensor, alpha: Tensor) -> Tensor:
        loss, count = _ext().normal_consistency_forward(depth, origins, dirs, normal, alpha)
        ctx.save_for_backward(depth, normal, origins, dirs, alpha)
        ctx.count = float(count)
        return loss

    @staticmethod
    def backward(ctx, g: Tensor):
        depth, normal, origins, dirs, alpha = ctx.saved_tensors
        g_depth, g_normal = _ext().normal_consistency_backward(float(g), ctx.count, depth, origins, dirs, normal, alpha)
        return g_depth, g_normal, None, None, None


def _affine_rays(cams, dtype: torch.dtype) -> tuple[Tensor, Tensor]:
    """Ray origins and directions of ``cams`` as affine functions of the pixel centre ``(u, v)``: ``[C, 3, 3]`` rows
    ``(r_u, r_v, r_1)`` with ``r(u, v) = u r_u + v r_v + r_1``, from :meth:`Cameras.rays` at three points (float64).
    Both camera models are affine in ``(u, v)`` (pinhole: directions; orthographic: origins)."""
    return cams.derived(("affine_rays", dtype), lambda c: _affine_rays_of(c, dtype))  # kept: the poses' alone


def _affine_rays_of(cams, dtype: torch.dtype) -> tuple[Tensor, Tensor]:
    assert cams.model in ("pinhole", "orthographic"), cams.model
    c64 = cams.to(dtype=torch.float64)
    uv = torch.tensor([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]], dtype=torch.float64, device=c64.K.device)
    rays = c64.rays(uv.expand(len(cams), 3, 2))  # [C, 3 points, 3] each
    out = []
    for r in rays:
        r1 = r[:, 2]
        out.append(torch.stack([r[:, 0] - r1, r[:, 1] - r1, r1], 1).to(dtype).contiguous())
    return out[0], out[1]


def fused_normal_consistency(depth: Tensor, normal: Tensor, alpha: Tensor, cams) -> Tensor:
    """The official 2DGS normal consistency of :class:`arcsem.losses.geometry.NormalConsistency` (a scalar).

    Args:
        depth: ``[C, H, W, 1]`` the depth whose normals are the target; normal: ``[C, H, W, 3]`` rendered;
        alpha: ``[C, H, W, 1]`` (no gradient); cams: the :class:`arcsem.cameras.Cameras` of the views.
    """
    origins, dirs = _affine_rays(cams, depth.dtype)
    return _NormalConsistency.apply(depth[..., 0].contiguous(), normal.contiguous(), origins, dirs,
                                    alpha.detach()[..., 0].to(depth.dtype).contiguous())


if __name__ == "__main__":  # `python -m arcsem.losses.fused`: build now (make setup does this)
    import time

    t0 = time.perf_counter()
    ok = _ext() is not None
    print(f"fused C++ losses: {'ready' if ok else 'unavailable, PyTorch path will be used'} "
          f"({time.perf_counter() - t0:.1f} s)")
