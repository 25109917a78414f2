"""2DGS rasteriser: values and gradients against the dense reference, gradcheck, chunking, ortho limit."""
import itertools

import pytest
import torch
from arcsem.backbones.gaussians.raster_scenes import orbit_cameras, random_splats
from arcsem.backbones.gs2d.reference import render_2dgs_dense
from arcsem.backbones.gs2d.render import distortion_depth, render_2dgs, splat_homographies

from arcsem.errors import ArcsemError

OUTS = ["rgb", "alpha", "depth", "median_depth", "normal", "distortion"]


def hard_scene(N=20, C=2, seed=0):
    """Random splats plus a stack in front of each other (early termination) and opacity-clamped ones."""
    s = random_splats(N, C, seed=seed)
    s.means[:5] = torch.tensor([0.05, -0.02, 0.0], dtype=torch.float64) + torch.linspace(-0.3, 0.3, 5)[:, None] * \
        torch.tensor([0.02, 0.01, 1.0], dtype=torch.float64)
    s.scales[:5] = 0.25
    s.quats[:5] = torch.tensor([1.0, 0.05, -0.04, 0.02], dtype=torch.float64)
    s.opacities[:5] = torch.tensor([0.93, 0.999, 0.96, 0.9, 0.97], dtype=torch.float64)
    s.opacities[7] = 0.995
    return s


def rel_err(a, b):
    return ((a - b).abs().max() / b.abs().max().clamp_min(1e-12)).item()


def compare(s, cams, tile, chunk_tiles=None, background=None, dist_depth=None, **kw):
    pa, pb = s.params(2), s.params(2)
    a = render_2dgs(*pa, cams, tile=tile, chunk_tiles=chunk_tiles, background=background, dist_depth=dist_depth, **kw)
    b = render_2dgs_dense(*pb, cams, tile=tile, background=background, dist_depth=dist_depth, **kw)
    g = torch.Generator().manual_seed(1)
    loss_a = loss_b = 0.0
    for k in OUTS:
        assert rel_err(a[k], b[k]) < 1e-6, k
        wgt = torch.rand(b[k].shape, generator=g, dtype=torch.float64)
        loss_a, loss_b = loss_a + (a[k] * wgt).sum(), loss_b + (b[k] * wgt).sum()
    ga = torch.autograd.grad(loss_a, pa)
    gb = torch.autograd.grad(loss_b, pb)
    for name, x, y in zip(["means", "quats", "scales", "opacities", "colors"], ga, gb):
        assert rel_err(x, y) < 1e-6, name
    return a, b


@pytest.mark.parametrize("ortho", [False, True])
@pytest.mark.parametrize("tile,mode", [(8, "ndc"), (16, "ndc"), (16, "linear")])
def test_matches_dense_reference(ortho, tile, mode):
    s = hard_scene()
    cams = orbit_cameras(2, 20, 16, ortho=ortho)
    a, b = compare(s, cams, tile, background=torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64),
                   dist_depth=distortion_depth(mode, 0.7))
    assert b["alpha"].max() > 0.999  # some pixels are early-terminated (T would fall below 1e-4)
    assert (b["alpha"] == 0).any()  # and some pixels see nothing
    assert a["visible"].sum() >= 15 and (a["radii"][a["visible"]] > 0).all()


@pytest.mark.parametrize("sigma", [0.3, 1.5])
def test_lowpass_sigma_matches_dense_reference(sigma):
    """A low-pass filter narrower and wider than the official 1/sqrt(2) px: values and gradients (the centre
    gradient of the 2-D fallback scales with 1/sigma^2) match the dense reference; tiny splats are drawn."""
    s = hard_scene(seed=4)
    s.scales[10:] = 0.004  # sub-pixel splats: drawn by the 2-D filter alone
    a, _ = compare(s, orbit_cameras(2, 20, 16), 8, lowpass_sigma=sigma)
    assert a["alpha"].max() > 0.5


def test_lowpass_sigma_is_the_screen_sigma_of_a_tiny_splat():
    """A splat far below a pixel is drawn as ``o exp(-d^2 / (2 sigma^2))`` of the distance ``d`` (pixels) from
    its projected centre, down to the 1/255 alpha cut-off within its 3-sigma footprint: it grows with sigma."""
    cams = orbit_cameras(1, 41, 41, focal=40.0)
    f64 = {"dtype": torch.float64}
    centre = torch.tensor([[0.013, -0.021, 0.0]], **f64)  # off the pixel grid
    c2d, _ = cams.project(centre)
    ys, xs = torch.meshgrid(torch.arange(41, **f64) + 0.5, torch.arange(41, **f64) + 0.5, indexing="ij")
    d2 = (xs - c2d[0, 0, 0]) ** 2 + (ys - c2d[0, 0, 1]) ** 2
    drawn = []
    for sigma in (0.35, 0.7071, 1.4):
        with torch.no_grad():
            out = render_2dgs(centre, torch.tensor([[1.0, 0.0, 0.0, 0.0]], **f64), torch.full((1, 2), 1e-6, **f64),
                              torch.tensor([0.8], **f64), torch.ones(1, 3, **f64), cams, tile=8, lowpass_sigma=sigma)
        a = out["alpha"][0, ..., 0]
        want = 0.8 * torch.exp(-0.5 * d2 / sigma**2)
        want = torch.where(want >= 1 / 255, want, torch.zeros_like(want))
        inside = d2 <= (3 * sigma) ** 2  # the footprint radius is 3 sigma (official): beyond it a tile may cut
        torch.testing.assert_close(a[inside], want[inside], rtol=1e-9, atol=1e-12)
        assert ((a[~inside] == 0) | ((a[~inside] - want[~inside]).abs() < 1e-12)).all()
        drawn.append(int((a > 0).sum()))
    assert drawn[0] < drawn[1] < drawn[2], drawn


def test_tile_grid_edges_and_straddling():
    """Splats straddling tile borders and the image border, a non-multiple-of-tile image size."""
    s = random_splats(16, 1, seed=3, extent=1.6, scale=(0.05, 0.3))
    compare(s, orbit_cameras(1, 21, 13), tile=4)


def test_chunked_equals_unchunked():
    s = hard_scene(seed=2)
    cams = orbit_cameras(2, 20, 16)
    pa, pb = s.params(2), s.params(2)
    a = render_2dgs(*pa, cams, tile=4, chunk_tiles=1)
    b = render_2dgs(*pb, cams, tile=4, chunk_tiles=None)
    for k in OUTS:
        torch.testing.assert_close(a[k], b[k], rtol=1e-12, atol=1e-12)
    ga = torch.autograd.grad(sum(a[k].sum() for k in OUTS), pa)
    gb = torch.autograd.grad(sum(b[k].sum() for k in OUTS), pb)
    for x, y in zip(ga, gb):
        torch.testing.assert_close(x, y, rtol=1e-10, atol=1e-12)


def test_gradcheck_tiny():
    s = random_splats(4, 1, seed=5, scale=(0.15, 0.3), opacity=(0.3, 0.8))
    cams = orbit_cameras(1, 8, 8, focal=10.0)

    def f(*p):
        out = render_2dgs(*p, cams, tile=4)
        return tuple(out[k] for k in OUTS)

    assert torch.autograd.gradcheck(f, tuple(s.params(2)), eps=1e-6, atol=1e-5, fast_mode=True)


def _shift_back(cams_o, d, d0):
    """Pinhole camera pushed back by ``d`` along its axis, focal scaled so the magnification at d0 holds."""
    pin = orbit_cameras(len(cams_o), cams_o.width, cams_o.height)
    pin.world_to_cam = cams_o.world_to_cam.clone()
    pin.world_to_cam[:, 2, 3] += d
    pin.K = cams_o.K.clone()
    pin.K[:, :2, :2] *= d0 + d
    return pin


def test_orthographic_is_limit_of_far_pinhole():
    s = random_splats(12, 1, seed=7)
    ortho = orbit_cameras(1, 20, 16, ortho=True)
    o = render_2dgs(*s.params(2), ortho)
    errs = []
    for d in [1e2, 1e3, 1e4, 1e5]:
        p = render_2dgs(*s.params(2), _shift_back(ortho, d, 3.0))
        depth_err = ((p["depth"] - d - o["depth"]) * (o["alpha"] > 0) * (p["alpha"] > 0)).abs().max()
        errs.append(max((p["rgb"] - o["rgb"]).abs().max().item(), depth_err.item(),
                        (p["normal"] - o["normal"]).abs().max().item()))
    assert all(e2 < e1 for e1, e2 in itertools.pairwise(errs)), errs
    assert errs[-1] < 1e-4 and o["alpha"].max() > 0.5


def test_homography_matches_ray_plane_intersection():
    """The centre of a splat projects to T's third column, for both camera models."""
    s = random_splats(5, 1, seed=1)
    for ortho in (False, True):
        cams = orbit_cameras(1, 20, 16, ortho=ortho)
        H, _ = splat_homographies(s.means, s.quats, s.scales[:, :2], cams)
        uv, z = cams.project(s.means)
        torch.testing.assert_close(H[..., :2, 2] / H[..., 2, 2:3], uv)
        torch.testing.assert_close(H[..., 3, 2], z)


def test_near_culling_and_unknown_impl():
    s = random_splats(6, 1, seed=4)
    s.means[0] = torch.tensor([0.0, 0.0, -3.5], dtype=torch.float64)  # behind the camera at z=-3
    cams = orbit_cameras(1, 20, 16)
    out = render_2dgs(*s.params(2), cams)
    assert not out["visible"][0, 0] and out["radii"][0, 0] == 0 and out["visible"][0, 1:].any()
    assert out["radii"].dtype == torch.long
    with pytest.raises(ArcsemError):
        render_2dgs(*s.params(2), cams, impl="gpu")


def test_float32_close_to_float64():
    s = hard_scene()
    cams = orbit_cameras(2, 20, 16)
    a = render_2dgs(*[p.detach().float() for p in s.params(2)], cams.to(dtype=torch.float32))
    b = render_2dgs(*[p.detach() for p in s.params(2)], cams)
    for k in ["rgb", "alpha", "normal"]:
        assert a[k].dtype == torch.float32
        torch.testing.assert_close(a[k].double(), b[k], atol=1e-4, rtol=1e-4)


@pytest.mark.parametrize("ortho", [False, True])
def test_means2d_grad_is_screen_position_gradient(ortho):
    """Moving every splat by eps pixels in x equals moving the principal point: sum of means2d.grad."""
    s = random_splats(10, 1, seed=9)
    cams = orbit_cameras(1, 20, 16, ortho=ortho)
    wgt = torch.rand(1, 16, 20, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    out = render_2dgs(*s.params(2), cams)
    (out["rgb"] * wgt).sum().backward()
    eps, losses = 1e-6, []
    for sign in (1, -1):
        c = orbit_cameras(1, 20, 16, ortho=ortho)
        c.K[:, 0, 2] += sign * eps
        with torch.no_grad():
            losses.append((render_2dgs(*s.params(2), c)["rgb"] * wgt).sum())
    fd = (losses[0] - losses[1]) / (2 * eps)
    torch.testing.assert_close(out["means2d"].grad[..., 0].sum(), fd, rtol=1e-5, atol=1e-8)


def test_rotate_by_quat_old_path_warns():
    """``rotate_by_quat`` moved to the gaussians package (issue 41); its old public path works, with a warning."""
    import arcsem.backbones.gs2d.reference as old
    from arcsem.backbones.gaussians.dense import rotate_by_quat

    with pytest.warns(DeprecationWarning, match="moved to arcsem.backbones.gaussians.dense.rotate_by_quat"):
        assert old.rotate_by_quat is rotate_by_quat
