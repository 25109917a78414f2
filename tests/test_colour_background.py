"""The background's colour target (arcsem.colorize.background): a line of the grey fitted on the references'
background, given to the other views' background pixels."""
from __future__ import annotations

import torch

from arcsem.colorize.background import MIN_PIXELS, background_target, fit_background


def _refs():
    """Two 8x8 references: the specimen (mask) the top-left quarter, coloured orange; the background tinted blue-grey
    as ``(0.8 g, 0.9 g, g + 0.1)`` of its grey."""
    grey = torch.rand(2, 8, 8)
    masks = torch.zeros(2, 8, 8, dtype=torch.bool)
    masks[:, :4, :4] = True
    rgb = torch.stack([0.8 * grey, 0.9 * grey, grey + 0.1], -1)
    rgb[masks] = torch.tensor([1.0, 0.5, 0.0])
    return rgb, grey, masks


def test_the_line_is_fitted_on_the_background_only_and_given_to_background_pixels():
    rgb, grey, masks = _refs()
    line = fit_background(rgb, grey, masks)
    torch.testing.assert_close(torch.tensor(line["a"]), torch.tensor([0.0, 0.0, 0.1]), atol=1e-5, rtol=0)
    torch.testing.assert_close(torch.tensor(line["b"]), torch.tensor([0.8, 0.9, 1.0]), atol=1e-5, rtol=0)
    assert line["pixels"] == 96 and line["rms"] < 1e-5  # the orange specimen is not in the fit
    view_grey = torch.full((1, 8, 8), 0.5)
    view_mask = torch.zeros(1, 8, 8, dtype=torch.bool)
    view_mask[:, 2:6, 2:6] = True
    target, where = background_target(view_grey, view_mask, line)
    assert torch.equal(where, ~view_mask)
    torch.testing.assert_close(target[0, 0, 0], torch.tensor([0.4, 0.45, 0.6]))


def test_no_line_without_enough_background():
    rgb, grey, masks = _refs()
    full = torch.ones_like(masks)
    full[0, 0, : MIN_PIXELS // 8] = False  # fewer than MIN_PIXELS background pixels
    assert fit_background(rgb, grey, full) is None
