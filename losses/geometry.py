"""2DGS geometry regularisers as loss plugins (Huang et al. 2024; docs/method.md).

* ``normal_consistency``: ``1 - (sum w n) . (n_surface alpha)`` (2DGS), with ``n_surface`` the normal
  of the rendered depth unprojected to world points (central differences, cross product) and
  ``alpha`` detached. Default weight 0.05 from step 7000.
* ``distortion``: mean of the per-pixel distortion ``sum_i w_i (m_i^2 A + M2 - 2 m_i M1)``.
  Default weight 0 (1000 for object scans in the 2DGS paper's DTU runs) from step 3000.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from arcsem.losses.fused import fused_normal_consistency, kernel_path
from torch import Tensor

from arcsem.cameras import Cameras
from arcsem.plugins import LOSSES, Batch, Loss, RenderOutput
from arcsem.registry import checked

__all__ = ["Distortion", "NormalConsistency", "depth_normals"]


def depth_normals(depth: Tensor, cams: Cameras) -> Tensor:
    """World normals ``[C, H, W, 3]`` of depth maps ``[C, H, W, 1]`` (zero on the one-pixel border).

    Points come from :meth:`Cameras.unproject`; the normal is the cross product of the central
    differences along x and y, oriented towards the camera (OpenCV: y down, so ``dx x dy`` faces it).
    """
    pts = cams.unproject(depth)
    dx = pts[:, 1:-1, 2:] - pts[:, 1:-1, :-2]
    dy = pts[:, 2:, 1:-1] - pts[:, :-2, 1:-1]
    n = F.normalize(torch.cross(dy, dx, dim=-1), dim=-1)
    return F.pad(n.permute(0, 3, 1, 2), (1, 1, 1, 1)).permute(0, 2, 3, 1)


@LOSSES.register("normal_consistency")
class NormalConsistency(Loss):
    """``1 - n_rendered . n_surface``, weighted by the detached alpha, averaged over pixels with a depth normal.

    ``official: true`` is the 2DGS form ``1 - (sum w n) . (n_surface alpha)``: the rendered normal is
    not normalised, so splats along a ray that disagree (``|sum w n| < alpha``) or leave the pixel
    partly transparent are penalised too. ``official: false`` normalises the rendered normal first.
    ``depth``: the depth map whose normals are the target, ``expected`` or ``median`` (2DGS uses
    the median for bounded objects: its ``depth_ratio 1``).
    """

    requires = frozenset({"normal", "depth", "alpha"})

    @dataclass
    class Config:
        weight: float = 0.05
        start_step: int = 7000
        official: bool = True
        depth: str = "expected"
        # the official form's path (losses/fused.py kernel_path): auto (the fused C++ kernel on the CPU where it
        # builds, the Triton kernels on CUDA where the rasteriser's run), torch, cpp, triton
        impl: str = checked("auto", choices=("auto", "torch", "cpp", "triton"))

    def __init__(self, cfg: Config, **runtime):
        super().__init__(cfg)
        if cfg.depth not in ("expected", "median"):
            from arcsem.errors import ConfigError

            raise ConfigError(f"losses.normal_consistency.depth must be 'expected' or 'median', got '{cfg.depth}'")
        self.requires = self.requires | ({"median_depth"} if cfg.depth == "median" else set())

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        depth = out["median_depth"] if self.cfg.depth == "median" else out["depth"]
        path = kernel_path(self.cfg.impl, "normal_consistency.impl", depth, out["normal"]) if self.cfg.official \
            else "torch"
        if path == "triton":
            from arcsem.losses.triton_normals import (
                triton_normal_consistency,  # imports triton: on first use only
            )

            return triton_normal_consistency(depth, out["normal"], out["alpha"], batch.cameras)
        if path == "cpp":
            return fused_normal_consistency(depth, out["normal"], out["alpha"], batch.cameras)
        surf = depth_normals(depth, batch.cameras)
        alpha = out["alpha"].detach()
        if self.cfg.official:
            err = 1.0 - (out["normal"] * surf).sum(-1, keepdim=True) * alpha
        else:
            err = (1.0 - (F.normalize(out["normal"], dim=-1) * surf).sum(-1, keepdim=True)) * alpha
        valid = (surf.abs().sum(-1, keepdim=True) > 0).to(err.dtype)
        return (err * valid).sum() / valid.sum().clamp_min(1.0)


@LOSSES.register("distortion")
class Distortion(Loss):
    requires = frozenset({"distortion"})

    @dataclass
    class Config:
        weight: float = 0.0
        start_step: int = 3000

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> Tensor:
        return out["distortion"].mean()
