"""The ``gs3d`` backbone: 3D Gaussian Splatting (Kerbl et al. 2023) on the shared Gaussian code."""
from __future__ import annotations

from typing import ClassVar

from arcsem.plugins import RenderOutput

from ..gaussians.base import GaussianBackbone
from .config import GS3DConfig

__all__ = ["GS3DBackbone"]


class GS3DBackbone(GaussianBackbone):
    """Anisotropic 3-D Gaussians (EWA splatting); renders colour, alpha and expected depth."""

    provides: ClassVar[frozenset[str]] = frozenset({"rgb", "alpha", "depth"})
    num_scales: ClassVar[int] = 3
    random_rotations: ClassVar[bool] = False  # official 3DGS starts from identity rotations

    Config = GS3DConfig

    def _rasterize(self, means, quats, scales, opacities, colors, cams, **kw) -> RenderOutput:
        if kw.get("impl") == "gsplat":
            from ..gaussians.gsplat_bridge import render_gsplat_3dgs as render_3dgs
        else:
            from .render import render_3dgs  # the rasteriser module (imported when first used)

        return render_3dgs(means, quats, scales, opacities, colors, cams, **kw)
