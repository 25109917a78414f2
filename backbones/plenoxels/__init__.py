"""Plenoxels (``plenoxels``), a sparse SH voxel grid (svox2): ``backbone.py`` registers it (entry point),
``config.py`` holds its settings (no torch: the Hydra schema). Names import lazily."""
from __future__ import annotations

from arcsem.lazy import lazy_getattr

__all__ = ["Plenoxels", "PlenoxelsConfig"]

_WHERE = {"Plenoxels": "backbone", "PlenoxelsConfig": "config"}


__getattr__ = lazy_getattr(__name__, _WHERE)
