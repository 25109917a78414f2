"""``gs3d_mip``: arcsem's 3DGS whose Gaussians are drawn through Mip-Splatting's 3-D smoothing filter.

Only the public contract is used: the in-tree ``GS3DBackbone`` class, the Gaussian hook ``splat_params``
(what the rasteriser draws) and the declared ``Backbone`` hooks (``post_backward``, ``state_dict``). The filter
(a buffer ``[N]``, saved with the checkpoint) is recomputed from the training cameras every ``filter_every``
stage-1 steps and whenever the number of Gaussians changed (densification). Mip-Splatting's 2-D mip filter,
which replaces the screen-space dilation, is not part of this plugin.
"""
from __future__ import annotations

from typing import Any

import torch
from arcsem.backbones.gs3d import GS3DBackbone
from torch import Tensor

from .config import MipConfig
from .filter3d import apply_filter, filter_variance

__all__ = ["MipGS3D"]


class MipGS3D(GS3DBackbone):
    """3DGS with a 3-D smoothing filter per Gaussian (see the module docstring)."""

    Config = MipConfig

    def __init__(self, cfg: MipConfig, scene: Any = None, **runtime: Any):
        super().__init__(cfg, scene, **runtime)
        self.__dict__["_cams"] = scene.train.cameras if scene is not None else None  # not a module or buffer
        self.register_buffer("filter3d", torch.zeros(len(self.model)))
        self.update_filter()

    def update_filter(self) -> None:
        """Recompute the filter variances from the training cameras (none known: no filter)."""
        with torch.no_grad():
            m = self.model
            if self._cams is None:
                self.filter3d = torch.zeros(len(m), dtype=m.means.dtype, device=m.means.device)
            else:
                self.filter3d = filter_variance(m.means, self._cams, self.cfg.filter_variance)

    def splat_params(self) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        means, quats, scales, opacities = super().splat_params()
        if self.filter3d.shape[0] != means.shape[0]:  # the model changed since the last update
            self.update_filter()
        scales, opacities = apply_filter(scales, opacities, self.filter3d.to(scales.dtype))
        return means, quats, scales, opacities

    def post_backward(self, step: int, out, optimizers) -> None:
        n = len(self.model)
        super().post_backward(step, out, optimizers)
        if self.stage == "geometry" and (len(self.model) != n or (step + 1) % self.cfg.filter_every == 0):
            self.update_filter()

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        """Checkpoints hold any number of Gaussians: the filter buffer takes the saved size first."""
        if "filter3d" in state_dict:
            self.filter3d = torch.empty_like(state_dict["filter3d"])
        return super().load_state_dict(state_dict, strict=strict, assign=assign)
