"""Shared rasteriser machinery: compositing rules, binning, segments, footprints (hand-computed values)."""
import math

import torch
from arcsem.backbones.gaussians.raster import Segments, bin_tiles, composite, tile_rects
from arcsem.backbones.gaussians.raster_camera import pixel_projection
from arcsem.backbones.gaussians.raster_scenes import orbit_cameras, random_splats
from arcsem.backbones.gs2d.render import footprint_2dgs, splat_homographies
from arcsem.backbones.gs3d.render import footprint_3dgs, project_gaussians

from arcsem.rotations import quat_to_rotmat


def one_segment(n):
    return Segments(torch.zeros(n, dtype=torch.long), torch.zeros(n, dtype=torch.long), 1, torch.zeros(1))


def test_composite_skip_clamp():
    alpha = torch.tensor([0.5, 0.5, 0.002, 1.2], dtype=torch.float64)
    w, T, keep = composite(alpha, one_segment(4))
    # T: 1, 0.5, 0.25, 0.25 (the 0.002 splat is skipped); last alpha clamped to 0.99
    torch.testing.assert_close(T, torch.tensor([1.0, 0.5, 0.25, 0.25], dtype=torch.float64))
    torch.testing.assert_close(w, torch.tensor([0.5, 0.25, 0.0, 0.2475], dtype=torch.float64))
    assert keep.tolist() == [True, True, False, True]


def test_composite_early_stop():
    alpha = torch.full((5,), 0.95, dtype=torch.float64)
    w, _, keep = composite(alpha, one_segment(5))
    # T after: 0.05, 0.0025, 1.25e-4, 6.25e-6 < 1e-4 -> the 4th and later are not composited
    torch.testing.assert_close(w, torch.tensor([0.95, 0.0475, 0.002375, 0.0, 0.0], dtype=torch.float64))
    assert keep.tolist() == [True, True, True, False, False]
    assert abs(1 - w.sum().item() - 1.25e-4) < 1e-12  # alpha = 1 - final transmittance


def test_segments_two_pixels():
    seg = torch.tensor([0, 0, 0, 1, 1])
    s = Segments(seg, torch.tensor([0, 0, 0, 3, 3]), 2, torch.tensor([5, 9]))
    x = torch.tensor([1.0, 2.0, 3.0, 10.0, 20.0])
    torch.testing.assert_close(s.excl_cumsum(x), torch.tensor([0.0, 1.0, 3.0, 0.0, 10.0]))
    torch.testing.assert_close(s.sum(x[:, None])[:, 0], torch.tensor([6.0, 30.0]))
    assert s.last(torch.tensor([True, True, False, False, False])).tolist() == [1, -1]
    _, T, _ = composite(torch.tensor([0.5, 0.5, 0.5, 0.5, 0.5]), s)
    torch.testing.assert_close(T, torch.tensor([1.0, 0.5, 0.25, 1.0, 0.5]))


def test_tile_rects_and_binning():
    # centres in pixels (official getRect on centre - 0.5), 20x16 image, tile 8 -> 3 x 2 tiles
    center = torch.tensor([[[4.5, 4.5], [8.5, 8.5], [19.0, 15.0], [30.0, 4.0]]])
    radius = torch.tensor([[2, 1, 3, 2]])
    rects = tile_rects(center, radius, 20, 16, 8)
    assert rects[0].tolist() == [[0, 1, 0, 1], [0, 2, 0, 2], [1, 3, 1, 2], [3, 3, 0, 1]]
    depth = torch.tensor([[3.0, 1.0, 2.0, 0.5]])
    b = bin_tiles(rects, depth, 20, 16, 8)
    # tile 0: splat 1 (depth 1) before splat 0 (depth 3); tiles 1, 3: splat 1; tile 4: splats 1, 2; tile 5: 2
    pairs = [(0, 1), (0, 0), (1, 1), (3, 1), (4, 1), (4, 2), (5, 2)]
    assert list(zip(b.ctile.tolist(), b.splat.tolist())) == pairs
    assert b.offsets.tolist() == [0, 2, 3, 3, 4, 6, 7]


def test_quaternion_and_projection_matrix():
    q = torch.tensor([[math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]], dtype=torch.float64) * 3
    R = quat_to_rotmat(q)[0]  # 90 degrees about z: x -> y
    torch.testing.assert_close(R @ torch.tensor([1.0, 0, 0], dtype=torch.float64),
                               torch.tensor([0.0, 1, 0], dtype=torch.float64))
    for ortho in (False, True):
        cams = orbit_cameras(2, 20, 16, ortho=ortho)
        pts = torch.randn(7, 3, dtype=torch.float64)
        h = torch.einsum("cij,nj->cni", pixel_projection(cams), torch.cat([pts, torch.ones(7, 1, dtype=torch.float64)], 1))
        uv, z = cams.project(pts)
        torch.testing.assert_close(h[..., :2] / h[..., 2:3], uv)
        torch.testing.assert_close(h[..., 3], z)


def _dense_alpha_outside_box(alpha, eff, W, H):
    ys, xs = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    inside = (xs[None] >= eff[:, 0, None, None]) & (xs[None] <= eff[:, 1, None, None]) & \
        (ys[None] >= eff[:, 2, None, None]) & (ys[None] <= eff[:, 3, None, None])
    return alpha[~inside].max() if (~inside).any() else torch.tensor(0.0)


def test_effective_boxes_contain_every_visible_pixel():
    """Outside the effective box alpha < 1/255 (so shrinking the work to the box changes nothing)."""
    W, H = 40, 32
    s = random_splats(40, 1, seed=11, opacity=(0.01, 1.0), scale=(0.02, 0.3))
    for ortho in (False, True):
        cams = orbit_cameras(1, W, H, ortho=ortho)
        pix = cams.pixel_grid(torch.float64)
        m2, z, cov = project_gaussians(s.means, s.quats, s.scales, cams)
        _, _, eff, ok = footprint_3dgs(m2, z, cov, s.opacities, cams, 16, 0.01)
        d = pix[None] - m2[0, :, None, None]
        conic = torch.linalg.inv(cov[0])
        alpha = s.opacities[:, None, None] * torch.exp(-0.5 * torch.einsum("nhwi,nij,nhwj->nhw", d, conic, d))
        assert _dense_alpha_outside_box(alpha[ok[0]], eff[0][ok[0]], W, H) < 1 / 255
        Hm, _ = splat_homographies(s.means, s.quats, s.scales[:, :2], cams)
        radius, _, eff2, _ = footprint_2dgs(Hm, s.opacities, cams, 16, 0.01)
        T = Hm[0][:, None, None]  # [N, 1, 1, 4, 3]
        x, y = pix[None, ..., :1], pix[None, ..., 1:]
        qv = torch.cross(x * T[..., 2, :] - T[..., 0, :], y * T[..., 2, :] - T[..., 1, :], dim=-1)
        rho3d = (qv[..., 0] ** 2 + qv[..., 1] ** 2) / qv[..., 2] ** 2
        c2d = Hm[0, :, :2, 2] / Hm[0, :, 2, 2:3]
        rho2d = 2 * ((pix[None] - c2d[:, None, None]) ** 2).sum(-1)
        alpha2 = s.opacities[:, None, None] * torch.exp(-0.5 * torch.minimum(rho3d, rho2d))
        vis = radius[0] > 0
        assert _dense_alpha_outside_box(alpha2[vis], eff2[0][vis], W, H) < 1 / 255


def test_automatic_chunks_respect_the_budget(monkeypatch):
    """A tiny pair-pixel budget splits the work into many chunks without changing the image."""
    from arcsem.backbones.gaussians import raster
    from arcsem.backbones.gs2d.render import render_2dgs

    s = random_splats(15, 2, seed=6)
    cams = orbit_cameras(2, 20, 16)
    full = render_2dgs(*[p.detach() for p in s.params(2)], cams, tile=4)
    sizes = []
    original = raster._expand

    def spy(b, p0, p1, *args):
        out = original(b, p0, p1, *args)
        sizes.append(p1 - p0)
        return out

    monkeypatch.setattr(raster, "PAIR_PIXEL_BUDGET", 64)
    monkeypatch.setattr(raster, "_expand", spy)
    small = render_2dgs(*[p.detach() for p in s.params(2)], cams, tile=4)
    assert len(sizes) > 5
    for k in ("rgb", "alpha", "depth", "median_depth", "normal", "distortion"):
        torch.testing.assert_close(small[k], full[k], rtol=1e-12, atol=1e-12)
