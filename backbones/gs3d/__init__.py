"""3D Gaussian Splatting backbone (``gs3d``): ``backbone.py`` registers it (entry point ``arcsem.backbones.gs3d.backbone``), ``config.py``
holds its settings, importable without torch (the Hydra schema). Names below import lazily."""
from __future__ import annotations

import importlib

__all__ = ["GS3DBackbone", "GS3DConfig"]

_WHERE = {"GS3DBackbone": "backbone", "GS3DConfig": "config"}


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
