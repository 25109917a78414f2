"""``colorize``: the stage-2 preset (its dataclass lives with the other schemas in :mod:`arcsem.configs`)."""
from __future__ import annotations

from ..configs import DEFAULT_LOSSES, ColorizeConfig

__all__ = ["DEFAULT_LOSSES", "ColorizeConfig"]
