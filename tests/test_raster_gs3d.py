"""3DGS rasteriser: values and gradients against the dense reference, gradcheck, chunking, ortho limit."""
import itertools

import pytest
import torch
from arcsem.backbones.gaussians.raster_scenes import orbit_cameras, random_splats
from arcsem.backbones.gs3d.reference import render_3dgs_dense
from arcsem.backbones.gs3d.render import project_gaussians, render_3dgs

from arcsem.errors import ArcsemError

OUTS = ["rgb", "alpha", "depth"]


def hard_scene(N=20, C=2, seed=0):
    """Random Gaussians plus a stack along the view axis (early termination) and opacity-clamped ones."""
    s = random_splats(N, C, seed=seed)
    s.means[:5] = torch.tensor([0.05, -0.02, 0.0], dtype=torch.float64) + torch.linspace(-0.3, 0.3, 5)[:, None] * \
        torch.tensor([0.02, 0.01, 1.0], dtype=torch.float64)
    s.scales[:5] = 0.2
    s.opacities[:5] = torch.tensor([0.93, 0.999, 0.96, 0.9, 0.97], dtype=torch.float64)
    s.opacities[7] = 0.995
    return s


def rel_err(a, b):
    return ((a - b).abs().max() / b.abs().max().clamp_min(1e-12)).item()


@pytest.mark.parametrize("ortho", [False, True])
@pytest.mark.parametrize("tile", [8, 16])
def test_matches_dense_reference(ortho, tile):
    s = hard_scene()
    cams = orbit_cameras(2, 20, 16, ortho=ortho)
    bg = torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64)
    pa, pb = s.params(3), s.params(3)
    a = render_3dgs(*pa, cams, tile=tile, background=bg)
    b = render_3dgs_dense(*pb, cams, tile=tile, background=bg)
    g = torch.Generator().manual_seed(1)
    la = lb = 0.0
    for k in OUTS:
        assert rel_err(a[k], b[k]) < 1e-6, k
        wgt = torch.rand(b[k].shape, generator=g, dtype=torch.float64)
        la, lb = la + (a[k] * wgt).sum(), lb + (b[k] * wgt).sum()
    for name, x, y in zip(["means", "quats", "scales", "opacities", "colors"],
                          torch.autograd.grad(la, pa), torch.autograd.grad(lb, pb)):
        assert rel_err(x, y) < 1e-6, name
    assert b["alpha"].max() > 0.999 and (b["alpha"] == 0).any()


def test_chunked_equals_unchunked():
    s = hard_scene(seed=2)
    cams = orbit_cameras(2, 20, 16)
    pa, pb = s.params(3), s.params(3)
    a = render_3dgs(*pa, cams, tile=4, chunk_tiles=1)
    b = render_3dgs(*pb, cams, tile=4)
    for k in OUTS:
        torch.testing.assert_close(a[k], b[k], rtol=1e-12, atol=1e-12)
    ga = torch.autograd.grad(sum(a[k].sum() for k in OUTS), pa)
    gb = torch.autograd.grad(sum(b[k].sum() for k in OUTS), pb)
    for x, y in zip(ga, gb):
        torch.testing.assert_close(x, y, rtol=1e-10, atol=1e-12)


def test_gradcheck_tiny():
    s = random_splats(4, 1, seed=5, scale=(0.1, 0.25), opacity=(0.3, 0.8))
    cams = orbit_cameras(1, 8, 8, focal=10.0)

    def f(*p):
        out = render_3dgs(*p, cams, tile=4)
        return tuple(out[k] for k in OUTS)

    assert torch.autograd.gradcheck(f, tuple(s.params(3)), eps=1e-6, atol=1e-5, fast_mode=True)


def test_orthographic_is_limit_of_far_pinhole():
    s = random_splats(12, 1, seed=7)
    ortho = orbit_cameras(1, 20, 16, ortho=True)
    o = render_3dgs(*s.params(3), ortho)
    errs = []
    for d in [1e2, 1e3, 1e4, 1e5]:
        pin = orbit_cameras(1, 20, 16)
        pin.world_to_cam = ortho.world_to_cam.clone()
        pin.world_to_cam[:, 2, 3] += d
        pin.K = ortho.K.clone()
        pin.K[:, :2, :2] *= 3.0 + d
        p = render_3dgs(*s.params(3), pin)
        depth_err = ((p["depth"] - d - o["depth"]) * (o["alpha"] > 0) * (p["alpha"] > 0)).abs().max()
        errs.append(max((p["rgb"] - o["rgb"]).abs().max().item(), depth_err.item()))
    assert all(e2 < e1 for e1, e2 in itertools.pairwise(errs)), errs
    assert errs[-1] < 1e-4 and o["alpha"].max() > 0.5


def test_projection_hand_values():
    """An isotropic Gaussian at depth 2 on the axis of a pinhole camera with f = 10: sigma_px = f s / z."""
    cams = orbit_cameras(1, 20, 16, focal=10.0)
    cams.world_to_cam = torch.eye(4, dtype=torch.float64)[None].clone()
    cams.world_to_cam[0, 2, 3] = 2.0
    means = torch.zeros(1, 3, dtype=torch.float64)
    quats = torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64)
    m2, z, cov = project_gaussians(means, quats, torch.full((1, 3), 0.1, dtype=torch.float64), cams)
    torch.testing.assert_close(m2[0, 0], torch.tensor([10.0, 8.0], dtype=torch.float64))
    assert z.item() == 2.0
    # (10 * 0.1 / 2)^2 + 0.3 = 0.55
    torch.testing.assert_close(cov[0, 0], torch.diag(torch.tensor([0.55, 0.55], dtype=torch.float64)))
    out = render_3dgs(means, quats, torch.full((1, 3), 0.1, dtype=torch.float64),
                      torch.tensor([0.5], dtype=torch.float64), torch.ones(1, 3, dtype=torch.float64), cams)
    assert out["radii"][0, 0] == 3  # ceil(3 sqrt(0.55)) = ceil(2.22)
    # pixel (9, 7) has centre (9.5, 7.5): d = (-0.5, -0.5), alpha = 0.5 exp(-0.5 * 0.5 / 0.55)
    expected = 0.5 * torch.exp(torch.tensor(-0.25 / 0.55, dtype=torch.float64))
    torch.testing.assert_close(out["alpha"][0, 7, 9, 0], expected)
    torch.testing.assert_close(out["depth"][0, 7, 9, 0], torch.tensor(2.0, dtype=torch.float64))


def test_near_culling_and_unknown_impl():
    s = random_splats(6, 1, seed=4)
    s.means[0] = torch.tensor([0.0, 0.0, -3.5], dtype=torch.float64)
    cams = orbit_cameras(1, 20, 16)
    out = render_3dgs(*s.params(3), cams)
    assert not out["visible"][0, 0] and out["radii"][0, 0] == 0 and out["visible"][0, 1:].any()
    with pytest.raises(ArcsemError):
        render_3dgs(*s.params(3), cams, impl="gpu")


def test_means2d_grad_is_screen_position_gradient():
    s = random_splats(10, 1, seed=9)
    cams = orbit_cameras(1, 20, 16)
    wgt = torch.rand(1, 16, 20, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    out = render_3dgs(*s.params(3), cams)
    (out["rgb"] * wgt).sum().backward()
    eps, losses = 1e-6, []
    for sign in (1, -1):
        c = orbit_cameras(1, 20, 16)
        c.K[:, 1, 2] += sign * eps
        with torch.no_grad():
            losses.append((render_3dgs(*s.params(3), c)["rgb"] * wgt).sum())
    fd = (losses[0] - losses[1]) / (2 * eps)
    torch.testing.assert_close(out["means2d"].grad[..., 1].sum(), fd, rtol=1e-5, atol=1e-8)
