"""ACT: a per-image affine colour transform (Darmon et al. 2024, as used by ArCSEM).

Each training image ``i`` has a transform ``L' = W_i * L + b_i`` applied to every primitive's (or
sample's) decoded colour BEFORE compositing, then clamped to ``[0, 1]``; a pixel therefore gets
``W C + b alpha``. It absorbs the per-image brightness/contrast drift of SEM images so the scene
itself stays consistent. Novel views (``image_id == -1``) use the mean ``W`` and ``b`` over training
images.

Two parameterisations (``conf/act/*.yaml``):

* ``mode="rgb"``   — 3 weights + 3 biases per image: the paper's text (lr 1e-4, ``act=paper``);
* ``mode="scalar"`` — 1 scale + 1 shift per image broadcast over RGB: the authors' released code
  (lr 1e-3, ``act=code``).

Initialisation: identity plus ``N(0, init_noise)`` noise on both ``W`` and ``b``.

Faster or closed-form ACTs, priors and a projection of the transforms' smooth part were tried and lost to
the paper's ACT on the built-in scene (benchmarks/results/README.md, "What ACT learns"); they are not here.
ACT is independent of any backbone: Gaussians call :meth:`ACT.apply` on ``[C, N, 3]`` colours,
ray backbones on ``[R, S, 3]`` per-sample colours with ``[R]`` image ids.
"""
from __future__ import annotations

from typing import Literal

import torch
from torch import Tensor, nn

from .configs import ACT_MODES

__all__ = ["ACT", "ACT_MODES"]


class ACT(nn.Module):
    """Per-image affine colour transforms.

    Attributes:
        weight: ``[num_images, k]`` with ``k = 3`` (rgb) or ``1`` (scalar).
        bias: ``[num_images, k]``.
    """

    def __init__(self, num_images: int, mode: Literal["rgb", "scalar"] = "rgb", init_noise: float = 1e-3):
        super().__init__()
        if mode not in ACT_MODES:
            raise ValueError(f"ACT mode must be one of {ACT_MODES}, got '{mode}'")
        if num_images < 1:
            raise ValueError(f"ACT needs at least one training image, got {num_images}")
        k = 3 if mode == "rgb" else 1
        self.mode = mode
        self.weight = nn.Parameter(torch.ones(num_images, k) + init_noise * torch.randn(num_images, k))
        self.bias = nn.Parameter(init_noise * torch.randn(num_images, k))

    @property
    def num_images(self) -> int:
        return self.weight.shape[0]

    def transforms(self, image_ids: Tensor) -> tuple[Tensor, Tensor]:
        """``W, b`` of shape ``[*image_ids.shape, k]``; id ``-1`` gives the mean over training images."""
        ids = image_ids.long().to(self.weight.device)
        # checked where the ids are host tensors; on a GPU the check would wait for the device every step (a
        # training step's ids are its split's, made by the dataset reader)
        if ids.device.type == "cpu" and ((ids >= self.num_images).any() or (ids < -1).any()):
            raise IndexError(f"ACT: image ids {ids.unique().tolist()} outside -1..{self.num_images - 1}")
        novel = (ids < 0)[..., None]
        safe = ids.clamp_min(0)
        W = torch.where(novel, self.weight.mean(0), self.weight[safe])
        b = torch.where(novel, self.bias.mean(0), self.bias[safe])
        return W, b

    def apply(self, colors: Tensor, image_ids: Tensor) -> Tensor:
        """Transform colours of the images ``image_ids``.

        Args:
            colors: ``[*B, ..., 3]`` decoded colours, e.g. ``[C, N, 3]`` (one row of primitives per
                camera) or ``[R, S, 3]`` (samples of a ray batch).
            image_ids: ``[*B]`` long, training-image index per leading entry; ``-1`` = novel view.
        Returns:
            ``clamp(W * colors + b, 0, 1)`` with the shape of ``colors``.
        """
        ids = torch.as_tensor(image_ids)
        nb = ids.ndim
        if tuple(colors.shape[:nb]) != tuple(ids.shape) or colors.shape[-1] != 3:
            raise ValueError(f"ACT.apply: colors {tuple(colors.shape)} do not start with image_ids {tuple(ids.shape)}"
                             " or do not end with 3 channels")
        W, b = self.transforms(ids)
        extra = colors.ndim - nb - 1
        shape = (*ids.shape, *([1] * extra), W.shape[-1])
        out = W.reshape(shape).to(colors.dtype) * colors + b.reshape(shape).to(colors.dtype)
        return out.clamp(0.0, 1.0)

    forward = apply

    def extra_repr(self) -> str:
        return f"num_images={self.num_images}, mode={self.mode}"
