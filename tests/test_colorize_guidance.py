"""TCM nearest-feature guidance and CCM targets on hand-built tiny feature maps; disk cache."""
import pytest
import torch
from torch import nn

from arcsem.colorize.guidance import Guidance, ccm_targets, nearest_cosine, tcm_match
from arcsem.imageops import patch_means


class FakeVGG(nn.Module):
    """'Features' = (image, 1 - image) per pixel: grey values stay distinguishable under cosine."""

    name, strides, differentiable = "fake", (1, 1), True

    def key(self):
        return "fake"

    def label(self):
        return "fake"

    def forward(self, images):
        f = torch.cat([images, 1 - images], -1).permute(0, 3, 1, 2)
        return [f, f]


def _grey(vals):
    return torch.tensor(vals, dtype=torch.float32)[..., None].expand(*torch.tensor(vals).shape, 3)


def test_nearest_cosine_hand_example():
    keys = torch.tensor([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0]])
    q = torch.tensor([[3.0, 0.1], [0.1, 1.0], [1.0, 0.9]])
    idx, dist = nearest_cosine(q, keys, chunk=2)
    assert idx.tolist() == [0, 1, 2]
    torch.testing.assert_close(dist[2], 1 - (1.9 / (2**0.5 * (1 + 0.81) ** 0.5)) * torch.ones(()))


def test_tcm_guidance_is_colour_feature_at_nearest_grey_feature():
    red, blue = torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 0.0, 1.0])
    ref_grey = _grey([[[0.2, 0.9]]])  # [R=1, H=1, W=2, 3]
    ref_col = torch.stack([red, blue])[None, None]  # [1, 1, 2, 3]
    view = _grey([[0.85, 0.25]])  # matches (1, 0)
    gray = torch.cat([ref_grey, view[None]])  # view 0 = reference, view 1 = query
    g = Guidance(FakeVGG(), FakeVGG(), gray, [0], ref_col, tcm_downscale=1, ccm_downscale=1)
    feats = [f[0] for f in FakeVGG()(view[None])]
    assert tcm_match(feats, FakeVGG()(ref_grey))[0].tolist() == [[1, 0]]
    guide = g.targets(1)["tcm_guidance"][0]  # [D=6, 1, 2]
    expect = torch.cat([torch.stack([blue, red]), 1 - torch.stack([blue, red])], -1).T.reshape(6, 1, 2)
    torch.testing.assert_close(guide, expect)


def test_patch_means_and_ccm_targets_hand_example():
    img = torch.arange(16.0).reshape(1, 4, 4, 1).expand(1, 4, 4, 3)
    # cells of 2x2: means (0+1+4+5)/4 = 2.5, 4.5, 10.5, 12.5
    torch.testing.assert_close(patch_means(img, 2)[0, ..., 0], torch.tensor([[2.5, 4.5], [10.5, 12.5]]))
    ref_means = torch.tensor([[0.2, 0.3, 0.4], [1.0, 1.0, 0.995], [0.5, 0.5, 0.5]])
    idx = torch.tensor([[0, 1], [2, 0]])
    dist = torch.tensor([[0.1, 0.1], [0.59, 0.61]])
    target, valid = ccm_targets(idx, dist, ref_means, 0.6, 0.99)
    torch.testing.assert_close(target[1, 0], ref_means[2])
    assert valid.tolist() == [[True, False], [True, False]]  # white cell, then a too-distant match


def test_ccm_targets_from_quadrant_matches(tmp_path):
    quads = [0.1, 0.4, 0.7, 0.95]  # grey level of each 2x2 quadrant of the reference
    cols = [torch.tensor(c) for c in ([1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [1.0, 1.0, 1.0])]
    ref_g, ref_c = torch.zeros(4, 4, 3), torch.zeros(4, 4, 3)
    view = torch.zeros(4, 4, 3)
    perm = [3, 2, 1, 0]  # view quadrant q looks like reference quadrant perm[q]
    for q, (r, c) in enumerate([(0, 0), (0, 2), (2, 0), (2, 2)]):
        ref_g[r:r + 2, c:c + 2] = quads[q]
        ref_c[r:r + 2, c:c + 2] = cols[q]
        view[r:r + 2, c:c + 2] = quads[perm[q]]
    g = Guidance(FakeVGG(), FakeVGG(), torch.stack([ref_g, view]), [0], ref_c[None], tcm_downscale=1, ccm_downscale=2,
                 cache_dir=tmp_path)
    t = g.targets(1)
    expect = torch.stack([cols[p] for p in perm]).reshape(2, 2, 3)
    torch.testing.assert_close(t["ccm_target"], expect)
    assert t["ccm_valid"].tolist() == [[False, True], [True, True]]  # the white quadrant is ignored
    # a second instance reads the matches from disk instead of recomputing
    g2 = Guidance(FakeVGG(), FakeVGG(), torch.stack([ref_g, view]), [0], ref_c[None], tcm_downscale=1, ccm_downscale=2,
                  cache_dir=tmp_path)
    g2._compute = lambda v: pytest.fail("recomputed despite the disk cache")
    torch.testing.assert_close(g2.targets(1)["ccm_target"], expect)
    assert g2.matches(1) is g2.matches(1)  # memory cache


def test_apart_matches_skip_the_locations_own_surface_point():
    """A view that sees the reference's two points again: its guarded matches are those points themselves; searched
    apart (beyond two 0.1-wide cells of the own point), each location must take the other point, as a point no
    reference sees would have to."""
    from arcsem.configs import GuardConfig

    ref_grey, view = _grey([[[0.2, 0.85]]]), _grey([[0.25, 0.8]])
    ref_col = torch.stack([torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 0.0, 1.0])])[None, None]
    points = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]).reshape(1, 1, 2, 3).expand(2, 1, 2, 3)
    g = Guidance(FakeVGG(), FakeVGG(), torch.cat([ref_grey, view[None]]), [0], ref_col, tcm_downscale=1,
                 ccm_downscale=1, geometry=torch.zeros(2, 2, 1, 2), guard=GuardConfig())
    assert g.matches(1)["tcm_idx0"].tolist() == [[0, 1]] and g.matches(1)["tcm_ok0"].all()
    apart = g.apart_matches(1, points, footprint=0.1, factor=2.0)
    assert apart["tcm_idx0"].tolist() == [[1, 0]] and apart["ccm_idx"].tolist() == [[1, 0]]
    colours, keep = g.carried(1, "tcm0", apart)
    torch.testing.assert_close(colours, ref_col[0, 0].flip(0))
    assert keep.all()
    assert g.matches(1)["tcm_idx0"].tolist() == [[0, 1]]  # the guidance's own matches are untouched
    far = g.apart_matches(1, points, footprint=0.1, factor=20.0)  # every point within the radius: no match kept
    assert not far["tcm_ok0"].any() and not far["ccm_ok"].any()
