"""2D Gaussian Splatting (``gs2d``): ``backbone.py`` holds the class, ``config.py`` its settings.

Its one registration is the entry point ``arcsem.backbones: gs2d = "arcsem.backbones.gs2d"`` naming this
package: ``CONFIG`` (the Config dataclass, no torch: the Hydra schema) and ``BACKBONE`` (the class) are read from
here (arcsem/registry.py). Names import lazily."""
from __future__ import annotations

from arcsem.lazy import lazy_getattr

__all__ = ["BACKBONE", "CONFIG", "GS2DBackbone", "GS2DConfig"]

_WHERE = {"GS2DBackbone": "backbone", "GS2DConfig": "config",
          "BACKBONE": "backbone:GS2DBackbone", "CONFIG": "config:GS2DConfig"}


__getattr__ = lazy_getattr(__name__, _WHERE)
