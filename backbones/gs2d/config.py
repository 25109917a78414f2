"""``gs2d`` settings: a plain dataclass, importable without torch (Hydra schema, :mod:`arcsem.schemas`)."""
from __future__ import annotations

from dataclasses import dataclass

from arcsem.registry import checked

from ..gaussians.config import LOWPASS_SIGMA, GaussianConfig

__all__ = ["GSPLAT_LOWPASS_SIGMA", "GS2DConfig", "lowpass_for"]

# gsplat's 2DGS kernels compile their screen-space filter in (FILTER_INV_SQUARE = 2: sigma = 1/sqrt(2) px, the
# official value); no argument changes it
GSPLAT_LOWPASS_SIGMA = LOWPASS_SIGMA


def lowpass_for(rasterizer: str, ours: float) -> float:
    """A preset's ``lowpass_sigma`` for ``rasterizer``: ``ours`` for arcsem's rasterisers, gsplat's fixed sigma for
    ``gsplat`` (the resolver ``${gs2d_lowpass:${backbone.rasterizer},<ours>}`` of conf/tuning/quick_gs2d.yaml, so the
    run's config.yaml records the filter the run drew with)."""
    return GSPLAT_LOWPASS_SIGMA if rasterizer == "gsplat" else float(ours)


@dataclass
class GS2DConfig(GaussianConfig):
    """2DGS defaults (official repository)."""

    prune_opacity: float = checked(0.05, ge=0.0, le=1.0)  # official 2DGS opacity_cull
    # normalised depth of the distortion loss: "linear" m = z / extent (any camera distance,
    # orthographic too) or "ndc", the official mapping, which is ~flat at SEM camera distances
    distortion_depth: str = checked("linear", choices=("linear", "ndc"))
    # sigma (pixels) of the screen-space low-pass filter: a surfel is drawn at least as a 2-D Gaussian of
    # this sigma around its projected centre (official 1/sqrt(2) = 0.707). It widens every silhouette by
    # about a sigma, and a fit to sharp silhouettes pays for that by shrinking the surface: at low
    # resolution a pixel is ~1 % of the specimen (benchmarks/results/README.md, "Surfels behind the surface")
    # (> 0: the kernels divide by sigma^2)
    lowpass_sigma: float = checked(LOWPASS_SIGMA, gt=0.0)
