"""Ground-truth colour of the built-in scenes: from a surface's albedo to a coloured pixel.

Each specimen's albedo lives beside its geometry (:func:`arcsem.synthetic.sdf.grain_albedo`,
:func:`arcsem.synthetic.diatom.diatom_albedo`); the substrate is neutral grey. The coloured image of a
view is ``albedo * (lo + hi * clean SEM grey)`` on a dark background.
"""
from __future__ import annotations

from torch import Tensor

__all__ = ["BACKGROUND_RGB", "SUBSTRATE_ALBEDO", "colorize"]

SUBSTRATE_ALBEDO = (0.3, 0.3, 0.3)
BACKGROUND_RGB = (0.02, 0.02, 0.02)


def colorize(albedo: Tensor, grey: Tensor, lo: float = 0.25, hi: float = 1.1) -> Tensor:
    """Coloured pixels ``[N, 3]``: ``albedo [N, 3]`` modulated by the clean SEM grey ``[N]``."""
    return (albedo * (lo + hi * grey)[:, None]).clamp(0, 1)
