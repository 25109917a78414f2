"""``gs3d`` settings: a plain dataclass, importable without torch (Hydra schema, :mod:`arcsem.schemas`)."""
from __future__ import annotations

from dataclasses import dataclass

from arcsem.registry import checked

from ..gaussians.config import GaussianConfig

__all__ = ["GS3DConfig"]


@dataclass
class GS3DConfig(GaussianConfig):
    """3DGS defaults (official repository)."""

    prune_opacity: float = checked(0.005, ge=0.0, le=1.0)  # official 3DGS min_opacity
