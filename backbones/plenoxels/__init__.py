"""Plenoxels backbone (``plenoxels``): a sparse SH voxel grid, ray marching, coarse-to-fine (svox2). ``backbone.py`` registers it (entry point ``arcsem.backbones.plenoxels.backbone``), ``config.py``
holds its settings, importable without torch (the Hydra schema). Names below import lazily."""
from __future__ import annotations

import importlib

__all__ = ["Plenoxels", "PlenoxelsConfig"]

_WHERE = {"Plenoxels": "backbone", "PlenoxelsConfig": "config"}


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
