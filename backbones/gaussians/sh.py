"""Moved: spherical harmonics are shared by every backbone and live in :mod:`arcsem.backbones.sh`.

Importing a name from here still works for one release and warns (DeprecationWarning).
"""
from __future__ import annotations

from arcsem.lazy import moved_getattr

__all__: list[str] = []

__getattr__ = moved_getattr(__name__, dict.fromkeys(
    ("C0", "C1", "C2", "C3", "RGB2SH", "SH2RGB", "eval_sh", "num_sh_coeffs", "rgb_to_sh", "sh_basis", "sh_to_rgb"),
    "arcsem.backbones.sh"))
