"""``backbone.rasterizer=gsplat``: the mapping of our cameras and splats onto gsplat's, checked on the CPU.

gsplat's rasteriser is CUDA only, but its PyTorch reference of the projection (``gsplat.cuda._torch_impl``,
the code its own tests check the CUDA kernels against) runs here: fed through our mapping
(:func:`gsplat_cameras`), it must give our projected centres, depths, conics (3DGS) and ray-splat
homographies (2DGS), values and gradients, in float64. The rendered images against ours: tests/test_cuda.py.
"""
from __future__ import annotations

import pytest
import torch
from arcsem.backbones.gaussians.gsplat_bridge import gsplat_cameras, require_gsplat
from arcsem.backbones.gaussians.raster_camera import camera_facing_normals
from arcsem.backbones.gs2d.render import _conic_box, splat_homographies
from arcsem.backbones.gs3d.render import project_gaussians
from gsplat.cuda._torch_impl import _fully_fused_projection, _quat_scale_to_covar_preci
from gsplat.cuda._torch_impl_2dgs import _fully_fused_projection_2dgs
from test_fused import _scene

from arcsem.cameras import Cameras
from arcsem.errors import ConfigError
from arcsem.rotations import quat_to_rotmat


def _weighted(outs, seed=1):
    g = torch.Generator().manual_seed(seed)
    return sum((o * torch.rand(o.shape, generator=g, dtype=o.dtype)).sum() for o in outs)


def _assert_close(a, b, what, tol=1e-11):
    err = ((a - b).abs().max() / b.abs().max().clamp_min(1e-12)).item()
    assert err < tol, f"{what}: relative error {err:.2e} (gsplat against ours)"


def _assert_all_close(named: dict, tol: float) -> None:
    """Every ``name: (gsplat, ours)`` pair within ``tol`` (relative, as :func:`_assert_close`); all errors are listed
    at once (a GPU is rare here: one run should show every figure)."""
    errs = {n: ((a - b).abs().max() / b.abs().max().clamp_min(1e-12)).item() for n, (a, b) in named.items()}
    bad = {n: f"{e:.2e}" for n, e in errs.items() if not e < tol}
    assert not bad, f"relative errors above {tol:g} (gsplat against ours): {bad}; all: " + \
        ", ".join(f"{n} {e:.2e}" for n, e in errs.items())


def _inside_clamp(means, cams):
    """gsplat (as the official 3DGS) evaluates the Jacobian at the centre clamped to 1.3x the frustum: the
    scenes must lie inside it for the two projections to agree (ours does not clamp)."""
    xyz = cams.to_camera(means.detach())
    K = cams.K
    tx, ty = xyz[..., 0] / xyz[..., 2], xyz[..., 1] / xyz[..., 2]
    fx, fy, cx, cy = K[:, 0, 0, None], K[:, 1, 1, None], K[:, 0, 2, None], K[:, 1, 2, None]
    return bool(((tx < (cams.width - cx) / fx + 0.15 * cams.width / fx) & (tx > -cx / fx - 0.15 * cams.width / fx)
                 & (ty < (cams.height - cy) / fy + 0.15 * cams.height / fy)
                 & (ty > -cy / fy - 0.15 * cams.height / fy)).all())


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
def test_3dgs_projection_equals_gsplat(model):
    """Centres, depths and conics (EWA, 0.3 px blur) and their gradients w.r.t. means, quaternions, scales."""
    (means, quats, scales, _, _), cams = _scene("gs3d", model, seed=4)
    assert model == "orthographic" or _inside_clamp(means, cams)
    res = []
    for ours in (True, False):
        p = [t.clone().requires_grad_() for t in (means, quats, scales)]
        if ours:
            m2, depth, cov = project_gaussians(*p, cams)
            det = cov[..., 0, 0] * cov[..., 1, 1] - cov[..., 0, 1] ** 2
            conics = torch.stack([cov[..., 1, 1], -cov[..., 0, 1], cov[..., 0, 0]], -1) / det[..., None]
        else:
            viewmats, Ks, name = gsplat_cameras(cams)
            covars = _quat_scale_to_covar_preci(p[1], p[2], compute_preci=False)[0]
            _, m2, depth, conics, _ = _fully_fused_projection(p[0], covars, viewmats, Ks, cams.width, cams.height,
                                                              eps2d=0.3, camera_model=name)
        outs = (m2, depth, conics)
        res.append((outs, torch.autograd.grad(_weighted(outs), p)))
    for name, a, b in zip(("means2d", "depth", "conics", "d/means", "d/quats", "d/scales"),
                          res[1][0] + res[1][1], res[0][0] + res[0][1]):
        _assert_close(a.detach(), b.detach(), name)


def test_2dgs_homography_footprint_and_normals_equal_gsplat():
    """gsplat's ray transform ``(K [R S_uv | t])`` is our homography's rows ``Tu, Tv, Tw``; its AABB centre and
    extent are our conic box of the unit disk; its camera-facing normals ours in camera axes."""
    (means, quats, scales, _, _), cams = _scene("gs2d", "pinhole", seed=5)
    viewmats, Ks, _ = gsplat_cameras(cams, two_d=True)
    res = []
    for ours in (True, False):
        p = [t.clone().requires_grad_() for t in (means, quats, scales)]
        if ours:
            Hm, R = splat_homographies(*p, cams)
            M = Hm[..., :3, :]
            centre, extent, _ = _conic_box(M.detach(), torch.ones(M.shape[:2], dtype=M.dtype))
            n = torch.einsum("cij,cnj->cni", viewmats[:, :3, :3], camera_facing_normals(R[:, :, 2], p[0], cams))
        else:
            scales3 = torch.cat([p[2], torch.ones_like(p[2][:, :1])], -1)  # as the bridge (gsplat's CUDA: s2 = 1)
            _, centre, _, M, n = _fully_fused_projection_2dgs(p[0], p[1], scales3, viewmats, Ks, cams.width,
                                                              cams.height)
            extent = torch.sqrt((centre ** 2 - (M[..., :2, :] ** 2 * torch.tensor([1.0, 1.0, -1.0], dtype=M.dtype)
                                                ).sum(-1) / (M[..., 2, :] ** 2 * torch.tensor(
                                                    [1.0, 1.0, -1.0], dtype=M.dtype)).sum(-1, keepdim=True)
                                 ).clamp_min(1e-4))  # gsplat's extents, as in its projection
        res.append(((M, centre.detach(), extent.detach(), n), torch.autograd.grad(_weighted((M, n)), p)))
    for name, a, b in zip(("ray transform", "centre", "extent", "normals", "d/means", "d/quats", "d/scales"),
                          res[1][0] + res[1][1], res[0][0] + res[0][1]):
        _assert_close(a.detach(), b.detach(), name)


def test_gsplat_refused_where_it_cannot_run():
    """One-line ConfigErrors naming the key: no CUDA device, a skewed K, an orthographic 2DGS camera."""
    with pytest.raises(ConfigError, match=r"backbone\.rasterizer=gsplat needs the model on a CUDA device"):
        require_gsplat("cpu")
    (_, _, _, _, _), cams = _scene("gs3d", "pinhole", seed=0)
    K = cams.K.clone()
    K[:, 0, 1] = 0.5
    with pytest.raises(ConfigError, match="skewed K"):
        gsplat_cameras(Cameras(cams.world_to_cam, K, cams.width, cams.height))
    (_, _, _, _, _), ortho = _scene("gs2d", "orthographic", seed=0)
    with pytest.raises(ConfigError, match="no orthographic camera"):
        gsplat_cameras(ortho, two_d=True)
    gsplat_cameras(ortho)  # 3DGS: gsplat's 'ortho'


def test_preflight_refuses_scenes_gsplat_cannot_draw():
    """Once the scene is read (before training): an orthographic 2DGS camera, another low-pass sigma."""
    from arcsem.preflight import _check_gsplat_scene
    from arcsem.scene import Scene, Split

    def scene(model):
        cams = _scene("gs2d", model, seed=0)[1]
        imgs = torch.zeros(len(cams), cams.height, cams.width, 3)
        return Scene("s", Split(["a", "b"], cams, imgs), Split([], cams[[]], imgs[:0]), torch.tensor([[-1.0] * 3, [1.0] * 3]))

    ortho, pinhole = scene("orthographic"), scene("pinhole")
    with pytest.raises(ConfigError, match="no orthographic camera"):
        _check_gsplat_scene({"name": "gs2d", "rasterizer": "gsplat"}, ortho)
    with pytest.raises(ConfigError, match=r"lowpass_sigma=0.7071 \(got 1.0\)"):
        _check_gsplat_scene({"name": "gs2d", "rasterizer": "gsplat", "lowpass_sigma": 1.0}, pinhole)
    with pytest.raises(ConfigError, match=r"backbone.tile=32 px tiles .* use backbone.tile=16"):
        _check_gsplat_scene({"name": "gs2d", "rasterizer": "gsplat", "lowpass_sigma": 2**-0.5, "tile": 32}, pinhole)
    _check_gsplat_scene({"name": "gs3d", "rasterizer": "gsplat", "tile": 32}, pinhole)  # its 3DGS launches there
    _check_gsplat_scene({"name": "gs3d", "rasterizer": "gsplat"}, ortho)  # gsplat's 3DGS has 'ortho'
    _check_gsplat_scene({"name": "gs2d", "rasterizer": "gsplat", "lowpass_sigma": 2**-0.5}, pinhole)
    _check_gsplat_scene({"name": "gs2d", "rasterizer": "auto"}, ortho)  # not gsplat: nothing to check


def test_quick_gs2d_preset_draws_with_gsplats_filter_on_gsplat():
    """The demo's 2DGS preset (low-pass 1/sqrt(8) px on our rasterisers) composes to gsplat's fixed 1/sqrt(2) with
    ``backbone.rasterizer=gsplat``, so the default job runs there (it stopped at preflight before); a sigma set
    on the command line is still the user's, and still refused where gsplat cannot draw it."""
    from test_config import compose_with

    from arcsem.preflight import _check_gsplat_scene
    from arcsem.registry import plain
    from arcsem.scene import Scene, Split

    cams = _scene("gs2d", "pinhole", seed=0)[1]
    imgs = torch.zeros(len(cams), cams.height, cams.width, 3)
    scene = Scene("s", Split(["a", "b"], cams, imgs), Split([], cams[[]], imgs[:0]), torch.tensor([[-1.0] * 3, [1.0] * 3]))
    ours = compose_with("experiment=demo")
    assert ours.backbone.lowpass_sigma == pytest.approx(8**-0.5)
    on_gsplat = compose_with("experiment=demo", "backbone.rasterizer=gsplat")
    assert on_gsplat.backbone.lowpass_sigma == pytest.approx(2**-0.5)
    _check_gsplat_scene(plain(on_gsplat.backbone), scene)
    explicit = compose_with("experiment=demo", "backbone.rasterizer=gsplat", "backbone.lowpass_sigma=0.5")
    with pytest.raises(ConfigError, match=r"lowpass_sigma=0.7071 \(got 0.5\)"):
        _check_gsplat_scene(plain(explicit.backbone), scene)


@pytest.mark.parametrize("kind", ["gs2d", "gs3d"])
def test_backbone_with_gsplat_on_cpu_is_a_config_error(kind):
    """The backbone's config accepts ``rasterizer=gsplat``; rendering on the CPU names the key and the fix."""
    from arcsem.plugins import BACKBONES

    cls = BACKBONES.get(kind)
    bb = cls(cls.Config(rasterizer="gsplat", random_init_points=50))
    (_, _, _, _, _), cams = _scene(kind, "pinhole", seed=0)
    with pytest.raises(ConfigError, match=r"rasterizer=gsplat needs the model on a CUDA device.*auto"):
        bb.render(cams.to(dtype=torch.float32))


def test_quaternions_are_read_alike():
    """Both take (w, x, y, z), unnormalised: the rotation matrices agree (a guard for the mapping above)."""
    from gsplat.cuda._torch_impl import _quat_to_rotmat

    q = torch.randn(50, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(2)) * 3
    _assert_close(_quat_to_rotmat(q), quat_to_rotmat(q), "rotation", tol=1e-13)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device (torch.cuda.is_available())")
@pytest.mark.parametrize("kind,model", [("gs3d", "pinhole"), ("gs3d", "orthographic"), ("gs2d", "pinhole")])
def test_gsplat_renders_equal_ours_on_cuda(kind, model):
    """Values and gradients (every splat parameter) of ``rasterizer=gsplat`` against our PyTorch path on CUDA,
    float32. The scene avoids what the two draw differently (gsplat_bridge's module doc): opacities below 0.35
    (no alpha clamp; alpha >= 1/255 only inside 3 sigma, where both bin), one tile (no tile-border footprint
    differences): 32 px for 3DGS, 16 px for 2DGS, whose backward gsplat cannot launch on 1024-thread blocks
    (benchmarks/gpu/gsplat_launch.py). 2DGS: colour, alpha and normals (its depth channels use centre depths)."""
    from arcsem.backbones.gaussians.gsplat_bridge import render_gsplat_2dgs, render_gsplat_3dgs
    from arcsem.backbones.gs2d.render import render_2dgs
    from arcsem.backbones.gs3d.render import render_3dgs

    params, cams = _scene(kind, model, seed=3)
    params[3] = params[3] * 0.35
    params = [t.float().cuda() for t in params]
    tile = 32 if kind == "gs3d" else 16
    cams = cams.scaled(tile / 48).to(device="cuda", dtype=torch.float32)  # 32 x 27 or 16 x 13 px: one tile
    assert cams.width <= tile and cams.height <= tile
    outs = ("rgb", "alpha", "depth") if kind == "gs3d" else ("rgb", "alpha", "normal")
    fns = {"gs3d": (render_3dgs, render_gsplat_3dgs), "gs2d": (render_2dgs, render_gsplat_2dgs)}[kind]
    bg = torch.tensor([0.1, 0.2, 0.3], device="cuda")
    res = []
    for fn in fns:
        p = [t.clone().requires_grad_() for t in params]
        kw = {"impl": "torch"} if fn in (render_3dgs, render_2dgs) else {}
        out = fn(*p, cams, background=bg, tile=tile, **kw)
        g = torch.Generator().manual_seed(1)
        loss = sum((out[k] * torch.rand(out[k].shape, generator=g).cuda()).sum() for k in outs)
        res.append([out[k].detach().cpu() for k in outs] + [x.cpu() for x in torch.autograd.grad(loss, p)])
    tol = 1e-3 if kind == "gs3d" else 1e-2  # float32, other summation orders; 2DGS: its low-pass centre differs
    names = outs + ("means", "quats", "scales", "opacities", "colors")
    _assert_all_close({n: (a, b) for n, a, b in zip(names, res[1], res[0])}, tol)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device (torch.cuda.is_available())")
def test_gsplat_2dgs_depth_outputs_equal_ours_for_splats_facing_the_camera():
    """Splats parallel to the image plane: the depth where a ray meets one is its centre depth, so gsplat's depth
    channels (bridge) equal ours: expected and median depth, distortion (linear ``m``), values and their gradients
    w.r.t. means and scales. Not w.r.t. rotations: tilting a splat moves the depth where a ray meets it (ours) but
    not its centre depth (gsplat's), so the two agree in value and differ in that derivative (an H200 run found
    1.15 relative, the values and the means' gradient within 1e-2)."""
    from arcsem.backbones.gaussians.gsplat_bridge import render_gsplat_2dgs
    from arcsem.backbones.gs2d.render import render_2dgs

    from arcsem.rotations import rotmat_to_quat

    params, cams = _scene("gs2d", "pinhole", seed=6)
    cams = cams[0:1].scaled(1 / 3)  # 16 x 13 px: one 16-px tile (gsplat's 2DGS backward: at most 16-px tiles)
    params[1] = rotmat_to_quat(cams.world_to_cam[0, :3, :3].T).expand(params[0].shape[0], 4).clone()
    params[3] = params[3] * 0.35
    params[4] = params[4][:1]
    params = [t.float().cuda() for t in params]
    cams = cams.to(device="cuda", dtype=torch.float32)
    outs, res = ("depth", "median_depth", "distortion"), []
    for fn in (render_2dgs, render_gsplat_2dgs):
        p = [t.clone().requires_grad_() for t in params]
        kw = {"impl": "torch"} if fn is render_2dgs else {}
        out = fn(*p, cams, tile=16, dist_depth=(0.0, 0.25, 0.0), **kw)
        g = torch.Generator().manual_seed(2)
        loss = sum((out[k] * torch.rand(out[k].shape, generator=g).cuda()).sum() for k in outs)
        res.append([out[k].detach().cpu() for k in outs] + [x.cpu() for x in torch.autograd.grad(loss, [p[0], p[2]])])
    _assert_all_close({n: (a, b) for n, a, b in zip(outs + ("means", "scales"), res[1], res[0])}, 1e-2)
