"""Plenoxels (``plenoxels``), a sparse SH voxel grid (svox2): ``backbone.py`` holds the class, ``config.py`` its
settings.

Its one registration is the entry point ``arcsem.backbones: plenoxels = "arcsem.backbones.plenoxels"`` naming
this package: ``CONFIG`` (the Config dataclass, no torch: the Hydra schema) and ``BACKBONE`` (the class) are read
from here (arcsem/registry.py). Names import lazily."""
from __future__ import annotations

from arcsem.lazy import lazy_getattr

__all__ = ["BACKBONE", "CONFIG", "Plenoxels", "PlenoxelsConfig"]

_WHERE = {"Plenoxels": "backbone", "PlenoxelsConfig": "config",
          "BACKBONE": "backbone:Plenoxels", "CONFIG": "config:PlenoxelsConfig"}


__getattr__ = lazy_getattr(__name__, _WHERE)
