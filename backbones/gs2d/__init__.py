"""2D Gaussian Splatting (``gs2d``): ``backbone.py`` registers it (entry point), ``config.py`` holds its settings
(no torch: the Hydra schema). Names import lazily."""
from __future__ import annotations

from arcsem.lazy import lazy_getattr

__all__ = ["GS2DBackbone", "GS2DConfig"]

_WHERE = {"GS2DBackbone": "backbone", "GS2DConfig": "config"}


__getattr__ = lazy_getattr(__name__, _WHERE)
