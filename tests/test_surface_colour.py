"""Colour spread over the surface (arcsem.colorize.surface): a two-part toy whose answer is known.

A flat plate seen from above by two orthographic views: its left part (columns 0-11) grey 0.3 and red, its right
part (12-39) grey 0.7 and blue. The reference (view 0) is coloured only on a 4-px strip at each end; view 1 sees all
of it. The right answer in view 1: every pixel of the left part red, of the right part blue, none blended. Half way
between the strips (column 20) is not the parts' border, so a solve blind to grey puts the border in the wrong place.
"""
from __future__ import annotations

import numpy as np
import pytest
import torch

from arcsem.cameras import Cameras, look_at
from arcsem.colorize.surface import build_graph, harmonic_solve, surface_colors
from arcsem.configs import SurfaceConfig

H, W = 16, 40
EDGE = 12  # first column of the right part
RED, BLUE = torch.tensor([0.9, 0.1, 0.1]), torch.tensor([0.1, 0.2, 0.9])


def _plate(tilt_right: bool = False):
    eye = torch.tensor([[0.0, 0.0, 5.0], [0.0, 0.0, 5.0]], dtype=torch.float64)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
    K = torch.tensor([[10.0, 0, W / 2], [0, 10.0, H / 2], [0, 0, 1]], dtype=torch.float64).repeat(2, 1, 1)
    cams = Cameras(w2c, K, W, H, "orthographic")
    depth = torch.full((2, H, W), 5.0, dtype=torch.float64)
    left = torch.zeros(H, W, dtype=torch.bool)
    left[:, :EDGE] = True
    grey = torch.where(left, 0.3, 0.7).expand(2, H, W).clone()
    normals = torch.zeros(2, H, W, 3, dtype=torch.float64)
    normals[..., 2] = 1.0
    masks = torch.ones(2, H, W, dtype=torch.bool)
    masks[0, :, 4:-4] = False  # the reference is coloured at both ends only
    ref = torch.where(left[..., None], RED, BLUE)[None]  # [1, H, W, 3]
    return cams, depth, masks, grey, normals, ref, left


def test_harmonic_solve_is_the_weighted_mean_of_neighbours():
    """A path 0-1-2-3 with weights 1, 1, 2 and known ends x0 = 0, x3 = 1: x1 = (x0 + x2) / 2, x2 = (x1 + 2 x3) / 3,
    so x1 = 0.4, x2 = 0.8 (hand-solved); node 4 is not connected: not reached."""
    from scipy.sparse import coo_matrix

    i, j, w = [0, 1, 2], [1, 2, 3], [1.0, 1.0, 2.0]
    Wm = coo_matrix((w + w, (i + j, j + i)), shape=(5, 5)).tocsr()
    x, reached = harmonic_solve(Wm, np.array([0, 3]), np.array([[0.0], [1.0]]))
    np.testing.assert_allclose(x[:4, 0], [0.0, 0.4, 0.8, 1.0], atol=1e-12)
    assert reached.tolist() == [True, True, True, True, False]


def test_two_part_plate_gets_each_part_its_colour():
    cams, depth, masks, grey, normals, ref, left = _plate()
    cols, valid, info = surface_colors(cams, depth, masks, grey, normals, [0], ref)
    assert info["scribbled"] > 0 and info["nodes"] > info["scribbled"]
    assert bool(valid[1].all()), f"view 1: {int((~valid[1]).sum())} pixels without a colour"
    err_left = (cols[1][left] - RED).abs().max()
    err_right = (cols[1][~left] - BLUE).abs().max()
    assert err_left < 0.02 and err_right < 0.02, (err_left, err_right)


def test_without_the_grey_term_the_border_moves():
    """The same plate with edges blind to grey (grey_scale huge): the colours meet half way between the scribbles,
    so columns 12-19 of the right part come out red (the grey term is what puts the border right, test above)."""
    cams, depth, masks, grey, normals, ref, left = _plate()
    cols, valid, _ = surface_colors(cams, depth, masks, grey, normals, [0], ref, SurfaceConfig(grey_scale=1e3))
    wrong = valid[1] & ((cols[1] - torch.where(left[..., None], RED, BLUE)).abs().amax(-1) > 0.3)
    assert int(wrong[:, EDGE:20].sum()) > 0.5 * H * (20 - EDGE)


def test_a_crease_separates_parts_of_one_grey():
    """Both parts grey 0.5 but at right angles (normals +z and +x): the normal term keeps the colours apart; without
    it (normal_scale huge) the border moves as without the grey term."""
    cams, depth, masks, grey, normals, ref, left = _plate()
    grey[:] = 0.5
    normals[:, :, EDGE:] = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    want = torch.where(left[..., None], RED, BLUE)
    cols, valid, _ = surface_colors(cams, depth, masks, grey, normals, [0], ref)
    assert bool(valid[1].all()) and (cols[1] - want).abs().max() < 0.02
    cols, valid, _ = surface_colors(cams, depth, masks, grey, normals, [0], ref, SurfaceConfig(normal_scale=1e3))
    assert int((valid[1] & ((cols[1] - want).abs().amax(-1) > 0.3)).sum()) > 0.5 * H * (20 - EDGE)


def test_no_reference_pixel_no_colour():
    cams, depth, masks, grey, normals, ref, _ = _plate()
    masks[0] = False
    cols, valid, info = surface_colors(cams, depth, masks, grey, normals, [0], ref)
    assert info["scribbled"] == 0 and not bool(valid.any()) and float(cols.abs().max()) == 0.0


@pytest.mark.parametrize("cell_px", [1.0, 2.0])
def test_graph_nodes_merge_pixels_of_both_views(cell_px):
    cams, depth, masks, grey, normals, _, _ = _plate()
    g = build_graph(cams, depth, masks, grey, normals, SurfaceConfig(cell_px=cell_px))
    both = (g.node_of[0] >= 0)
    # view 0's pixels fall in the same nodes as view 1's at the same place (same camera)
    assert np.array_equal(g.node_of[0][both], g.node_of[1][both])
    assert g.weights.shape == (len(g.grey), len(g.grey)) and (g.weights != g.weights.T).nnz == 0
