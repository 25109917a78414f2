"""Guarded correspondences (arcsem.colorize.guard): geometry, ratio and mutual tests on hand-built features.

The scene: one view location on the specimen's top (normal towards the cameras, high) and a reference with two
candidate locations: on another part (a side, low) whose grey appearance is IDENTICAL to the query's, and on the
same part, alike but not identical. Appearance alone picks the other part; the guard picks the right one.
"""
from __future__ import annotations

import torch

from arcsem.colorize.guard import grid_positions, guarded_nearest
from arcsem.colorize.guidance import nearest_cosine
from arcsem.configs import GuardConfig

D = 16
TOP, SIDE = [0.95, 0.9], [0.05, 0.3]  # (normal elevation, height) of the two parts


def _keys(g: torch.Generator, n: int = 30) -> tuple[torch.Tensor, torch.Tensor]:
    """A 1 x 5 x 6 reference grid of random features, all on the side part."""
    keys = torch.randn(n, D, generator=g)
    geo = torch.tensor(SIDE).repeat(n, 1)
    return keys, geo


def _wrong_part_scene():
    g = torch.Generator().manual_seed(0)
    keys, kgeo = _keys(g)
    f = torch.randn(D, generator=g)
    keys[7] = f  # another part, the same appearance
    keys[22] = f + 0.3 * torch.randn(D, generator=g)  # the same part, alike
    kgeo[22] = torch.tensor(TOP)
    query, qgeo = f[None], torch.tensor([TOP])
    return query, keys, qgeo, kgeo


def test_appearance_alone_picks_the_other_part_and_the_guard_the_right_one():
    query, keys, qgeo, kgeo = _wrong_part_scene()
    plain, _ = nearest_cosine(query, keys)
    assert plain.tolist() == [7]  # the wrong part: its grey features are identical
    idx, dist, kept = guarded_nearest(query, keys, qgeo, kgeo, torch.tensor([[0, 0]]), grid_positions(1, 5, 6),
                                      GuardConfig())
    assert idx.tolist() == [22] and kept.tolist() == [True] and 0 < float(dist[0]) < 0.2


def test_no_compatible_location_no_match():
    query, keys, qgeo, kgeo = _wrong_part_scene()
    kgeo[22] = torch.tensor(SIDE)
    _, _, kept = guarded_nearest(query, keys, qgeo, kgeo, torch.tensor([[0, 0]]), grid_positions(1, 5, 6),
                                 GuardConfig())
    assert kept.tolist() == [False]
    _, _, kept = guarded_nearest(query, keys, torch.tensor([[float("nan"), 0.5]]), kgeo, torch.tensor([[0, 0]]),
                                 grid_positions(1, 5, 6), GuardConfig())
    assert kept.tolist() == [False]  # no geometry known for the query: nothing is compatible


def test_ratio_test_drops_a_match_that_could_as_well_be_elsewhere():
    """Two compatible locations far apart (cells 2 and 27) alike and near the query: ambiguous, dropped; the same
    pair as neighbours (cells 2 and 3) is one match, kept."""
    g = torch.Generator().manual_seed(1)
    keys, kgeo = _keys(g)
    f = torch.randn(D, generator=g)
    for far, want in ((27, False), (3, True)):
        k, kg = keys.clone(), kgeo.clone()
        k[2] = k[far] = f + 0.2 * torch.randn(D, generator=g)
        kg[2], kg[far] = torch.tensor(TOP), torch.tensor(TOP)
        _, _, kept = guarded_nearest(f[None], k, torch.tensor([TOP]), kg, torch.tensor([[0, 0]]),
                                     grid_positions(1, 5, 6), GuardConfig())
        assert kept.tolist() == [want], far


def test_apart_search_skips_the_querys_own_surface_point():
    """The right part's location 22 is the query's own surface point (the reference shows it): found as usual, and
    with ``apart`` the search goes past it, to the same-part location 12 three units away, or to none when 12 is
    within the radius too (a point no reference sees has no such match)."""
    query, keys, qgeo, kgeo = _wrong_part_scene()
    keys[12], kgeo[12] = keys[22] + 0.2 * torch.randn(D, generator=torch.Generator().manual_seed(3)), torch.tensor(TOP)
    kpts = torch.full((30, 3), 50.0)
    kpts[22], kpts[12] = torch.tensor([0.0, 0.0, 0.1]), torch.tensor([3.0, 0.0, 0.0])
    qpts = torch.zeros(1, 3)
    args = (query, keys, qgeo, kgeo, torch.tensor([[0, 0]]), grid_positions(1, 5, 6), GuardConfig())
    assert guarded_nearest(*args)[0].tolist() == [22]
    idx, _, kept = guarded_nearest(*args, apart=(qpts, kpts, 1.0))
    assert idx.tolist() == [12] and kept.tolist() == [True]
    _, _, kept = guarded_nearest(*args, apart=(qpts, kpts, 4.0))
    assert kept.tolist() == [False]


def test_mutual_test_keeps_only_the_best_of_two_queries_for_one_location():
    """Queries at cells (0, 0) and (3, 3) both match key 22; its nearest query is the second: only it is kept
    (the first kept without the mutual test)."""
    _, keys, qgeo, kgeo = _wrong_part_scene()
    q = torch.stack([keys[22] + 0.4 * torch.randn(D, generator=torch.Generator().manual_seed(5)), keys[22]])
    args = (q, keys, qgeo.repeat(2, 1), kgeo, torch.tensor([[0, 0], [3, 3]]), grid_positions(1, 5, 6))
    idx, _, kept = guarded_nearest(*args, GuardConfig())
    assert idx.tolist() == [22, 22] and kept.tolist() == [False, True]
    _, _, kept = guarded_nearest(*args, GuardConfig(mutual=False))
    assert kept.tolist() == [True, True]


def test_views_that_disagree_about_a_points_colour_are_dropped():
    """Three views see the same surface point (and one more point each); at the shared point two bring red and
    one blue: the blue match is dropped. A point only one view sees keeps its match, whatever its colour; two views
    that disagree, with no third, both lose theirs."""
    from arcsem.colorize.guard import cross_view_agreement

    red, blue = torch.tensor([0.9, 0.1, 0.1]), torch.tensor([0.1, 0.1, 0.9])
    shared = torch.tensor([0.05, 0.05, 0.05])
    points = [torch.stack([shared, torch.tensor([float(v) + 1.05, 0.05, 0.05])]) for v in range(3)]
    colours = [torch.stack([red, blue]), torch.stack([red, red]), torch.stack([blue, blue])]
    keep = [torch.tensor([True, True])] * 3
    out = cross_view_agreement(points, colours, keep, cell=0.5, tol=0.2)
    assert [o.tolist() for o in out] == [[True, True], [True, True], [False, True]]
    points[1][0] = float("nan")  # no surface known at the shared point in view 1: one red, one blue, no majority
    out = cross_view_agreement(points, colours, keep, cell=0.5, tol=0.2)
    assert [o.tolist() for o in out] == [[False, True], [False, True], [False, True]]


class _Carried:
    """Guidance stub: one CCM grid of 2x2 cells per 8x8 view; every match brings ``colour`` and is kept, except the
    bottom-right cell's (dropped by the guard); the matches searched apart from their own points bring ``apart``."""

    def __init__(self, colour, apart=(0.0, 0.0, 1.0)):
        self.colour, self.apart, self.asked = torch.tensor(colour), torch.tensor(apart), []

    def kinds(self):
        return [("ccm", (2, 2))]

    def apart_matches(self, v, points, footprint, factor):
        self.asked.append((v, factor))
        return {"apart": True}

    def carried(self, v, name, matches=None):
        keep = torch.tensor([True, True, True, False])
        return (self.colour if matches is None else self.apart).expand(4, 3), keep


def test_match_check_keeps_matches_that_bring_the_pseudo_colours_and_drops_those_that_bring_another_part():
    """Views 1 and 2: the top half has 2-D pseudo-colours (red, the part the reference shows there), the bottom none.
    Matches that bring red beat the flat guess (the references' mean, grey) on the two covered cells; matches that
    bring blue (another part) do not, and the loss is dropped; bottom cells (uncovered) and dropped matches do not
    count."""
    from arcsem.colorize.guard import match_check

    pseudo = torch.zeros(3, 8, 8, 3)
    pseudo[..., 0] = 1.0
    valid = torch.zeros(3, 8, 8, dtype=torch.bool)
    valid[:, :4] = True
    flat = torch.tensor([0.5, 0.5, 0.5])
    right = match_check(_Carried([1.0, 0.0, 0.0]), [1, 2], pseudo, valid, flat)["ccm"]
    assert right["cells"] == 4 and right["match"] == 0.0 and abs(right["guess"] - 0.25) < 1e-6 and right["keep"]
    wrong = match_check(_Carried([0.0, 0.0, 1.0]), [1, 2], pseudo, valid, flat)["ccm"]
    assert abs(wrong["match"] - 2 / 3) < 1e-6 and not wrong["keep"]
    nowhere = match_check(_Carried([1.0, 0.0, 0.0]), [1, 2], pseudo, torch.zeros_like(valid), flat)["ccm"]
    assert nowhere["cells"] == 0 and not nowhere["keep"]  # no evidence: the loss is dropped
    prior = torch.zeros(3, 8, 8, 3)  # a guess per pixel (the grey prior): red on the top half, where it is right
    prior[:, :4, :, 0] = 1.0
    beaten = match_check(_Carried([1.0, 0.0, 0.0]), [1, 2], pseudo, valid, prior)["ccm"]
    assert beaten["guess"] == 0.0 and not beaten["keep"]  # matches no better than the prior: dropped
    # searched away from their own points, the matches that found red bring blue: dropped
    guide = _Carried([1.0, 0.0, 0.0])
    apart = match_check(guide, [1, 2], pseudo, valid, flat, (torch.zeros(3, 8, 8, 3), 0.1, 2.0))["ccm"]
    assert abs(apart["match"] - 2 / 3) < 1e-6 and not apart["keep"] and guide.asked == [(1, 2.0), (2, 2.0)]
    found = match_check(_Carried([0.0, 0.0, 1.0], apart=(1.0, 0.0, 0.0)), [1, 2], pseudo, valid, flat,
                        (torch.zeros(3, 8, 8, 3), 0.1, 2.0))["ccm"]
    assert found["match"] == 0.0 and found["keep"]  # and the other way round: the apart matches decide
