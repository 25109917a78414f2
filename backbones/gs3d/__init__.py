"""3D Gaussian Splatting (``gs3d``): ``backbone.py`` holds the class, ``config.py`` its settings.

Its one registration is the entry point ``arcsem.backbones: gs3d = "arcsem.backbones.gs3d"`` naming this
package: ``CONFIG`` (the Config dataclass, no torch: the Hydra schema) and ``BACKBONE`` (the class) are read from
here (arcsem/registry.py). Names import lazily."""
from __future__ import annotations

from arcsem.lazy import lazy_getattr

__all__ = ["BACKBONE", "CONFIG", "GS3DBackbone", "GS3DConfig"]

_WHERE = {"GS3DBackbone": "backbone", "GS3DConfig": "config",
          "BACKBONE": "backbone:GS3DBackbone", "CONFIG": "config:GS3DConfig"}


__getattr__ = lazy_getattr(__name__, _WHERE)
