"""Shading carried with the colour: a reference colour moved to another view takes that view's SEM brightness.

An SEM image's brightness at a surface point depends on the view (the beam's incidence on the surface), and
artists colour with that shading kept (the colour multiplies or overlays the grey). So a pseudo-colour copied from
a reference pixel carries the reference view's shading, not the target view's. The references themselves say how
their colours follow the grey: a least-squares line ``L = a + b g`` of the colour's luminance (channel mean)
against the grey over the reference pixels (:func:`fit_shading`). A colour ``c`` taken from a pixel of grey
``g_src`` is given to a pixel of grey ``g_dst`` as ``c (a + b g_dst) / (a + b g_src)`` (:func:`shade`): unchanged
where the colours do not follow the grey (``b = 0``), and on the reference views themselves (``g_src = g_dst``).
"""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["fit_shading", "shade"]


def fit_shading(ref_colors: Tensor, ref_grey: Tensor, masks: Tensor) -> tuple[float, float]:
    """``(a, b)`` of the line ``mean(rgb) = a + b g`` over the masked pixels of the references (``ref_colors
    [R, H, W, 3]``, ``ref_grey [R, H, W]``, ``masks [R, H, W]``); ``(1, 0)`` (no shading) with fewer than 16 pixels
    or a line that is not positive over the grey range."""
    m = masks.bool()
    if int(m.sum()) < 16:
        return 1.0, 0.0
    L, g = ref_colors.float().mean(-1)[m].double(), ref_grey.float()[m].double()
    A = torch.stack([torch.ones_like(g), g], 1)
    a, b = torch.linalg.lstsq(A, L[:, None]).solution[:, 0].tolist()
    lo, hi = float(g.min()), float(g.max())
    if min(a + b * lo, a + b * hi) <= 0.02 or b < 0:
        return 1.0, 0.0
    return a, b


def shade(colors: Tensor, src_grey: Tensor, dst_grey: Tensor, a: float, b: float, limit: float = 4.0) -> Tensor:
    """``colors [..., 3]`` taken at grey ``src_grey [...]``, shaded for pixels of grey ``dst_grey [...]``; the factor
    is kept within ``[1/limit, limit]`` and the result within [0, 1]."""
    f = (a + b * dst_grey.float()) / (a + b * src_grey.float()).clamp_min(1e-3)
    return (colors * f.clamp(1.0 / limit, limit)[..., None]).clamp(0, 1)
