"""Fused C++ rasteriser (projection + backward, footprints, tile binning, compositing) against the
PyTorch path (the reference), 2DGS and 3DGS, pinhole and orthographic.

Every output (colour, alpha, depth, median depth, normals, distortion) and the gradient w.r.t. every
splat parameter must agree: float64 within 1e-10, float32 within 1e-5 (relative to the largest
magnitude). The scenes include empty tiles, splats straddling tile borders, opacity-clamped splats
(opacity ~ 1) and pixels that terminate early behind a stack of opaque splats.
"""
from __future__ import annotations

import warnings

import pytest
import torch
from arcsem.backbones.gaussians.fused import load_extension, resolve_impl
from arcsem.backbones.gs2d.render import distortion_depth, render_2dgs
from arcsem.backbones.gs3d.render import render_3dgs

from arcsem.cameras import Cameras, look_at

OUTPUTS = {"gs2d": ("rgb", "alpha", "depth", "median_depth", "normal", "distortion"), "gs3d": ("rgb", "alpha", "depth")}


@pytest.fixture(scope="module", autouse=True)
def extension():
    ext = load_extension()
    assert ext is not None, "the fused C++ rasteriser did not build; run `python -m arcsem.backbones.gaussians.fused`"
    return ext


def scene(kind: str, dtype: torch.dtype, model: str, seed: int = 0):
    """Splats in the left part of a 48x40 image (right tiles empty) incl. an opaque stack in front.

    Made in float64 and cast, so a float32 scene is the float64 one rounded (truth exists for it).
    """
    params, cams = _scene(kind, model, seed)
    return [p.to(dtype) for p in params], cams.to(dtype=dtype)


def _scene(kind: str, model: str, seed: int):
    dtype = torch.float64
    g = torch.Generator().manual_seed(seed)
    n = 60
    means = (torch.rand(n, 3, generator=g, dtype=dtype) - 0.5) * torch.tensor([0.8, 1.2, 1.0], dtype=dtype)
    means[:, 0] -= 0.35  # leave the right-hand tiles empty
    quats = torch.randn(n, 4, generator=g, dtype=dtype)
    scales = torch.rand(n, 2 if kind == "gs2d" else 3, generator=g, dtype=dtype) * 0.12 + 0.01
    scales[:5] *= 4  # big splats straddle tile borders
    opac = torch.rand(n, generator=g, dtype=dtype) * 0.9 + 0.05
    opac[5:15] = 0.999  # clamped to 0.99
    means[5:15, :2] = means[5, :2]  # an opaque stack: pixels behind it stop early
    means[5:15, 2] = torch.linspace(-0.4, 0.4, 10, dtype=dtype)
    colors = torch.rand(2, n, 3, generator=g, dtype=dtype)
    eye = torch.tensor([[0.0, 0.0, -4.0], [0.6, -0.3, -3.9]], dtype=dtype)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0], dtype=dtype))
    f = 50.0 if model == "pinhole" else 12.5
    K = torch.tensor([[f, 0, 24.0], [0, f, 20.0], [0, 0, 1]], dtype=dtype).repeat(2, 1, 1)
    return [means, quats, scales, opac, colors], Cameras(w2c, K, 48, 40, model)


def render(kind: str, params, cams, impl: str):
    fn = render_2dgs if kind == "gs2d" else render_3dgs
    return fn(*params, cams, background=torch.tensor([0.1, 0.2, 0.3], dtype=params[0].dtype), impl=impl)


def assert_rel(a, b, tol, what):
    scale = b.abs().max().clamp_min(1e-12)
    err = ((a - b).abs().max() / scale).item()
    assert err < tol, f"{what}: relative error {err:.2e} >= {tol:.0e}"


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
@pytest.mark.parametrize("kind", ["gs2d", "gs3d"])
@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-10), (torch.float32, 1e-5)], ids=["f64", "f32"])
def test_fused_matches_torch_values_and_gradients(kind, model, dtype, tol):
    params, cams = scene(kind, dtype, model)
    outs, grads = {}, {}
    g = torch.Generator().manual_seed(1)
    for impl in ("torch", "cpp"):
        ps = [p.clone().requires_grad_() for p in params]
        out = render(kind, ps, cams, impl)
        if impl == "torch":
            cot = {k: torch.rand(out[k].shape, generator=g, dtype=dtype) for k in OUTPUTS[kind]}
        loss = sum((out[k] * cot[k]).sum() for k in OUTPUTS[kind])
        grads[impl] = torch.autograd.grad(loss, [*ps, out["means2d"]])  # + the screen-position gradient
        outs[impl] = out
    truth = render(kind, *scene(kind, torch.float64, model), "torch") if dtype == torch.float32 else None
    for k in OUTPUTS[kind]:
        a, b = outs["cpp"][k].detach(), outs["torch"][k].detach()
        if k == "distortion" and truth is not None:
            # float32 conditioning of sum w_i w_j (m_i - m_j)^2 limits the reference itself to ~1e-5: the kernel
            # must be at least as close to the float64 truth as the PyTorch path, and within 2e-5 of it
            t = truth[k].detach()
            err_cpp, err_torch = ((a.double() - t).abs().max() / t.abs().max()), ((b.double() - t).abs().max() / t.abs().max())
            assert err_cpp <= err_torch + 1e-6, f"{kind} {model} distortion: kernel {err_cpp:.1e} vs torch {err_torch:.1e}"
            assert_rel(a, b, 2e-5, f"{kind} {model} {k}")
        else:
            assert_rel(a, b, tol, f"{kind} {model} {k}")
    for name, a, b in zip(("means", "quats", "scales", "opacities", "colors", "means2d"), grads["cpp"], grads["torch"]):
        assert_rel(a, b, tol, f"{kind} {model} d/d{name}")
    for k in ("radii", "visible"):
        assert torch.equal(outs["cpp"][k], outs["torch"][k]), k
    assert_rel(outs["cpp"]["means2d"].detach(), outs["torch"]["means2d"].detach(), tol, "means2d")
    # the scene really exercises the edge cases
    alpha = outs["torch"]["alpha"].detach()
    assert (alpha[:, :, -8:] == 0).all(), "right-hand tiles should be empty"
    assert alpha.max() > 0.99, "the opaque stack should saturate some pixels (early termination)"


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
def test_fused_linear_distortion_depth_matches_torch(model):
    """The kernel's m = c0 + c1 z + c2 / z with the ``linear`` coefficients (value and every gradient)."""
    params, cams = scene("gs2d", torch.float64, model)
    res = {}
    for impl in ("torch", "cpp"):
        ps = [p.clone().requires_grad_() for p in params]
        out = render_2dgs(*ps, cams, impl=impl, dist_depth=distortion_depth("linear", 0.8))
        res[impl] = out["distortion"].detach(), torch.autograd.grad(out["distortion"].sum(), ps[:4])
    assert res["torch"][0].max() > 1e-4, "the scene should have overlapping splats"
    assert_rel(res["cpp"][0], res["torch"][0], 1e-10, "distortion")
    for name, a, b in zip(("means", "quats", "scales", "opacities"), res["cpp"][1], res["torch"][1]):
        assert_rel(a, b, 1e-10, f"d distortion / d{name}")


def test_fused_lowpass_sigma_matches_torch():
    """A non-default low-pass sigma: footprints, every output and every gradient of the kernel equal torch."""
    params, cams = scene("gs2d", torch.float64, "pinhole", seed=4)
    params[2] = params[2] * 0.05  # small splats: the 2-D filter draws many pixels
    res = {}
    for impl in ("torch", "cpp"):
        ps = [p.clone().requires_grad_() for p in params]
        out = render_2dgs(*ps, cams, impl=impl, lowpass_sigma=0.35)
        loss = sum((out[k] * (i + 1)).sum() for i, k in enumerate(OUTPUTS["gs2d"]))
        res[impl] = {k: out[k].detach() for k in OUTPUTS["gs2d"]}, torch.autograd.grad(loss, ps[:4]), out["radii"]
    assert torch.equal(res["cpp"][2], res["torch"][2])
    for k in OUTPUTS["gs2d"]:
        assert_rel(res["cpp"][0][k], res["torch"][0][k], 1e-10, k)
    for name, a, b in zip(("means", "quats", "scales", "opacities"), res["cpp"][1], res["torch"][1]):
        assert_rel(a, b, 1e-10, f"d/d{name}")


@pytest.mark.parametrize("kind", ["gs2d", "gs3d"])
def test_fused_rows_stopped_behind_an_opaque_wall(kind):
    """Big opaque splats in front stop every pixel of whole tile rows; the small splats behind them still
    overlap those rows (the backward pass skips a row once all its pixels stopped): values and gradients
    equal torch."""
    params, cams = scene(kind, torch.float64, "pinhole", seed=5)
    means, quats, scales, opac, _ = params
    wall = slice(0, 6)
    jitter = torch.rand(6, 3, generator=torch.Generator().manual_seed(6), dtype=torch.float64) - 0.5
    means[wall] = torch.tensor([-0.35, 0.0, -1.0], dtype=torch.float64) + 0.04 * jitter
    quats[wall] = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64)  # facing the first camera
    scales[wall] = torch.tensor([2.0, 1.7, 1.4], dtype=torch.float64)[:scales.shape[1]]  # (isotropic: a zero quaternion gradient)
    opac[wall] = 0.97  # not clamped: no pixel sits on the stopping threshold (ties would be decided by rounding)
    res = {}
    for impl in ("torch", "cpp"):
        ps = [p.clone().requires_grad_() for p in params]
        out = render(kind, ps, cams, impl)
        loss = sum((out[k] * (i + 1)).sum() for i, k in enumerate(OUTPUTS[kind]))
        res[impl] = {k: out[k].detach() for k in OUTPUTS[kind]}, torch.autograd.grad(loss, ps[:4])
    alpha = res["torch"][0]["alpha"][0, ..., 0]
    assert (alpha[16:32, 16:32] > 0.99).all(), "the wall should cover a whole tile (its pixels stop)"
    for k in OUTPUTS[kind]:
        assert_rel(res["cpp"][0][k], res["torch"][0][k], 1e-10, f"{kind} {k}")
    for name, a, b in zip(("means", "quats", "scales", "opacities"), res["cpp"][1], res["torch"][1]):
        assert_rel(a, b, 1e-10, f"{kind} d/d{name}")


@pytest.mark.parametrize("kind", ["gs2d", "gs3d"])
def test_fused_tile_stopped_before_its_later_pairs(kind):
    """Ten opaque walls in front stop every pixel; the 300 small splats behind them are pairs of the same tiles
    that the forward pass never gathers (it gathers in batches as far as the pixels go on) and the backward pass
    gives no rows. Values and gradients equal torch, also when the kernels' buffers are reused (the second
    render of the fused path: unused pairs and rows hold the first render's values)."""
    g = torch.Generator().manual_seed(8)
    dt = torch.float64
    n, nw = 1010, 10
    means = (torch.rand(n, 3, generator=g, dtype=dt) - 0.5) * torch.tensor([0.8, 0.8, 0.6], dtype=dt)
    means[:nw] = torch.tensor([0.0, 0.0, -1.2], dtype=dt) + 0.02 * torch.randn(nw, 3, generator=g, dtype=dt)
    quats = torch.randn(n, 4, generator=g, dtype=dt)
    quats[:nw] = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=dt)
    scales = torch.rand(n, 2 if kind == "gs2d" else 3, generator=g, dtype=dt) * 0.05 + 0.03
    scales[:nw] = torch.tensor([6.0, 5.0, 4.0], dtype=dt)[:scales.shape[1]]
    opac = torch.rand(n, generator=g, dtype=dt) * 0.5 + 0.3
    opac[:nw] = 0.985
    colors = torch.rand(2, n, 3, generator=g, dtype=dt)
    eye = torch.tensor([[0.0, 0.0, -4.0], [0.05, -0.03, -4.0]], dtype=dt)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0], dtype=dt))
    K = torch.tensor([[50.0, 0, 24.0], [0, 50.0, 20.0], [0, 0, 1]], dtype=dt).repeat(2, 1, 1)
    cams = Cameras(w2c, K, 48, 40, "pinhole")
    res = {}
    for impl in ("torch", "cpp", "cpp again"):
        ps = [p.clone().requires_grad_() for p in (means, quats, scales, opac, colors)]
        out = render(kind, ps, cams, impl.split()[0])
        loss = sum((out[k] * (i + 1)).sum() for i, k in enumerate(OUTPUTS[kind]))
        res[impl] = {k: out[k].detach() for k in OUTPUTS[kind]}, torch.autograd.grad(loss, ps[:4])
    assert (res["torch"][0]["alpha"] > 0.99).all(), "the walls should stop every pixel"
    xy = out["means2d"][0].detach()  # centres in tile (1, 1) of camera 0: pairs of that tile
    inside = ((xy >= 16) & (xy < 32)).all(-1) & (out["radii"][0] > 0)
    assert inside.sum() > 3 * 64, "the tile should have several gather batches of pairs"
    for impl in ("cpp", "cpp again"):
        for k in OUTPUTS[kind]:
            assert_rel(res[impl][0][k], res["torch"][0][k], 1e-10, f"{impl}: {kind} {k}")
        for name, a, b in zip(("means", "quats", "scales", "opacities"), res[impl][1], res["torch"][1]):
            assert_rel(a, b, 1e-10, f"{impl}: {kind} d/d{name}")


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
def test_fused_frozen_geometry_colour_gradient(model):
    """Stage 2 freezes the geometry: the 2DGS kernel then computes the colour gradient alone (its own lane loop),
    equal to torch's, and hands back no other gradient."""
    params, cams = scene("gs2d", torch.float64, model, seed=3)
    res = {}
    for impl in ("torch", "cpp"):
        ps = [p.clone() for p in params]
        ps[4].requires_grad_(True)  # colours only
        out = render_2dgs(*ps, cams, impl=impl, background=torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64))
        cot = torch.rand(out["rgb"].shape, generator=torch.Generator().manual_seed(7), dtype=torch.float64)
        res[impl] = torch.autograd.grad((out["rgb"] * cot).sum(), ps[4])[0], out["means2d"].requires_grad
    assert res["cpp"][1] is False, "no screen-position leaf when the means are frozen"
    assert res["torch"][0].abs().max() > 0
    assert_rel(res["cpp"][0], res["torch"][0], 1e-10, f"{model} d/dcolors, geometry frozen")


@pytest.mark.parametrize("kind", ["gs2d", "gs3d"])
def test_fused_unused_outputs_and_learned_background(kind):
    """Only rgb in the loss (the other outputs get no gradient: the kernels read them as zero) and a
    background that requires grad (composited outside the kernel): same values and gradients as torch."""
    params, cams = scene(kind, torch.float64, "pinhole", seed=2)
    g = torch.Generator().manual_seed(3)
    cot = None
    res = {}
    for impl in ("torch", "cpp"):
        ps = [p.clone().requires_grad_() for p in params]
        bg = torch.tensor([0.3, 0.5, 0.7], dtype=torch.float64, requires_grad=True)
        fn = render_2dgs if kind == "gs2d" else render_3dgs
        out = fn(*ps, cams, background=bg, impl=impl)
        cot = torch.rand(out["rgb"].shape, generator=g, dtype=torch.float64) if cot is None else cot
        res[impl] = (out["rgb"].detach(), torch.autograd.grad((out["rgb"] * cot).sum(), [*ps, bg]))
    assert_rel(res["cpp"][0], res["torch"][0], 1e-10, "rgb")
    for a, b in zip(res["cpp"][1], res["torch"][1]):
        assert_rel(a, b, 1e-10, f"{kind} gradient")


@pytest.mark.parametrize("model,N", [("pinhole", 3001), ("orthographic", 3001), ("pinhole", 40001)])
@pytest.mark.parametrize("kind", ["gs2d", "gs3d"])
def test_fused_footprint_and_binning_equal_torch(kind, model, N):
    """The C++ footprints, tile rectangles, pixel boxes and (tile, depth)-sorted pairs are those of the torch
    functions exactly (2 cameras, splats partly off-screen and behind the camera, some ties in depth); each entry's
    pair positions hold that entry. 40,001 splats on two threads: enough pairs for two workers to fill them; entry
    counts (2 N) not multiples of the footprint kernel's 8 lanes."""
    from arcsem.backbones.gaussians.raster_scenes import orbit_cameras, random_splats

    s = random_splats(N, 1, seed=3, scale=(0.002, 0.3), extent=4.0, opacity=(0.001, 1.0))
    s.means[:50] = s.means[50:100]  # equal depths: ties keep the index order
    cams = orbit_cameras(2, 72, 40, ortho=model == "orthographic")
    C, W, H, tile, near = 2, 72, 40, 16, 0.01
    threads = torch.get_num_threads()
    torch.set_num_threads(2 if N > 10000 else threads)
    try:
        _check_footprint_and_binning(kind, s, cams, C, W, H, tile, near, N)
    finally:
        torch.set_num_threads(threads)


def _check_footprint_and_binning(kind, s, cams, C, W, H, tile, near, N):
    from arcsem.backbones.gaussians import fused
    from arcsem.backbones.gaussians.raster import bin_tiles
    from arcsem.backbones.gs2d.render import footprint_2dgs, splat_homographies
    from arcsem.backbones.gs3d.render import footprint_3dgs, project_gaussians

    model = "orthographic" if cams.is_ortho else "pinhole"
    if kind == "gs2d":
        Hm, _ = splat_homographies(s.means, s.quats, s.scales[:, :2], cams)
        sigma = 0.4 if model == "orthographic" else 0.7071  # a non-default low-pass filter radius too
        radius, rects, eff, depth = footprint_2dgs(Hm, s.opacities, cams, tile, near, sigma)
        got = fused.footprint_bin_2dgs(Hm[..., :3, :].reshape(C * N, 9), Hm[..., 3, :].reshape(C * N, 3),
                                       s.opacities, C, near, W, H, tile, sigma)
    else:
        m2, depth, cov2d = project_gaussians(s.means, s.quats, s.scales, cams)
        radius, rects, eff, _ = footprint_3dgs(m2, depth, cov2d, s.opacities, cams, tile, near)
        cov = torch.stack([cov2d[..., 0, 0], cov2d[..., 0, 1], cov2d[..., 1, 1]], -1)
        got = fused.footprint_bin_3dgs(m2.reshape(C * N, 2), depth.reshape(-1), cov.reshape(C * N, 3), s.opacities,
                                       C, near, W, H, tile)
    radii, visible, rects_c, eff_c, offsets, ids = got.radii, got.visible, got.rects, got.box, got.offsets, got.ids
    b = bin_tiles(rects, depth, W, H, tile)
    vis = (radius > 0) & (rects[..., 1] > rects[..., 0]) & (rects[..., 3] > rects[..., 2])
    assert 0 < int(vis.sum()) < C * N, "the scene should have visible and culled splats"
    assert N < 10000 or len(got.ids) > 2 * 16384, "the large scene should be binned by two workers"
    assert torch.equal(visible, vis.reshape(-1)) and torch.equal(radii, torch.where(vis, radius, 0).reshape(-1))
    assert torch.equal(rects_c, rects.reshape(-1, 4))
    assert torch.equal(eff_c[visible], eff.reshape(-1, 4)[visible])
    assert torch.equal(offsets, b.offsets) and torch.equal(ids, b.splat)
    entry = torch.repeat_interleave(torch.arange(C * N), got.entry_offsets.diff())  # [P] entry of each pair slot
    assert torch.equal(ids[got.pair_of], entry) and torch.equal(got.pair_of.sort().values, torch.arange(len(ids)))


def test_resolve_impl_choices():
    assert resolve_impl("torch") == "torch"
    assert resolve_impl("auto") == "cpp"
    assert resolve_impl("cpp") == "cpp"
    from arcsem.errors import ConfigError

    with pytest.raises(ConfigError, match="rasterizer"):
        resolve_impl("cuda-magic")


def test_unavailable_extension_falls_back_with_one_warning(monkeypatch):
    import torch.utils.cpp_extension as cpp_ext
    from arcsem.backbones.gaussians import fused

    from arcsem.errors import ConfigError

    def broken(*a, **k):
        raise OSError("no compiler here")

    monkeypatch.setattr(cpp_ext, "load", broken)
    fused.load_extension.cache_clear()
    try:
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            impls = [fused.resolve_impl("auto"), fused.resolve_impl("auto")]
            with pytest.raises(ConfigError, match=r"needs a C\+\+ toolchain"):
                fused.resolve_impl("cpp")
        assert impls == ["torch", "torch"]
        msgs = [str(w.message) for w in rec if issubclass(w.category, RuntimeWarning)]
        assert len(msgs) == 1, f"warn once, not per call: {msgs}"
        assert "no compiler here" in msgs[0]
    finally:
        fused.load_extension.cache_clear()


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_fused_sh_colors_match_torch(model, degree):
    """The fused SH colours (every camera, splat) and their gradients to means and coefficients equal
    GaussianModel.colors' PyTorch path in float64, clamped colours included; degree 0 leaves means and the rest
    coefficients without a gradient, as the PyTorch path."""
    from arcsem.backbones.gaussians.model import GaussianModel

    g = torch.Generator().manual_seed(degree)
    n = 50
    params = {"means": torch.randn(n, 3, generator=g, dtype=torch.float64), "quats": torch.randn(n, 4, dtype=torch.float64),
              "log_scales": torch.zeros(n, 3, dtype=torch.float64), "opacity_logits": torch.zeros(n, dtype=torch.float64),
              "sh_dc": torch.randn(n, 1, 3, generator=g, dtype=torch.float64),  # some colours clamp at 0
              "sh_rest": torch.randn(n, 15, 3, generator=g, dtype=torch.float64) * 0.5}
    _, cams = _scene("gs3d", model, 0)
    res = {}
    for impl in ("torch", "cpp"):
        m = GaussianModel(params).double()
        rgb = m.colors(cams, degree=degree, impl=impl)
        cot = torch.rand(rgb.shape, generator=torch.Generator().manual_seed(9), dtype=torch.float64)
        grads = torch.autograd.grad((rgb * cot).sum(), [m.means, m.sh_dc, m.sh_rest], allow_unused=True)
        res[impl] = rgb.detach(), grads
    assert (res["torch"][0] == 0).any() and (res["torch"][0] > 0).any(), "some colours should be clamped"
    assert_rel(res["cpp"][0], res["torch"][0], 1e-12, "colours")
    for name, a, b in zip(("means", "sh_dc", "sh_rest"), res["cpp"][1], res["torch"][1]):
        if b is None:
            assert a is None or not a.any(), f"{name}: the PyTorch path has no gradient"
        else:
            assert_rel(a, b, 1e-12, f"d/d{name}")


def test_fused_2dgs_tiles_taller_than_the_row_mask():
    """Tiles of 40 rows: the forward records the rows it drew a pair on for the first 32 only (the backward skips
    the others); rows 32..39 are always visited. Values and gradients equal the PyTorch path in float64."""
    params, cams = _scene("gs2d", "pinhole", 0)
    res = {}
    for impl in ("torch", "cpp"):
        ps = [p.clone().requires_grad_() for p in params]
        out = render_2dgs(*ps, cams, tile=40, impl=impl)
        cot = torch.rand(out["rgb"].shape, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
        res[impl] = out["rgb"].detach(), torch.autograd.grad((out["rgb"] * cot).sum(), ps)
    assert (res["torch"][0][:, 32:].sum(-1) > 0).any(), "rows past 32 should be drawn"
    assert_rel(res["cpp"][0], res["torch"][0], 1e-10, "rgb")
    for name, a, b in zip(("means", "quats", "scales", "opacities", "colors"), res["cpp"][1], res["torch"][1]):
        assert_rel(a, b, 1e-10, f"d/d{name}")
