"""Photometric loss plugins: ``l1``, ``l2`` and ``dssim`` (1 - SSIM, 11x11 Gaussian window, sigma 1.5).

The stage-1 loss of the Gaussian backbones is ``0.8 * l1 + 0.2 * dssim`` (weights set by the
trainer preset); Plenoxels uses ``l2``. ``l1``/``l2`` work on image batches ``[C,H,W,3]`` and on
ray batches ``[R,3]``; ``dssim`` needs whole images. With ``masked: true`` only pixels inside the
specimen mask count (falls back to every pixel when the batch has no mask).

:func:`arcsem.imageops.ssim_map` is the pure, differentiable SSIM used by the ``dssim`` loss and by the
SSIM metric (Wang et al. 2004, constants ``C1 = 0.01^2``, ``C2 = 0.03^2`` for data range 1, zero padding as
in 3DGS/2DGS); the loss computes the same map with one fused C++ kernel on the CPU and four Triton kernels on CUDA
(``impl``, :mod:`arcsem.losses.fused`, :mod:`arcsem.losses.triton_ssim`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from arcsem.losses.fused import fused_ssim_map, kernel_path
from torch import Tensor

from arcsem.imageops import gaussian_window, ssim_map
from arcsem.plugins import LOSSES, Batch, Loss, RenderOutput
from arcsem.registry import checked

__all__ = ["DSSIM", "L1", "L2", "gaussian_window", "masked_mean", "ssim_map"]

def masked_mean(x: Tensor, mask: Tensor | None) -> Tensor:
    """Mean of ``x [..., ch]`` over entries where ``mask [..., 1]`` is set (all entries if None)."""
    if mask is None:
        return x.mean()
    m = mask.to(x.dtype).expand_as(x)
    return (x * m).sum() / m.sum().clamp_min(1.0)


class _Pixelwise(Loss):
    requires: ClassVar[frozenset[str]] = frozenset({"rgb"})
    batch_modes: ClassVar[frozenset[str]] = frozenset({"image", "rays"})

    @dataclass
    class Config:
        weight: float = 1.0
        start_step: int = 0
        masked: bool = False  # count only pixels inside the specimen mask (if the batch has one)

    def error(self, diff: Tensor) -> Tensor:
        raise NotImplementedError

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        mask = batch.masks if self.cfg.masked else None
        return masked_mean(self.error(out["rgb"] - batch.images), mask)


@LOSSES.register("l1")
class L1(_Pixelwise):
    """Mean absolute colour error."""

    def error(self, diff: Tensor) -> Tensor:
        return diff.abs()


@LOSSES.register("l2")
class L2(_Pixelwise):
    """Mean squared colour error (the Plenoxels loss)."""

    def error(self, diff: Tensor) -> Tensor:
        return diff * diff


@LOSSES.register("dssim")
class DSSIM(Loss):
    """``1 - SSIM`` over whole images (11x11 Gaussian window, sigma 1.5)."""

    requires: ClassVar[frozenset[str]] = frozenset({"rgb"})
    batch_modes: ClassVar[frozenset[str]] = frozenset({"image"})

    @dataclass
    class Config:
        weight: float = 1.0
        start_step: int = 0
        window: int = 11  # Gaussian window size (pixels)
        sigma: float = 1.5  # Gaussian window standard deviation (pixels)
        masked: bool = False  # average the SSIM map inside the specimen mask only
        # the SSIM map's path (losses/fused.py kernel_path): auto (the fused C++ kernel on the CPU where it builds,
        # the Triton kernels on CUDA where the rasteriser's run), torch, cpp, triton
        impl: str = checked("auto", choices=("auto", "torch", "cpp", "triton"))

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        if batch.images.ndim != 4:
            raise ValueError("dssim needs image batches [C,H,W,3]; ray batches cannot compute SSIM")
        # the fused paths take a target without gradient
        path = "torch" if batch.images.requires_grad else kernel_path(self.cfg.impl, "dssim.impl", out["rgb"],
                                                                      batch.images)
        if path == "triton":
            from arcsem.losses.triton_ssim import triton_ssim_map as fn  # imports triton: on first use only
        else:
            fn = fused_ssim_map if path == "cpp" else ssim_map
        s = fn(out["rgb"], batch.images, self.cfg.window, self.cfg.sigma)
        return 1.0 - masked_mean(s, batch.masks if self.cfg.masked else None)
