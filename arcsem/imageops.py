"""Small differentiable image operations shared by the colourisation guidance and its losses.

Images are ``[C, H, W, 3]`` (channels last, as renders are)."""
from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor

__all__ = ["downscale", "patch_means"]


def downscale(images: Tensor, factor: int) -> Tensor:
    """``[C, H, W, 3]`` -> ``[C, H//f, W//f, 3]`` (antialiased bilinear, differentiable); f=1: unchanged."""
    if factor == 1:
        return images
    H, W = images.shape[1:3]
    x = F.interpolate(images.permute(0, 3, 1, 2), size=(H // factor, W // factor), mode="bilinear",
                      antialias=True, align_corners=False)
    return x.permute(0, 2, 3, 1)


def patch_means(images: Tensor, cell: int) -> Tensor:
    """Mean colour of ``cell x cell`` patches: ``[C, H, W, 3]`` -> ``[C, H//cell, W//cell, 3]``."""
    return F.avg_pool2d(images.permute(0, 3, 1, 2), cell).permute(0, 2, 3, 1)
