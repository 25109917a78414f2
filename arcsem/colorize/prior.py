"""The references' colour for a grey level: the target of specimen pixels nothing else gives a colour.

The 2-D pseudo-colours and the surface spread colour what the references see and what the surface connects to it
with confidence; the rest of the specimen (what no reference looks at, or parts the spread cannot tell apart) has
no target, and stage 2 leaves it the stage-1 grey. Without other evidence the least-squares guess of a pixel's
colour is its expected colour given what is known of it, its grey level (as Welsh, Ashikhmin and Mueller 2002
transfer colour to a grey image by luminance): ``E[rgb | g]``, estimated over the references' specimen pixels by
kernel regression (Nadaraya-Watson, a Gaussian kernel of width ``bandwidth`` in grey), shrunk towards the
references' mean colour where few reference pixels have that grey (``prior_px`` pseudo-pixels of the mean).

It paints only the references' own palette and never where other evidence exists: the pseudo-colour target takes
it (``colorize.prior=grey``) on the specimen pixels left after the pseudo-colours and the surface spread.
"""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["BINS", "fit_grey_prior", "grey_prior"]

BINS = 256  # grey levels of the lookup table


def fit_grey_prior(ref_colors: Tensor, ref_grey: Tensor, ref_masks: Tensor, bandwidth: float = 0.05,
                   prior_px: float = 50.0) -> Tensor | None:
    """The lookup table ``[BINS, 3]`` of ``E[rgb | g]`` at ``g = (k + 0.5) / BINS`` over the references' masked
    pixels (``ref_colors [R, H, W, 3]``, ``ref_grey [R, H, W]`` in [0, 1], ``ref_masks [R, H, W]``); None without
    any masked pixel."""
    m = ref_masks.bool()
    if not bool(m.any()):
        return None
    c, g = ref_colors.float()[m].double(), ref_grey.float()[m].double().clamp(0, 1)
    k = (g * BINS).long().clamp_max(BINS - 1)
    count = torch.zeros(BINS, dtype=torch.float64).index_add_(0, k, torch.ones_like(g))
    sums = torch.zeros(BINS, 3, dtype=torch.float64).index_add_(0, k, c)
    centres = (torch.arange(BINS, dtype=torch.float64) + 0.5) / BINS
    kern = torch.exp(-((centres[:, None] - centres[None]) ** 2) / (2 * bandwidth ** 2))  # [BINS, BINS]
    w, s = kern @ count, kern @ sums
    mean = c.mean(0)
    return ((s + prior_px * mean) / (w + prior_px)[:, None]).float().clamp(0, 1)


def grey_prior(lut: Tensor, grey: Tensor) -> Tensor:
    """``[..., 3]``: the table ``lut [BINS, 3]`` (:func:`fit_grey_prior`) at each grey of ``grey [...]`` in [0, 1]."""
    k = (grey.float().clamp(0, 1) * BINS).long().clamp_max(BINS - 1)
    return lut[k]
