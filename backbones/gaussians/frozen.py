"""Renders of a frozen geometry as a linear map of the colours (stage 2 of the Gaussian backbones).

With the means, shapes and opacities fixed, every pixel's colour is ``sum_k w_k colour_k + T_final bg`` with weights
``w = alpha T`` that do not change: the compositing weights of a view are recorded once (the fused forward pass with
an emitter, ``cpp/weights.h``) and every later render of it is a sparse product, forward ``W x`` and backward
``W^T g``, instead of a compositing pass. Same rules, same weights: the renders equal the compositing ones up to the
order of the float sums.
"""
from __future__ import annotations

import warnings
from collections.abc import Callable

import torch
from torch import Tensor

__all__ = ["FrozenColours", "FrozenRender"]


class _Product(torch.autograd.Function):
    """``W colors[ids]`` ``[P, 3]`` of ``colors [M, 3]``; backward ``index_add(ids, W^T g)`` (``transpose``)."""

    @staticmethod
    def forward(ctx, colors: Tensor, W: Tensor, transpose, ids: Tensor) -> Tensor:
        ctx.save_for_backward(ids)
        ctx.rows, ctx.transpose = colors.shape[0], transpose
        return W @ colors.index_select(0, ids)

    @staticmethod
    def backward(ctx, g: Tensor):
        (ids,) = ctx.saved_tensors
        gc = g.new_zeros(ctx.rows, g.shape[1]).index_add_(0, ids, ctx.transpose(g.contiguous()))
        return gc, None, None, None


class FrozenColours:
    """``rgb [C, H, W, 3]`` of one recorded geometry as a function of the entries' colours ``[C*N, 3]``.

    Args:
        weights: a record (:func:`arcsem.backbones.gaussians.fused.composite_weights`, or the PyTorch path's
            :func:`arcsem.backbones.gaussians.raster.weights_record`): pixel-major CSR, ``t_final``, ``ids [P]`` (the
            entry ``c*N + n`` of each column), ``transpose`` (``W^T g``), ``nbytes``.
        shape: ``(C, H, W)``; background: ``[3]`` or None.
    """

    def __init__(self, weights, shape: tuple[int, int, int], background: Tensor | None):
        npix, npairs = shape[0] * shape[1] * shape[2], weights.ids.numel()
        with warnings.catch_warnings():  # PyTorch's notice that sparse CSR support is in beta
            warnings.simplefilter("ignore", UserWarning)
            self.W = torch.sparse_csr_tensor(weights.pix_ptr, weights.pix_pair, weights.pix_w, (npix, npairs))
        self.ids, self.transpose, self.shape, self.nbytes = weights.ids, weights.transpose, shape, weights.nbytes
        self.rest = None if background is None else weights.t_final[:, None] * background.to(weights.t_final)

    def __call__(self, colors: Tensor) -> Tensor:
        rgb = _Product.apply(colors, self.W, self.transpose, self.ids)
        if self.rest is not None:
            rgb = rgb + self.rest
        return rgb.view(*self.shape, 3)


class FrozenRender:
    """One view's render while the geometry stays as recorded: ``render()`` returns ``outputs`` (a render of that
    geometry; everything but ``rgb`` is kept as it is) with ``rgb`` from ``colours`` of ``colors_fn()``
    (``[C, N, 3]``, differentiable in the colour parameters). ``nbytes``: the memory the record holds."""

    def __init__(self, outputs: dict, colours: FrozenColours, colors_fn: Callable[[], Tensor]):
        self.const = {k: v.detach() if torch.is_tensor(v) else v for k, v in outputs.items() if k != "rgb"}
        self.colours, self.colors_fn, self.nbytes = colours, colors_fn, colours.nbytes

    def __call__(self) -> dict:
        return {**self.const, "rgb": self.colours(self.colors_fn().reshape(-1, 3))}
