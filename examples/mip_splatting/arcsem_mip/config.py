"""``gs3d_mip`` settings: 3DGS's, plus the 3-D filter's (a light module: the Hydra schema, no torch)."""
from __future__ import annotations

from dataclasses import dataclass

from arcsem.backbones.gs3d.config import GS3DConfig

from arcsem.registry import checked

__all__ = ["MipConfig"]


@dataclass
class MipConfig(GS3DConfig):
    filter_variance: float = checked(0.2, gt=0.0)  # s: the low-pass filter's variance in pixels^2 (Mip-Splatting 0.2)
    filter_every: int = checked(100, ge=1)  # recompute the filter every this many stage-1 steps (Mip-Splatting 100)
