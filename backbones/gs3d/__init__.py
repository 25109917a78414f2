"""3D Gaussian Splatting (``gs3d``): ``backbone.py`` registers it (entry point), ``config.py`` holds its settings
(no torch: the Hydra schema). Names import lazily."""
from __future__ import annotations

from arcsem.lazy import lazy_getattr

__all__ = ["GS3DBackbone", "GS3DConfig"]

_WHERE = {"GS3DBackbone": "backbone", "GS3DConfig": "config"}


__getattr__ = lazy_getattr(__name__, _WHERE)
