"""Plenoxels beyond the grid: background models, grid bounds from the frusta, the point-cloud start, the
sparse RMSProp, and float64 parity of the whole render (grid + background + ACT) between the two paths."""
from __future__ import annotations

import pytest
import torch
from arcsem.backbones.plenoxels.background import MSIBackground, PlaneBackground
from arcsem.backbones.plenoxels.bounds import grid_bounds
from arcsem.backbones.plenoxels.optim import SparseRMSprop
from test_plenoxels import make, small_scene, with_ball
from torch.func import functional_call

from arcsem.scene import Scene, Split

F64 = torch.float64
UP = torch.tensor([0.0, 0.0, 1.0])
BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def _rays(n, origin, towards, spread, seed=0):
    g = torch.Generator().manual_seed(seed)
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=F64) * spread
                                      + torch.tensor(towards, dtype=F64), dim=-1)
    return torch.tensor(origin, dtype=F64) + 0.5 * torch.randn(n, 3, generator=g, dtype=F64), d


def test_plane_reads_its_texture_where_rays_hit_and_the_constant_elsewhere():
    bg = PlaneBackground(BOX, UP, [0.2, 0.2, 0.2], True, reso=9, degree=0).double()
    with torch.no_grad():  # the texel at s = (0.5, 0) of a 9x9 texture over [-1, 1]^2 (column 6, row 4)
        bg.texture[0, :, 4, 6] = torch.tensor([1.0, -0.5, 0.0], dtype=F64) / 0.28209479177387814
    e1 = bg.frame[1].double()  # in-plane axis of the texture's x
    o = torch.stack([e1 + torch.tensor([0, 0, 5.0], dtype=F64), torch.tensor([0, 0, 5.0], dtype=F64),
                     torch.tensor([0, 0, 5.0], dtype=F64)])
    d = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]], dtype=F64)
    front, back = bg(o, d)
    assert front is None
    # plane z = -1 (the box's bottom); x = 1 = c contracts to s = 1 / (1 + 1) = 0.5; colour SH . basis + 0.5
    torch.testing.assert_close(back[0], torch.tensor([1.5, 0.0, 0.5], dtype=F64))
    torch.testing.assert_close(back[1], torch.full((3,), 0.5, dtype=F64))  # zero texels: grey
    torch.testing.assert_close(back[2], torch.full((3,), 0.2, dtype=F64), atol=1e-6, rtol=0)  # upwards: the constant


@pytest.mark.parametrize("kind", ["plane", "msi"])
def test_background_gradients(kind):
    if kind == "plane":
        bg = PlaneBackground(BOX, UP, [0.2, 0.3, 0.4], True, reso=5, degree=1).double()
        name, o, d = "texture", *_rays(9, [0.0, 0.0, 4.0], [0.0, 0.0, -1.0], 0.3)
    else:
        bg = MSIBackground(BOX, UP, torch.tensor([0.0, -1.0, 0.0]), [0.2, 0.3, 0.4], True, reso=8, layers=3,
                           far=4.0).double()
        name, o, d = "layers", *_rays(9, [0.0, -6.0, 0.3], [0.0, 1.0, 0.0], 0.15)
    param = (0.5 * torch.randn(getattr(bg, name).shape, dtype=F64)).requires_grad_()

    def f(p, logit):
        front, back = functional_call(bg, {name: p, "const_logit": logit}, (o, d))
        return back if front is None else torch.cat([front, back], -1)

    logit = torch.zeros(3, dtype=F64, requires_grad=True)
    out = f(param, logit)
    assert out.abs().sum() > 0
    assert torch.autograd.gradcheck(f, (param, logit), atol=1e-6)


def _arc(axis: str, degrees, elevation: float = 0.0):
    """Orthographic cameras ``[C]`` looking at the origin: a tilt series about the image-vertical world ``x``
    (``axis="tilt"``, views about ``+z``) or an azimuth arc about ``z`` at ``elevation`` (``axis="azimuth"``)."""
    from arcsem.cameras import Cameras, look_at

    a, el = torch.deg2rad(torch.tensor(degrees, dtype=F64)), torch.deg2rad(torch.tensor(elevation, dtype=F64))
    if axis == "tilt":
        eye = torch.stack([torch.zeros_like(a), 5 * torch.sin(a), 5 * torch.cos(a)], -1)
        w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([1.0, 0.0, 0.0], dtype=F64))
    else:
        eye = 5 * torch.stack([torch.cos(el) * torch.cos(a), torch.cos(el) * torch.sin(a), torch.sin(el).expand_as(a)], -1)
        w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, 0.0, 1.0], dtype=F64))
    K = torch.tensor([[10.0, 0, 16], [0, 10.0, 16], [0, 0, 1]], dtype=F64).repeat(len(a), 1, 1)
    return Cameras(w2c.float(), K.float(), 32, 32, "orthographic", image_ids=torch.arange(len(a)))


def test_plane_faces_a_single_axis_tilt_series():
    from arcsem.backbones.plenoxels.background import build_background
    from arcsem.backbones.plenoxels.config import PlenoxelsConfig

    from arcsem.orbit import orbit_frame

    cams = _arc("tilt", [-6.0, 0.0, 6.0])  # the real DSA series' geometry: 3 views, 6 degrees apart
    assert abs(float(orbit_frame(cams, BOX).up[0])) > 0.99  # the orbit's vertical is the tilt axis ...
    cfg = PlenoxelsConfig(background_model="plane", background=[0.2, 0.2, 0.2], background_reso=8)
    bg = build_background(cfg, BOX, cams).double()
    back = -cams.forward.double()
    assert (back @ bg.frame[3].double()).min() > 0.99  # ... the plane's normal points at every camera
    o, d = cams.rays()
    _, col = bg(o.reshape(-1, 3).double(), d.reshape(-1, 3).double())
    torch.testing.assert_close(col, torch.full_like(col, 0.5))  # every ray sees the (zero: grey) texture


@pytest.mark.parametrize("elevation", [10.0, 40.0])
def test_plane_of_an_azimuth_arc_lies_on_its_vertical(elevation):
    from arcsem.backbones.plenoxels.background import plane_normal

    from arcsem.orbit import orbit_frame

    cams = _arc("azimuth", [-150.0, -110.0, -70.0, -30.0], elevation)  # the built-in scene's horizontal arc
    n = plane_normal(cams, orbit_frame(cams, BOX).up)
    torch.testing.assert_close(n, torch.tensor([0.0, 0.0, 1.0], dtype=F64), atol=1e-6, rtol=0)


def test_msi_puts_near_crossings_in_front_and_far_ones_behind():
    bg = MSIBackground(BOX, UP, torch.tensor([0.0, -1.0, 0.0]), [0.0, 0.0, 1.0], False, reso=8, layers=1,
                       far=4.0).double()
    with torch.no_grad():
        bg.layers[0, :3] = torch.tensor([10.0, -10.0, -10.0], dtype=F64)[:, None, None, None]  # red
        bg.layers[0, 3] = 0.0  # opacity 0.5
    o = torch.tensor([[0.0, -8.0, 0.0], [0.0, 0.0, 0.0]], dtype=F64)
    d = torch.tensor([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]], dtype=F64)
    front, back = bg(o, d)
    red = torch.sigmoid(torch.tensor([10.0, -10.0, -10.0], dtype=F64))
    torch.testing.assert_close(front[0], torch.cat([0.5 * red, torch.tensor([0.5], dtype=F64)]))
    torch.testing.assert_close(back[0], 0.5 * red + 0.5 * torch.tensor([0.0, 0.0, 1.0], dtype=F64))
    assert front[1, 3] == 0  # a ray starting inside the sphere crosses it once, behind
    torch.testing.assert_close(back[1], back[0])


def test_whole_render_float64_parity_of_the_two_paths_with_background_and_act():
    """rgb of render_rays, and gradients of density, SH, the plane's texture and constant, and ACT."""
    from test_plenoxels_fused import _cpp_or_skip

    from arcsem.act import ACT

    _cpp_or_skip()
    scene = small_scene(n=3, w=16, h=12)
    act = ACT(3, mode="rgb", init_noise=0.2).double()
    over = {"background_model": "plane", "learn_background": True, "background_reso": 8, "lambda_tv": 0.0,
            "lambda_tv_sh": 0.0}
    a, b = make(scene, act=act, rasterizer="torch", **over), make(scene, act=act, rasterizer="cpp", **over)
    with_ball(a, sigma=6.0)
    with torch.no_grad():
        a.sh.normal_(0, 0.3, generator=torch.Generator().manual_seed(1))
        a.background.texture.normal_(0, 0.3, generator=torch.Generator().manual_seed(2))
    b.load_state_dict(a.state_dict())
    a.double(), b.double()
    o, d = (t.reshape(-1, 3).double() for t in scene.train.cameras.rays())
    ids = scene.train.cameras.image_ids[:, None].expand(3, 16 * 12).reshape(-1)
    # the plane faces the views: every ray hits it; rays turned away from it see the constant
    o, d, ids = torch.cat([o, o[::8]]), torch.cat([d, -d[::8]]), torch.cat([ids, ids[::8]])
    res = []
    for bb in (a, b):
        out = bb.render_rays(o, d, ids)
        params = (bb.density, bb.sh, bb.background.texture, bb.background.const_logit, act.weight, act.bias)
        grads = torch.autograd.grad((out["rgb"] * torch.tensor([1.0, -2.0, 0.5], dtype=F64)).sum(), params)
        res.append((out["rgb"], [g.to_dense() if g.is_sparse else g for g in grads]))
    torch.testing.assert_close(res[1][0], res[0][0], atol=1e-12, rtol=0)
    for gc, gt in zip(res[1][1], res[0][1]):
        assert gt.abs().sum() > 0
        torch.testing.assert_close(gc, gt, atol=1e-10, rtol=1e-10)


def test_sparse_rmsprop_updates_only_the_rows_it_is_given():
    g = torch.Generator().manual_seed(3)
    p0 = torch.randn(6, 2, generator=g)
    p, q = p0.clone().requires_grad_(), p0.clone().requires_grad_()
    sparse, dense = SparseRMSprop([p], lr=0.1, alpha=0.9), torch.optim.RMSprop([q], lr=0.1, alpha=0.9, eps=1e-8)
    rows = torch.tensor([4, 1, 4])  # row 4 twice: an uncoalesced sum (marcher + TV)
    vals = torch.randn(3, 2, generator=g)
    p.grad = torch.sparse_coo_tensor(rows[None], vals, (6, 2), check_invariants=True)
    q.grad = torch.zeros(6, 2).index_add_(0, rows, vals)
    sparse.step()
    dense.step()
    touched = torch.tensor([1, 4])
    torch.testing.assert_close(p[touched], q[touched])
    torch.testing.assert_close(sparse.state[p]["square_avg"], dense.state[q]["square_avg"])
    assert torch.equal(p.detach()[[0, 2, 3, 5]], p0[[0, 2, 3, 5]])


def test_grid_bounds_keep_the_points_every_view_sees():
    from arcsem.cameras import Cameras, look_at

    ang = torch.linspace(-0.3, 0.3, 4)
    eye = torch.stack([5 * torch.sin(ang), torch.zeros(4), -5 * torch.cos(ang)], -1)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0]))
    K = torch.tensor([[100.0, 0, 20], [0, 100.0, 15], [0, 0, 1]]).repeat(4, 1, 1)  # 2 x 1.5 units at the origin
    cams = Cameras(w2c, K, 40, 30, "pinhole", image_ids=torch.arange(4))
    g = torch.Generator().manual_seed(0)
    specimen = 1.2 * (torch.rand(2000, 3, generator=g) - 0.5)  # a cube at the origin ...
    stub = torch.cat([20 * torch.rand(2000, 2, generator=g) - 10, torch.full((2000, 1), 0.6)], 1)[:, [0, 2, 1]]
    pts = torch.cat([specimen, stub])  # ... on a 20 x 20 plane y = 0.6 that the views see only in part
    img = torch.zeros(4, 30, 40, 3)
    sc = Scene("s", Split(list("abcd"), cams, img), Split([], cams[[]], img[:0]), torch.tensor([[-10.0] * 3, [10.0] * 3]),
               points=pts, bounds_source="points")
    box = grid_bounds(sc)
    assert (box[0] < -0.55).all() and (box[1] > 0.55).all()  # the specimen
    assert (box[1] - box[0]).max() < 3.5  # and the stub under it, not its 20 units
    assert torch.equal(grid_bounds(Scene(**{**sc.__dict__, "bounds_source": "given"})), sc.bounds)


def test_density_starts_from_the_point_cloud():
    scene = small_scene()
    pts = torch.tensor([[0.0, 0.0, 0.0], [0.3, -0.2, 0.1]])
    scene = Scene(**{**scene.__dict__, "points": pts})
    bb = make(scene, reso=[[13, 13, 13]], init_points_sigma=10.0, init_sigma=-1.0, init_points_dilate=1)
    dense = torch.full((13, 13, 13), -1.0)
    for p in pts:
        c = torch.round((p + 0.6) / 0.1).long()
        dense[c[0] - 1 : c[0] + 2, c[1] - 1 : c[1] + 2, c[2] - 1 : c[2] + 2] = 10.0
    assert torch.equal(bb.density.detach().reshape(13, 13, 13), dense)
