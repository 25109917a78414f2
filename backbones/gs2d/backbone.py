"""The ``gs2d`` backbone: 2D Gaussian Splatting (Huang et al. 2024) on the shared Gaussian code."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from arcsem.errors import ConfigError
from arcsem.plugins import BACKBONES, RenderOutput
from arcsem.registry import checked

from ..gaussians.base import GaussianBackbone, GaussianConfig

__all__ = ["GS2DBackbone"]


@BACKBONES.register("gs2d")
class GS2DBackbone(GaussianBackbone):
    """Surfels with two scales; renders colour, alpha, expected/median depth, normals and distortion."""

    provides: ClassVar[frozenset[str]] = frozenset(
        {"rgb", "alpha", "depth", "median_depth", "normal", "distortion"}
    )
    num_scales: ClassVar[int] = 2
    random_rotations: ClassVar[bool] = True  # official 2DGS starts from random rotations

    @dataclass
    class Config(GaussianConfig):
        """2DGS defaults (official repository)."""

        prune_opacity: float = checked(0.05, ge=0.0, le=1.0)  # official 2DGS opacity_cull
        # normalised depth of the distortion loss: "linear" m = z / extent (any camera distance,
        # orthographic too) or "ndc", the official mapping, which is ~flat at SEM camera distances
        distortion_depth: str = checked("linear", choices=("linear", "ndc"))
        # sigma (pixels) of the screen-space low-pass filter: a surfel is drawn at least as a 2-D Gaussian of
        # this sigma around its projected centre (official 1/sqrt(2) = 0.707). It widens every silhouette by
        # about a sigma, and a fit to sharp silhouettes pays for that by shrinking the surface: at low
        # resolution a pixel is ~1 % of the specimen (benchmarks/results/README.md, "Surfels behind the surface")
        lowpass_sigma: float = checked(0.7071067811865476, ge=0.0)

    def __init__(self, cfg: Config, scene=None, act=None, **runtime):
        super().__init__(cfg, scene=scene, act=act, **runtime)
        self._dist_depth()  # a bad mode fails at construction, not at the first render
        if not self.cfg.lowpass_sigma > 0:
            raise ConfigError(f"backbone.lowpass_sigma must be > 0 (pixels), got {self.cfg.lowpass_sigma}")

    def _dist_depth(self) -> tuple[float, float, float]:
        from .render import distortion_depth

        try:
            return distortion_depth(self.cfg.distortion_depth, float(self.extent))
        except ValueError as e:
            raise ConfigError(f"backbone.{e}") from None

    def _rasterize(self, means, quats, scales, opacities, colors, cams, **kw) -> RenderOutput:
        from .render import render_2dgs  # the rasteriser module (imported when first used)

        return render_2dgs(means, quats, scales, opacities, colors, cams, dist_depth=self._dist_depth(),
                           lowpass_sigma=float(self.cfg.lowpass_sigma), **kw)
