"""The grey prior (arcsem.colorize.prior): the references' expected colour at a grey level, and where stage 2
takes it."""
from __future__ import annotations

import torch

from arcsem.colorize.prior import fit_grey_prior, grey_prior


def _two_parts():
    """One 8x8 reference: a dark red part (grey 0.2) on the left, a bright yellow one (grey 0.8) on the right."""
    grey = torch.full((1, 8, 8), 0.2)
    grey[:, :, 4:] = 0.8
    col = torch.zeros(1, 8, 8, 3)
    col[:, :, :4] = torch.tensor([0.5, 0.05, 0.05])
    col[:, :, 4:] = torch.tensor([0.95, 0.9, 0.3])
    return col, grey


def test_each_grey_level_takes_the_colour_the_references_give_it():
    col, grey = _two_parts()
    lut = fit_grey_prior(col, grey, torch.ones(1, 8, 8, dtype=torch.bool), prior_px=0.0)
    out = grey_prior(lut, torch.tensor([0.2, 0.8, 0.22]))
    torch.testing.assert_close(out[0], torch.tensor([0.5, 0.05, 0.05]), atol=1e-4, rtol=0)
    torch.testing.assert_close(out[1], torch.tensor([0.95, 0.9, 0.3]), atol=1e-4, rtol=0)
    torch.testing.assert_close(out[2], out[0], atol=1e-4, rtol=0)  # a nearby grey: the same part


def test_where_no_reference_pixel_has_the_grey_the_prior_is_the_references_mean():
    col, grey = _two_parts()
    lut = fit_grey_prior(col, grey, torch.ones(1, 8, 8, dtype=torch.bool))
    mean = col.reshape(-1, 3).mean(0)
    torch.testing.assert_close(grey_prior(lut, torch.tensor(0.5)), mean, atol=2e-3, rtol=0)  # between the parts
    near = grey_prior(lut, torch.tensor(0.2))  # 32 pixels against 50 pseudo-pixels of the mean: towards the part
    assert (near - col[0, 0, 0]).abs().max() < (mean - col[0, 0, 0]).abs().max()


def test_only_the_masked_pixels_count_and_none_gives_no_prior():
    col, grey = _two_parts()
    mask = torch.zeros(1, 8, 8, dtype=torch.bool)
    mask[:, :, :4] = True  # the red part only
    lut = fit_grey_prior(col, grey, mask, prior_px=0.0)
    torch.testing.assert_close(grey_prior(lut, torch.tensor(0.8)), torch.tensor([0.5, 0.05, 0.05]), atol=1e-4,
                               rtol=0)
    assert fit_grey_prior(col, grey, torch.zeros(1, 8, 8, dtype=torch.bool)) is None
