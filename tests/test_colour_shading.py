"""Shading carried with the colour (arcsem.colorize.shading): the line fitted to the references, and its use."""
from __future__ import annotations

import torch

from arcsem.colorize.shading import fit_shading, shade


def _refs(a: float, b: float):
    g = torch.Generator().manual_seed(0)
    grey = torch.rand(2, 8, 8, generator=g)
    albedo = torch.tensor([0.9, 0.5, 0.1])  # mean 0.5: luminance = 0.5 (a' + b' g)
    colors = albedo * (a + b * grey)[..., None]
    return colors, grey, torch.ones(2, 8, 8, dtype=torch.bool)


def test_fit_recovers_the_line_of_colour_against_grey():
    colors, grey, masks = _refs(0.25, 1.1)  # the built-in scenes' rule: albedo x (0.25 + 1.1 grey)
    a, b = fit_shading(colors, grey, masks)
    assert abs(a - 0.125) < 1e-6 and abs(b - 0.55) < 1e-6  # x 0.5, the albedo's mean


def test_colours_that_do_not_follow_the_grey_are_not_shaded():
    colors, grey, masks = _refs(0.5, 0.0)
    a, b = fit_shading(colors, grey, masks)
    assert abs(b) < 1e-6 and shade(torch.full((4, 3), 0.4), torch.full((4,), 0.2), torch.full((4,), 0.9), a,
                                   b).allclose(torch.full((4, 3), 0.4))
    assert fit_shading(colors, grey, torch.zeros_like(masks)) == (1.0, 0.0)  # no pixels: no line
    assert fit_shading(colors.flip(0) * 0 + (1 - grey)[..., None], grey, masks) == (1.0, 0.0)  # darker where brighter


def test_shade_moves_a_colour_to_another_pixels_brightness():
    c = torch.tensor([[0.4, 0.2, 0.1]])
    out = shade(c, torch.tensor([0.5]), torch.tensor([0.25]), 0.0, 1.0)
    torch.testing.assert_close(out, c / 2)  # half the grey: half the colour
    same = shade(c, torch.tensor([0.3]), torch.tensor([0.3]), 0.1, 0.7)
    torch.testing.assert_close(same, c)  # a reference's own pixel keeps its colour
    big = shade(c, torch.tensor([0.01]), torch.tensor([1.0]), 0.0, 1.0)
    torch.testing.assert_close(big, (c * 4).clamp(0, 1))  # the factor is limited to 4
