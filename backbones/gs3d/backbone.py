"""The ``gs3d`` backbone: 3D Gaussian Splatting (Kerbl et al. 2023) on the shared Gaussian code."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from arcsem.plugins import BACKBONES, RenderOutput
from arcsem.registry import checked

from ..gaussians.base import GaussianBackbone, GaussianConfig

__all__ = ["GS3DBackbone"]


@BACKBONES.register("gs3d")
class GS3DBackbone(GaussianBackbone):
    """Anisotropic 3-D Gaussians (EWA splatting); renders colour, alpha and expected depth."""

    provides: ClassVar[frozenset[str]] = frozenset({"rgb", "alpha", "depth"})
    num_scales: ClassVar[int] = 3
    random_rotations: ClassVar[bool] = False  # official 3DGS starts from identity rotations

    @dataclass
    class Config(GaussianConfig):
        """3DGS defaults (official repository)."""

        prune_opacity: float = checked(0.005, ge=0.0, le=1.0)  # official 3DGS min_opacity

    def _rasterize(self, means, quats, scales, opacities, colors, cams, **kw) -> RenderOutput:
        from .render import render_3dgs  # the rasteriser module (imported when first used)

        return render_3dgs(means, quats, scales, opacities, colors, cams, **kw)
