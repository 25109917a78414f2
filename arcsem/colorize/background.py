"""The background's colour target: what the artist did to the substrate, carried to every view by its grey.

The pseudo-colours (and TCM/CCM) colour the specimen. The substrate around it is in every view, but no target
holds it in the non-reference views: its Gaussians take whatever colour the reference views' L1 gives the
Gaussians they see, and a large one behind the specimen in a reference becomes a smear of specimen colour over
the background of the others (measured on the built-in diatom at one reference: the whole-image PSNR 0.9 dB below
pseudo-colours alone while the specimen's was 0.9 dB above). Artists colour a substrate simply: left grey, tinted,
or darkened. So the references' background pixels (outside the specimen masks) fit one line per channel,
``rgb = a + b g`` (:func:`fit_background`, least squares over the grey), and every non-reference view's background
pixel takes the line at its grey as its pseudo-colour target (:func:`background_target`).
"""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["MIN_PIXELS", "background_target", "fit_background"]

MIN_PIXELS = 64  # fewer background pixels in the references: no line, no target


def fit_background(ref_colors: Tensor, ref_grey: Tensor, ref_masks: Tensor) -> dict | None:
    """The per-channel line ``rgb = a + b g`` over the references' pixels outside their specimen masks
    (``ref_colors [R, H, W, 3]``, ``ref_grey [R, H, W]``, ``ref_masks [R, H, W]``): ``{"a": [3], "b": [3],
    "pixels": n, "rms": residual}``, or None with fewer than :data:`MIN_PIXELS` background pixels."""
    bg = ~ref_masks.bool()
    n = int(bg.sum())
    if n < MIN_PIXELS:
        return None
    c, g = ref_colors.float()[bg].double(), ref_grey.float()[bg].double()
    A = torch.stack([torch.ones_like(g), g], 1)
    sol = torch.linalg.lstsq(A, c).solution  # [2, 3]
    rms = float(((A @ sol - c) ** 2).mean().sqrt())
    return {"a": sol[0].tolist(), "b": sol[1].tolist(), "pixels": n, "rms": rms}


def background_target(grey: Tensor, masks: Tensor, line: dict) -> tuple[Tensor, Tensor]:
    """``(colours [N, H, W, 3], where [N, H, W])``: the line at each pixel's grey (``grey [N, H, W]``), clamped to
    [0, 1], on the pixels outside the specimen masks (``masks [N, H, W]``)."""
    a = torch.tensor(line["a"], dtype=torch.float32)
    b = torch.tensor(line["b"], dtype=torch.float32)
    rgb = (a + b * grey.float()[..., None]).clamp(0, 1)
    return rgb, ~masks.bool()
