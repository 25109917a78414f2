"""The SSIM map of :func:`arcsem.imageops.ssim_map` as one fused C++ kernel, forward and backward (``losses/cpp/ssim.cpp``).

Used by the ``dssim`` loss for CPU images when the target needs no gradient (the rendered image's gradient only):
the five blurs, the per-pixel formula and the gradient's three blurs in two passes over the image each, instead of
some thirty PyTorch ops and their autograd nodes. Same sums in the same order as the PyTorch function (float64:
equal to round-off; tests/test_fused_ssim.py).
"""
from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor

from arcsem import cext
from arcsem.imageops import gaussian_window

__all__ = ["EXTENSION", "fused_ssim_map", "usable"]

EXTENSION = cext.Extension(prefix="arcsem_ssim", sources=(Path(__file__).parent / "cpp" / "ssim.cpp",),
                           what="fused C++ SSIM", cflags=(*cext.NATIVE_CFLAGS, "-fno-trapping-math"))


def usable(impl: str, x: Tensor, y: Tensor) -> bool:
    """Whether ``impl`` (``auto|torch|cpp``) takes the fused path for these images (only ``x`` may need a gradient)."""
    if impl == "torch" or y.requires_grad or x.dtype not in (torch.float32, torch.float64):
        return False
    return cext.resolve_impl(impl, EXTENSION, x.device.type, key="dssim.impl") == "cpp"


class _SSIMMap(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x: Tensor, y: Tensor, window: Tensor) -> Tensor:
        smap, stats = cext.load(EXTENSION).ssim_forward(x, y, window)
        ctx.save_for_backward(x, y, window, stats)
        return smap

    @staticmethod
    def backward(ctx, g_map: Tensor):
        x, y, window, stats = ctx.saved_tensors
        return cext.load(EXTENSION).ssim_backward(g_map.contiguous(), x, y, window, stats), None, None


def fused_ssim_map(x: Tensor, y: Tensor, size: int = 11, sigma: float = 1.5) -> Tensor:
    """:func:`arcsem.imageops.ssim_map` on the fused kernel: ``[C, H, W, ch]`` x2 -> ``[C, H, W, ch]``.

    Differentiable in ``x`` only (``y`` is the target). Needs the extension (:func:`usable`)."""
    if x.shape != y.shape or x.ndim != 4:
        raise ValueError(f"ssim_map: expected two [C,H,W,ch] tensors, got {tuple(x.shape)} and {tuple(y.shape)}")
    g = gaussian_window(size, sigma, x.dtype)
    return _SSIMMap.apply(x.contiguous(), y.detach().to(x.dtype).contiguous(), g)
