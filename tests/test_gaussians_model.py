"""Gaussian backbones without the rasteriser (a tiny dense stand-in), plus the render contract."""
from __future__ import annotations

import importlib.util
import math

import pytest
import torch
from arcsem.backbones.gaussians.init import init_gaussians, knn_scales
from arcsem.backbones.gaussians.model import active_sh_degree_at
from arcsem.backbones.sh import C0, eval_sh

from arcsem.act import ACT
from arcsem.cameras import Cameras, look_at
from arcsem.plugins import BACKBONES
from arcsem.registry import validate_config
from arcsem.rotations import quat_to_rotmat
from arcsem.scene import Scene, Split

SHAPES = {"rgb": 3, "alpha": 1, "depth": 1, "median_depth": 1, "normal": 3, "distortion": 1}


def scene_of(model: str = "pinhole", n: int = 3, w: int = 12, h: int = 8, points: int = 40) -> Scene:
    g = torch.Generator().manual_seed(0)
    ang = torch.linspace(-0.4, 0.4, n)
    eye = torch.stack([4 * torch.sin(ang), torch.full_like(ang, -0.5), -4 * torch.cos(ang)], -1)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0]))
    f = 15.0 if model == "pinhole" else 4.0
    K = torch.tensor([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]]).repeat(n, 1, 1)
    cams = Cameras(w2c, K, w, h, model, image_ids=torch.arange(n))
    img = torch.rand(n, h, w, 3, generator=g)
    pts = (torch.rand(points, 3, generator=g) - 0.5) if points else None
    return Scene("t", Split([f"v{i}" for i in range(n)], cams, img), Split([], cams[[]], img[:0]),
                 torch.tensor([[-0.6] * 3, [0.6] * 3]), points=pts)


def fake_raster(means, quats, scales, opacities, colors, cams, *, background=None, **kw):
    """Every splat is an isotropic 1.5 px blob at its projected centre, summed (no occlusion)."""
    uv, _ = cams.project(means)  # [C, N, 2]
    pix = cams.pixel_grid(means.dtype).reshape(-1, 2)  # [P, 2]
    wgt = torch.exp(-((pix[None, :, None] - uv[:, None]) ** 2).sum(-1) / 4.5) * opacities  # [C, P, N]
    rgb = (wgt @ colors).reshape(len(cams), cams.height, cams.width, 3)
    alpha = wgt.sum(-1).clamp(max=1).reshape(len(cams), cams.height, cams.width, 1)
    C, N = uv.shape[:2]
    return {"rgb": rgb, "alpha": alpha, "depth": alpha * 0 + 1, "colors_in": colors,
            "radii": torch.full((C, N), 3, dtype=torch.long), "visible": torch.ones(C, N, dtype=torch.bool)}


def build(name: str, scene: Scene, act=None, fake: bool = True, **cfg):
    cls = BACKBONES.get(name)
    torch.manual_seed(0)
    bb = cls(validate_config(cls.Config, cfg, where=name), scene=scene, act=act)
    if fake:
        bb._rasterize = fake_raster
    return bb


# ---------------------------------------------------------------- init and model
def test_knn_scale_and_init_values():
    grid = torch.stack(torch.meshgrid(*[torch.arange(4.0)] * 3, indexing="ij"), -1).reshape(-1, 3) * 0.5
    torch.testing.assert_close(knn_scales(grid), torch.full((64,), 0.5, dtype=torch.float32))
    pts = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]])
    # point 0: neighbours at 1, 2, 3 -> sqrt((1 + 4 + 9) / 3)
    assert knn_scales(pts)[0] == pytest.approx(math.sqrt(14 / 3))
    cols = torch.rand(4, 3)
    p = init_gaussians(pts, cols, num_scales=2, sh_degree=2)
    torch.testing.assert_close(torch.sigmoid(p["opacity_logits"]), torch.full((4,), 0.1))
    torch.testing.assert_close(p["sh_dc"][:, 0] * C0 + 0.5, cols)
    assert p["sh_rest"].shape == (4, 8, 3) and p["log_scales"].shape == (4, 2)
    assert (p["quats"] == torch.tensor([1.0, 0, 0, 0])).all()
    r = init_gaussians(pts, random_rotations=True)["quats"]
    torch.testing.assert_close(r.norm(dim=1), torch.ones(4))


def test_quat_to_rotmat_is_a_rotation_matching_axis_angle():
    q = torch.tensor([[math.cos(0.3), 0, 0, math.sin(0.3)]]) * 2.0  # 0.6 rad about z, unnormalised
    R = quat_to_rotmat(q)[0]
    c, s = math.cos(0.6), math.sin(0.6)
    torch.testing.assert_close(R, torch.tensor([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]))


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
def test_colors_use_view_directions(model):
    scene = scene_of(model)
    bb = build("gs3d", scene)
    m = bb.model
    with torch.no_grad():
        m.sh_rest.normal_()
    cams = scene.train.cameras
    m.set_active_sh_degree(3)
    col = m.colors(cams)
    if model == "pinhole":
        dirs = m.means[None] - cams.centers[:, None]
    else:
        dirs = cams.forward[:, None].expand(-1, len(m), -1)
    ref = (eval_sh(3, m.sh[None], dirs) + 0.5).clamp_min(0)
    torch.testing.assert_close(col, ref)
    m.set_active_sh_degree(0)
    torch.testing.assert_close(m.colors(cams), (m.sh_dc[None, :, 0] * C0 + 0.5).clamp_min(0).expand(3, -1, -1))


def test_sh_degree_grows_every_1000_steps_in_stage_one_only():
    assert [active_sh_degree_at(s, 3) for s in (0, 999, 1000, 2500, 10_000)] == [0, 0, 1, 2, 3]
    bb = build("gs2d", scene_of(), densify=False)
    bb.param_groups("geometry")
    bb.post_backward(999, {}, {})  # prepares iteration 1000
    assert int(bb.model.active_sh_degree) == 1
    bb.param_groups("color")
    bb.post_backward(0, {}, {})
    assert int(bb.model.active_sh_degree) == 1


def test_param_groups_and_learning_rates():
    scene = scene_of()
    bb = build("gs3d", scene)
    geo = bb.param_groups("geometry")
    assert sorted(geo) == sorted(["xyz", "f_dc", "f_rest", "opacity", "scaling", "rotation"])
    col = bb.param_groups("color")
    assert sorted(col) == ["f_dc", "f_rest"] and not bb.model.means.requires_grad
    assert bb.model.sh_dc.requires_grad
    ext = scene.extent
    from arcsem.train.optim import lr_at

    rates = bb.learning_rates("geometry")
    lr0, lr_end, lr_mid = (lr_at(rates["xyz"], s, 1) for s in (0, 30_000, 15_000))
    assert lr0 == pytest.approx(1.6e-4 * ext) and lr_end == pytest.approx(1.6e-6 * ext)
    assert lr_mid == pytest.approx(1.6e-5 * ext)  # log-linear: geometric mean halfway
    lrs = {g: lr_at(r, 0, 1) for g, r in rates.items()}
    assert sorted(bb.learning_rates("color")) == ["f_dc", "f_rest"]
    assert (lrs["f_dc"], lrs["f_rest"], lrs["opacity"], lrs["scaling"], lrs["rotation"]) == pytest.approx(
        (2.5e-3, 2.5e-3 / 20, 0.05, 0.005, 0.001))
    assert build("gs2d", scene).cfg.prune_opacity == 0.05 and bb.cfg.prune_opacity == 0.005


def test_random_init_without_point_cloud():
    scene = scene_of(points=0)
    bb = build("gs2d", scene, random_init_points=300)
    assert bb.num_primitives() == 300
    m = bb.model.means
    assert (m >= -0.6).all() and (m <= 0.6).all() and bb.model.log_scales.shape == (300, 2)


# ---------------------------------------------------------------- render plumbing, ACT, densification
def test_render_passes_act_colours_and_mean_act_for_novel_views():
    scene = scene_of()
    act = ACT(3, "rgb", init_noise=0.0)
    with torch.no_grad():
        act.weight.copy_(torch.tensor([[0.5] * 3, [1.0] * 3, [2.0] * 3]))
    bb = build("gs3d", scene, act=act)
    cams = scene.train.cameras[[0, 2]]
    base = bb.model.colors(cams)
    out = bb.render(cams)
    torch.testing.assert_close(out["colors_in"], act.apply(base, torch.tensor([0, 2])))
    cams.image_ids = torch.tensor([-1, -1])
    torch.testing.assert_close(bb.render(cams)["colors_in"], (base * 3.5 / 3).clamp(0, 1))


@pytest.mark.parametrize("fused", [None, True], ids=["loop", "fused"])  # the trainer's Adam is the fused one
def test_post_backward_densifies_and_optimizer_keeps_stepping(fused):
    scene = scene_of()
    bb = build("gs3d", scene)
    opt = torch.optim.Adam([{"params": ps, "name": g} for g, ps in bb.param_groups("geometry").items()], lr=1e-3,
                           fused=fused)
    n0 = bb.num_primitives()
    for step in range(598, 600):
        out = bb.render(scene.train.cameras[:1])
        ((out["rgb"] - 1) ** 2).sum().mul(1e3).backward()
        bb.post_backward(step, out, {"main": opt})  # step 599 = iteration 600: densify
        opt.step()
        opt.zero_grad()
    assert bb.num_primitives() > n0
    assert len(bb.stats) == bb.num_primitives() and bb.stats.count.sum() == 0
    assert opt.state[bb.model.means]["exp_avg"].shape == bb.model.means.shape
    for p in bb.parameters():  # parameters the stand-in renderer ignores have no state
        assert not opt.state[p] or opt.state[p]["exp_avg_sq"].shape == p.shape
    xyz_group = next(g for g in opt.param_groups if g["name"] == "xyz")
    assert xyz_group["lr"] == 1e-3  # the trainer owns the rates (train.optim.groups overrides hold)


def test_state_dict_survives_a_different_number_of_gaussians(tmp_path):
    scene = scene_of()
    a = build("gs2d", scene)
    with torch.no_grad():
        a.model.set_params({k: torch.cat([v, v[:5]]) for k, v in a.model.params().items()})
        a.model.set_params({"sh_rest": 0.3 * torch.randn_like(a.model.sh_rest)})  # colours that vary with the degree
    a.model.set_active_sh_degree(2)
    b = build("gs2d", scene_of(points=10), act=None)
    b.load_state_dict(a.state_dict())
    assert b.num_primitives() == 45 and int(b.model.active_sh_degree) == 2
    for k, v in a.model.params().items():
        torch.testing.assert_close(getattr(b.model, k), v)
    # the loaded model colours with the loaded degree (its host copy follows the buffer: a stage-2 model drew with
    # degree 0 once, 1 dB of colour lost)
    cams = scene.train.cameras
    torch.testing.assert_close(b.model.colors(cams), a.model.colors(cams))
    assert not torch.allclose(b.model.colors(cams), b.model.colors(cams, degree=0))
    with_act = build("gs2d", scene, act=ACT(3))
    b.load_state_dict(with_act.state_dict())  # stage 2 (no ACT) loads a stage-1 checkpoint
    with pytest.raises(RuntimeError):
        with_act.load_state_dict(b.state_dict())  # missing ACT entries are an error
    a.export(tmp_path / "m.ply")
    c = build("gs2d", scene_of(points=7))
    c.load_ply(tmp_path / "m.ply")
    for k, v in a.model.params().items():
        assert torch.equal(getattr(c.model, k).detach(), v.detach())


# ---------------------------------------------------------------- the real rasterisers
def _renderer_available(name: str) -> bool:
    return importlib.util.find_spec(f"arcsem.backbones.{name}.render") is not None


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
@pytest.mark.parametrize("name", ["gs2d", "gs3d"])
def test_render_contract_with_real_rasteriser(name, model):
    if not _renderer_available(name):
        pytest.skip(f"backbones/{name}/render.py not there yet")
    scene = scene_of(model)
    bb = build(name, scene, act=ACT(3), fake=False)
    cams = scene.train.cameras[:2]
    out = bb.render(cams)
    N = bb.num_primitives()
    for key in bb.provides:
        assert out[key].shape == (2, cams.height, cams.width, SHAPES[key]), key
        assert torch.isfinite(out[key]).all(), key
    assert out["radii"].shape == (2, N) and out["visible"].shape == (2, N) and out["visible"].dtype == torch.bool
    out["rgb"].sum().backward()
    assert bb.model.sh_dc.grad is not None and bb.act.weight.grad is not None


@pytest.mark.parametrize("radius", [1.0, 4.0, 60.0])
def test_scene_extent_is_the_camera_radius_capped_by_the_specimen(radius):
    """3DGS's 1.1 x camera radius for cameras near the specimen; 1.1 x bbox diagonal for far SEM cameras."""
    ang = torch.linspace(-math.pi / 2, math.pi / 2, 3)  # centres on a half circle: centroid off-centre
    eye = torch.stack([radius * torch.sin(ang), torch.zeros(3), -radius * torch.cos(ang)], -1)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0]))
    cams = Cameras(w2c, torch.tensor([[10.0, 0, 4], [0, 10.0, 4], [0, 0, 1]]).repeat(3, 1, 1), 8, 8, "pinhole")
    img = torch.zeros(3, 8, 8, 3)
    scene = Scene("t", Split(["a", "b", "c"], cams, img), Split([], cams[[]], img[:0]),
                  torch.tensor([[-0.5] * 3, [0.5] * 3]))
    centroid = eye.mean(0)
    cam_radius = 1.1 * float((eye - centroid).norm(dim=-1).max())
    box = 1.1 * math.sqrt(3.0)
    assert scene.extent == pytest.approx(min(cam_radius, box), rel=1e-6)
    assert (scene.extent == pytest.approx(box, rel=1e-6)) == (radius > 1.0)
    ortho = Scene("t", Split(["a", "b", "c"], Cameras(w2c, cams.K, 8, 8, "orthographic"), img), scene.test,
                  scene.bounds)
    assert ortho.extent == pytest.approx(box, rel=1e-6)


def test_gs2d_distortion_depth_is_linear_in_scene_units_by_default():
    """The distortion's normalised depth is z / extent (the official NDC one is a config choice): the
    backbone's distortion equals the rasteriser's with those coefficients, and a bad mode is refused."""
    if not _renderer_available("gs2d"):
        pytest.skip("backbones/gs2d/render.py not there yet")
    from arcsem.backbones.gs2d.render import distortion_depth, render_2dgs

    from arcsem.errors import ConfigError

    scene = scene_of("pinhole")
    cams = scene.train.cameras[:1]
    outs = {}
    for mode in ("linear", "ndc"):
        bb = build("gs2d", scene, fake=False, distortion_depth=mode)
        m = bb.model
        want = render_2dgs(m.means, m.quats, m.scales, m.opacities, m.colors(cams), cams, tile=bb.cfg.tile,
                           impl=bb.cfg.rasterizer, dist_depth=distortion_depth(mode, float(scene.extent)))["distortion"]
        outs[mode] = bb.render(cams)["distortion"].detach()
        torch.testing.assert_close(outs[mode], want.detach())
    assert outs["linear"].max() > 100 * outs["ndc"].max()  # at z ~ 4, NDC's slope is 0.0125 per unit
    with pytest.raises(ConfigError, match="distortion_depth"):
        build("gs2d", scene, distortion_depth="metric")


def test_gs2d_lowpass_sigma_reaches_the_rasteriser():
    """``backbone.lowpass_sigma`` is the rasteriser's: the backbone's render equals render_2dgs with it (and
    differs from the official sigma's); zero or negative is refused with the key's name."""
    if not _renderer_available("gs2d"):
        pytest.skip("backbones/gs2d/render.py not there yet")
    from arcsem.backbones.gs2d.render import LOWPASS_SIGMA, distortion_depth, render_2dgs

    from arcsem.errors import ConfigError

    scene = scene_of("pinhole")
    cams = scene.train.cameras[:1]
    bb = build("gs2d", scene, fake=False, lowpass_sigma=0.3)
    m = bb.model
    with torch.no_grad():
        m.log_scales.fill_(math.log(1e-3))  # sub-pixel splats: drawn by the filter
        got = bb.render(cams)["alpha"]
        kw = {"tile": bb.cfg.tile, "impl": bb.cfg.rasterizer, "dist_depth": distortion_depth("linear", float(scene.extent))}
        want = render_2dgs(m.means, m.quats, m.scales, m.opacities, m.colors(cams), cams, lowpass_sigma=0.3, **kw)["alpha"]
        official = render_2dgs(m.means, m.quats, m.scales, m.opacities, m.colors(cams), cams,
                               lowpass_sigma=LOWPASS_SIGMA, **kw)["alpha"]
    torch.testing.assert_close(got, want)
    assert official.sum() > 2 * got.sum()
    for bad in (0.0, -1.0):
        with pytest.raises(ConfigError, match="lowpass_sigma"):
            build("gs2d", scene, lowpass_sigma=bad)
