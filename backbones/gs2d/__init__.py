"""2D Gaussian Splatting backbone (``gs2d``): ``backbone.py`` registers it (entry point ``arcsem.backbones.gs2d.backbone``), ``config.py``
holds its settings, importable without torch (the Hydra schema). Names below import lazily."""
from __future__ import annotations

import importlib

__all__ = ["GS2DBackbone", "GS2DConfig"]

_WHERE = {"GS2DBackbone": "backbone", "GS2DConfig": "config"}


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
