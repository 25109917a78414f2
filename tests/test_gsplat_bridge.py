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
from arcsem.rotations import quat_to_rotmat, rotmat_to_quat


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


def _check_gsplat_scene(bcfg: dict, scene) -> None:
    """The backbone's own scene check (:meth:`arcsem.plugins.Backbone.check_scene`), as a run's stage checks call it."""
    from arcsem.plugins import BACKBONES
    from arcsem.registry import validate_config

    cls = BACKBONES.get(bcfg["name"])
    cls.check_scene(validate_config(cls.Config, {k: v for k, v in bcfg.items() if k != "name"}, "backbone"), scene)


def test_preflight_refuses_scenes_gsplat_cannot_draw():
    """Once the scene is read (before training): an orthographic 2DGS camera, another low-pass sigma."""
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


def _scene_2dgs_resolved(seed: int):
    """The 2DGS parity scene: one 16 x 13 px camera (one 16-px tile), 20 splats tilted at most 35 degrees from
    facing it, 1-3 px wide (sigma) along both axes, opacities below 0.35.

    gsplat, as the official 2DGS, centres its low-pass filter on the centre of the splat's projected 1-sigma
    ellipse (its bounding box); ours centres it on the projected splat centre (docs/method.md). Under perspective
    the two differ for a tilted splat, so values and gradients differ wherever the low-pass branch wins. For a
    splat at least ``1/sqrt(2)`` px wide (sigma) in every image direction the ray-splat distance never exceeds
    the low-pass one, so the low-pass branch never wins and the two rasterisers must agree.
    """
    params, cams = _scene("gs2d", "pinhole", seed=seed)
    cams = cams[0:1].scaled(1 / 3)
    g = torch.Generator().manual_seed(seed)
    n = 20
    facing = cams.world_to_cam[0, :3, :3].T  # splat axes = camera axes: the splat faces the camera
    axis = torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=torch.float64), dim=-1)
    angle = torch.rand(n, generator=g, dtype=torch.float64) * (35 * torch.pi / 180)
    qt = torch.cat([torch.cos(angle / 2)[:, None], torch.sin(angle / 2)[:, None] * axis], -1)
    spin = torch.rand(n, generator=g, dtype=torch.float64) * torch.pi  # in-plane rotation
    qs = torch.stack([torch.cos(spin / 2), 0 * spin, 0 * spin, torch.sin(spin / 2)], -1)
    R = quat_to_rotmat(qt) @ facing @ quat_to_rotmat(qs)
    means, _, _, opac, colors = params
    scales = torch.rand(n, 2, generator=g, dtype=torch.float64) * 0.3 + 0.3
    return [means[:n], rotmat_to_quat(R), scales, opac[:n] * 0.35, colors[:1, :n]], cams


def _image_jacobian_singular_values(means, quats, scales, cams):
    """``[N, 2]`` singular values (px per sigma) of d(pixel)/d(u, v) at each splat's centre, camera 0."""
    Hm, _ = splat_homographies(means, quats, scales, cams)
    Tu, Tv, Tw = Hm[0, :, 0], Hm[0, :, 1], Hm[0, :, 2]
    x, y = Tu[:, 2] / Tw[:, 2], Tv[:, 2] / Tw[:, 2]
    J = torch.stack([torch.stack([(Tu[:, k] - x * Tw[:, k]) / Tw[:, 2] for k in (0, 1)], -1),
                     torch.stack([(Tv[:, k] - y * Tw[:, k]) / Tw[:, 2] for k in (0, 1)], -1)], -2)
    return torch.linalg.svdvals(J)


def _gsplat_2dgs_dense(means, quats, scales, opacities, colors, cams):
    """gsplat's 2DGS pixel rule, dense, from its PyTorch projection (``_fully_fused_projection_2dgs``) and the
    per-pixel weight of its rasteriser (``min(rho3d, 2 |pixel - means2d|^2)``, alpha clamped at 0.999, kept at
    >= 1/255, front to back in centre depth): rgb ``[H, W, 3]`` and alpha ``[H, W, 1]`` of camera 0."""
    viewmats, Ks, _ = gsplat_cameras(cams, two_d=True)
    scales3 = torch.cat([scales, torch.ones_like(scales[:, :1])], -1)
    _, centre, depth, M, _ = _fully_fused_projection_2dgs(means, quats, scales3, viewmats, Ks, cams.width,
                                                          cams.height)
    order = depth[0].argsort()
    M, centre, op, col = M[0, order], centre[0, order], opacities[order], colors[0, order]  # [N, ...]
    px = cams.pixel_grid(means.dtype).reshape(-1, 1, 2)  # [P, 1, 2]
    h_u = -M[:, 0] + M[:, 2] * px[..., :1]  # [P, N, 3]
    h_v = -M[:, 1] + M[:, 2] * px[..., 1:]
    cr = torch.cross(h_u, h_v, dim=-1)
    rho3d = (cr[..., 0] / cr[..., 2]) ** 2 + (cr[..., 1] / cr[..., 2]) ** 2
    rho2d = 2 * ((px - centre) ** 2).sum(-1)
    alpha = (op * torch.exp(-0.5 * torch.minimum(rho3d, rho2d))).clamp_max(0.999)
    alpha = torch.where(alpha >= 1 / 255, alpha, torch.zeros_like(alpha))
    T = torch.cumprod(torch.cat([torch.ones_like(alpha[:, :1]), 1 - alpha[:, :-1]], 1), 1)
    w = alpha * T
    shape = (cams.height, cams.width)
    return (w @ col).reshape(*shape, 3), w.sum(1).reshape(*shape, 1), rho3d <= rho2d


def test_2dgs_parity_scene_draws_alike_with_gsplats_pixel_rule():
    """The scene of the CUDA parity test below, checked here: every splat is wider than the low-pass filter in
    every image direction, so gsplat's rule never takes its low-pass branch, and its rule (dense, from its own
    PyTorch projection) gives our image and gradients in float64. The usual test scene, with sub-pixel splats,
    does take it, and the two then differ (the centre of the filter, :func:`_scene_2dgs_resolved`)."""
    from arcsem.backbones.gs2d.render import render_2dgs

    params, cams = _scene_2dgs_resolved(seed=3)
    assert cams.width <= 16 and cams.height <= 16
    sv = _image_jacobian_singular_values(*params[:3], cams)
    assert bool((sv > 0.85).all()), f"a splat narrower than the low-pass filter: {sv.min():.3f} px"
    res = []
    for fn in ("ours", "gsplat"):
        p = [t.clone().requires_grad_() for t in params]
        if fn == "ours":
            out = render_2dgs(*p, cams, impl="torch", tile=16)
            rgb, alpha = out["rgb"][0], out["alpha"][0]
        else:
            rgb, alpha, use3d = _gsplat_2dgs_dense(*p, cams)
            assert bool(use3d.all())
        res.append([rgb.detach(), alpha.detach(), *torch.autograd.grad(_weighted((rgb, alpha)), p)])
    names = ("rgb", "alpha", "means", "quats", "scales", "opacities", "colors")
    _assert_all_close({n: (a, b) for n, a, b in zip(names, res[1], res[0])}, 1e-9)
    (means, quats, scales, opac, colors), cams = _scene("gs2d", "pinhole", seed=3)
    *_, use3d = _gsplat_2dgs_dense(means, quats, scales, opac * 0.35, colors[:1], cams[0:1].scaled(1 / 3))
    assert not bool(use3d.all())  # sub-pixel splats: the low-pass branch is taken somewhere


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device (torch.cuda.is_available())")
@pytest.mark.parametrize("kind,model", [("gs3d", "pinhole"), ("gs3d", "orthographic"), ("gs2d", "pinhole")])
def test_gsplat_renders_equal_ours_on_cuda(kind, model):
    """Values and gradients (every splat parameter) of ``rasterizer=gsplat`` against our PyTorch path on CUDA,
    float32. The scene avoids what the two draw differently (gsplat_bridge's module doc): opacities below 0.35
    (no alpha clamp; alpha >= 1/255 only inside 3 sigma, where both bin), one tile (no tile-border footprint
    differences): 32 px for 3DGS, 16 px for 2DGS, whose backward gsplat cannot launch on 1024-thread blocks
    (benchmarks/gpu/gsplat_launch.py). 2DGS: splats wider than the low-pass filter, whose centre differs
    (:func:`_scene_2dgs_resolved`); colour, alpha and normals (its depth channels use centre depths)."""
    from arcsem.backbones.gaussians.gsplat_bridge import render_gsplat_2dgs, render_gsplat_3dgs
    from arcsem.backbones.gs2d.render import render_2dgs
    from arcsem.backbones.gs3d.render import render_3dgs

    tile = 32 if kind == "gs3d" else 16
    if kind == "gs3d":
        params, cams = _scene(kind, model, seed=3)
        params[3] = params[3] * 0.35
        cams = cams.scaled(tile / 48)  # 32 x 27 px: one tile
    else:
        params, cams = _scene_2dgs_resolved(seed=3)
    params = [t.float().cuda() for t in params]
    cams = cams.to(device="cuda", dtype=torch.float32)
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
    names = outs + ("means", "quats", "scales", "opacities", "colors")
    _assert_all_close({n: (a, b) for n, a, b in zip(names, res[1], res[0])}, 1e-3)  # float32, summation orders


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


def test_gsplat_2dgs_draws_the_splats_ours_draws():
    """The bridge hands gsplat only the splats our rasteriser draws (:func:`drawn_2dgs`, the same test as
    ``footprint_2dgs``): splats whose 3-sigma disk crosses the camera plane, or whose centre is behind ``near``,
    get opacity 0 and are not visible. gsplat would draw them, and its screen-centre gradient divides by a
    quantity that goes to zero there (an H200 run: positions not finite after 10 steps of a 32 x 24 scene)."""
    from arcsem.backbones.gaussians.gsplat_bridge import drawn_2dgs
    from arcsem.backbones.gs2d.render import footprint_2dgs

    (means, quats, scales, opac, _), cams = _scene("gs2d", "pinhole", seed=7)
    means, scales = means.clone(), scales.clone()
    means[:8, 2] = torch.linspace(-4.2, -3.6, 8, dtype=means.dtype)  # near the first camera's plane (z = -4)
    scales[:8] = torch.linspace(0.05, 0.6, 8, dtype=scales.dtype)[:, None]
    Hm, _ = splat_homographies(means, quats, scales, cams)
    radius, *_ = footprint_2dgs(Hm, opac, cams, 16, 0.01)
    drawn = drawn_2dgs(means, quats, scales, cams.world_to_cam, 0.01)
    assert drawn.shape == radius.shape and 0 < int((~drawn).sum()) < drawn.numel()
    assert torch.equal(drawn, radius > 0)


def test_gsplat_2dgs_projects_no_splat_ours_culls():
    """The splats ours does not draw reach gsplat at the camera's centre (:func:`culled_at_eye`), where gsplat's
    2DGS projection (its PyTorch reference, the CUDA kernel's rule: depth at most ``near_plane``) drops them before
    anything else; given only opacity 0 they were still projected (radius > 0), and their disk crossing the camera
    plane makes that projection divide by about zero. The drawn splats are projected as before, and the culled
    rows get no gradient."""
    from arcsem.backbones.gaussians.gsplat_bridge import culled_at_eye, drawn_2dgs

    (means, quats, scales, _, _), cams = _scene("gs2d", "pinhole", seed=7)
    means, scales = means.clone(), scales.clone()
    means[:8, 2] = torch.linspace(-4.2, -3.6, 8, dtype=means.dtype)  # near the first camera's plane (z = -4)
    scales[:8] = torch.linspace(0.05, 0.6, 8, dtype=scales.dtype)[:, None]
    cams = cams[0:1]
    drawn = drawn_2dgs(means, quats, scales, cams.world_to_cam, 0.01)[0]
    viewmats, Ks, _ = gsplat_cameras(cams, two_d=True)
    scales3 = torch.cat([scales, torch.ones_like(scales[:, :1])], -1)

    def radii(m):
        return _fully_fused_projection_2dgs(m, quats, scales3, viewmats, Ks, cams.width, cams.height)[0][0].amax(-1)

    before = radii(means)
    assert int((~drawn).sum()) > 0 and bool((before[~drawn] > 0).any())  # opacity 0 alone: still projected
    leaf = means.clone().requires_grad_(True)
    handed = culled_at_eye(leaf, drawn, cams.world_to_cam[0])
    after = radii(handed.detach())
    assert bool((after[~drawn] == 0).all()) and torch.equal(after[drawn], before[drawn])
    assert torch.equal(handed[drawn], means[drawn])
    handed.square().sum().backward()
    assert bool((leaf.grad[~drawn] == 0).all()) and bool((leaf.grad[drawn] != 0).any())
