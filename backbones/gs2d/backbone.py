"""The ``gs2d`` backbone: 2D Gaussian Splatting (Huang et al. 2024) on the shared Gaussian code."""
from __future__ import annotations

from typing import ClassVar

from arcsem.errors import ConfigError
from arcsem.plugins import RenderOutput

from ..gaussians.base import GaussianBackbone
from .config import GS2DConfig

__all__ = ["GS2DBackbone"]


class GS2DBackbone(GaussianBackbone):
    """Surfels with two scales; renders colour, alpha, expected/median depth, normals and distortion."""

    provides: ClassVar[frozenset[str]] = frozenset(
        {"rgb", "alpha", "depth", "median_depth", "normal", "distortion"}
    )
    num_scales: ClassVar[int] = 2
    random_rotations: ClassVar[bool] = True  # official 2DGS starts from random rotations

    Config = GS2DConfig

    def __init__(self, cfg: Config, scene=None, act=None, **runtime):
        super().__init__(cfg, scene=scene, act=act, **runtime)
        self._dist_depth()  # a bad mode fails at construction, not at the first render

    @classmethod
    def check_scene(cls, cfg: GS2DConfig, scene) -> None:
        """``rasterizer=gsplat``: pinhole cameras, gsplat's fixed low-pass sigma, tiles of at most 16 px."""
        super().check_scene(cfg, scene)
        if cfg.rasterizer == "gsplat":
            from ..gaussians.gsplat_bridge import require_2dgs_tile, require_lowpass

            require_lowpass(float(cfg.lowpass_sigma))
            require_2dgs_tile(int(cfg.tile))

    def _dist_depth(self) -> tuple[float, float, float]:
        from .render import distortion_depth

        try:
            return distortion_depth(self.cfg.distortion_depth, self.extent_value)
        except ValueError as e:
            raise ConfigError(f"backbone.{e}") from None

    def _rasterize(self, means, quats, scales, opacities, colors, cams, **kw) -> RenderOutput:
        if kw.get("impl") == "gsplat":
            from ..gaussians.gsplat_bridge import render_gsplat_2dgs as render_2dgs
        else:
            from .render import render_2dgs  # the rasteriser module (imported when first used)

        return render_2dgs(means, quats, scales, opacities, colors, cams, dist_depth=self._dist_depth(),
                           lowpass_sigma=float(self.cfg.lowpass_sigma), **kw)
