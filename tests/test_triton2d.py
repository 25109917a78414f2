"""``rasterizer=triton``: the 2DGS compositing as Triton kernels equals the PyTorch path (the reference), values and
gradients; the kernels compile for a GPU (sm_90) on this machine; the choice says where it cannot run.

Without a GPU the kernels run on CPU tensors through Triton's interpreter (``TRITON_INTERPRET=1``, set here before
the kernels are first imported; a few seconds a render). On a GPU machine ``pytest -m cuda`` checks them compiled.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

if not torch.cuda.is_available():
    os.environ.setdefault("TRITON_INTERPRET", "1")

pytest.importorskip("triton")

from test_fused import OUTPUTS, _scene, assert_rel, render, scene

ROOT = Path(__file__).resolve().parents[1]
NAMES = ("means", "quats", "scales", "opacities", "colors", "means2d")


def _values_and_grads(params, cams, impl: str, cot=None, wrt=None):
    """Render with ``impl``; outputs and the gradients of ``sum(out * cot)`` w.r.t. ``wrt`` (default: every
    parameter) and the screen positions."""
    ps = [p.detach().clone().requires_grad_(wrt is None or i in wrt) for i, p in enumerate(params)]
    out = render("gs2d", ps, cams, impl)
    if cot is None:
        g = torch.Generator().manual_seed(1)
        cot = {k: torch.rand(out[k].shape, generator=g, dtype=out[k].dtype) for k in OUTPUTS["gs2d"]}
    loss = sum((out[k] * cot[k].to(out[k].device)).sum() for k in OUTPUTS["gs2d"])
    inputs = [ps[i] for i in (wrt or range(len(ps)))] + ([out["means2d"]] if wrt is None else [])
    return out, torch.autograd.grad(loss, inputs), cot


@pytest.mark.parametrize("model,dtype,tol", [("pinhole", torch.float64, 1e-10), ("orthographic", torch.float32, 2e-5)],
                         ids=["pinhole-f64", "orthographic-f32"])
def test_triton_matches_torch_values_and_gradients(model, dtype, tol):
    """Every output and the gradient of every splat parameter and screen position, on a scene with splats across
    tile borders, empty tiles, clamped opacities and an opaque stack that stops pixels early (test_fused.scene)."""
    params, cams = scene("gs2d", dtype, model)
    ref, g_ref, cot = _values_and_grads(params, cams, "torch")
    out, g_out, _ = _values_and_grads(params, cams, "triton", cot)
    for k in OUTPUTS["gs2d"]:  # (float32 distortion: the reference's own conditioning, as test_fused)
        assert_rel(out[k].detach(), ref[k].detach(), tol, f"{model} {k}")
    for name, a, b in zip(NAMES, g_out, g_ref):
        assert_rel(a, b, tol, f"{model} d/d{name}")
    for k in ("radii", "visible"):
        assert torch.equal(out[k], ref[k]), k
    assert ref["alpha"].detach().max() > 0.99, "the opaque stack should stop some pixels early"


@pytest.mark.parametrize("how", ["tile_acq", "tile", "warp"])
def test_every_backward_reduction_gives_the_gradients(monkeypatch, how):
    """The compositing backward's other ways of summing a pair's 21 gradient columns over the tile
    (``triton2d.BACKWARD_SUM``; the default, "row", is checked above) give the same gradients, float64."""
    from arcsem.backbones.gaussians import triton2d

    monkeypatch.setattr(triton2d, "BACKWARD_SUM", how)
    params, cams = scene("gs2d", torch.float64, "pinhole")
    _, g_ref, cot = _values_and_grads(params, cams, "torch")
    _, g_out, _ = _values_and_grads(params, cams, "triton", cot)
    for name, a, b in zip(NAMES, g_out, g_ref):
        assert_rel(a, b, 1e-10, f"{how} d/d{name}")


def test_triton_frozen_geometry_colour_gradient_and_odd_tiles():
    """Stage 2 (only the colours train: the backward's colour columns alone) and 12-px tiles (144 pixels in blocks
    of 256 lanes) with the quick preset's low-pass filter and a linear distortion depth equal the PyTorch path."""
    params, cams = scene("gs2d", torch.float64, "pinhole", seed=2)
    _, g_ref, cot = _values_and_grads(params, cams, "torch", wrt=[4])
    _, g_out, _ = _values_and_grads(params, cams, "triton", cot, wrt=[4])
    assert_rel(g_out[0], g_ref[0], 1e-10, "frozen geometry d/dcolors")
    from arcsem.backbones.gs2d.render import distortion_depth, render_2dgs

    kw = {"tile": 12, "lowpass_sigma": 0.3536, "dist_depth": distortion_depth("linear", 1.7)}  # (not float32 numbers)
    tiled = {impl: render_2dgs(*params, cams, impl=impl, **kw) for impl in ("torch", "triton")}
    for k in OUTPUTS["gs2d"]:
        assert_rel(tiled["triton"][k], tiled["torch"][k], 1e-10, f"12-px tiles, quick low-pass, linear depth: {k}")


def test_triton_backbone_renders_trains_and_records_as_torch():
    """The gs2d backbone with ``rasterizer=triton`` (SH colours, then the Triton compositing): the render, the
    gradient of every parameter group and stage 2's recorded render (``colour_operator``) equal ``rasterizer=torch``."""
    from trainer_util import tiny_scene

    from arcsem.plugins import BACKBONES

    scene = tiny_scene(n=2)
    cams = scene.train.cameras
    res = {}
    for r in ("torch", "triton"):
        torch.manual_seed(0)
        bb = BACKBONES.build({"name": "gs2d", "random_init_points": 300, "rasterizer": r, "sh_degree": 1}, scene=scene)
        out = bb.render(cams)
        g = torch.Generator().manual_seed(1)
        loss = sum((out[k] * torch.rand(out[k].shape, generator=g)).sum() for k in OUTPUTS["gs2d"])
        params = [p for ps in bb.param_groups("geometry").values() for p in ps]
        grads = torch.autograd.grad(loss, params, allow_unused=True)  # (SH rest: unused at active degree 0)
        frozen = bb.colour_operator(cams)()
        res[r] = out, grads, frozen
    (o_ref, g_ref, f_ref), (o, g, f) = res["torch"], res["triton"]
    assert o_ref["alpha"].max() > 0.5, "the random model should cover the views"
    for k in OUTPUTS["gs2d"]:
        assert_rel(o[k].detach(), o_ref[k].detach(), 2e-5, k)
    assert [a is None for a in g] == [b is None for b in g_ref] and sum(a is not None for a in g) >= 5
    for i, (a, b) in enumerate(zip(g, g_ref)):
        if a is not None:
            assert_rel(a, b, 2e-5, f"parameter {i}")
    assert_rel(f["rgb"].detach(), f_ref["rgb"].detach(), 2e-5, "recorded render")


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
def test_triton_footprints_equal_torch(model):
    """The footprint kernel's radii, tile rectangles, effective pixel boxes and depths are those of
    ``footprint_2dgs`` exactly (splats partly off-screen and behind the camera, opacities down to 0.001, a
    non-default low-pass sigma on the orthographic cameras), and so are the tile lists binned from them."""
    from arcsem.backbones.gaussians._triton2d_footprint import footprint_bin_2dgs_triton
    from arcsem.backbones.gaussians.raster import bin_tiles
    from arcsem.backbones.gaussians.raster_scenes import orbit_cameras, random_splats
    from arcsem.backbones.gs2d.render import footprint_2dgs, splat_homographies

    s = random_splats(3001, 1, seed=3, scale=(0.002, 0.3), extent=4.0, opacity=(0.001, 1.0))
    cams = orbit_cameras(2, 72, 40, ortho=model == "orthographic")
    Hm, _ = splat_homographies(s.means, s.quats, s.scales[:, :2], cams)
    sigma = 0.4 if model == "orthographic" else 0.7071
    radius, rects, eff, depth = footprint_2dgs(Hm, s.opacities, cams, 16, 0.01, sigma)
    r2, rects2, eff2, b2 = footprint_bin_2dgs_triton(Hm, s.opacities, 72, 40, 16, 0.01, sigma)
    vis = (radius > 0) & (rects[..., 1] > rects[..., 0]) & (rects[..., 3] > rects[..., 2])
    assert 0 < int(vis.sum()) < vis.numel(), "the scene should have visible and culled splats"
    assert torch.equal(r2, radius) and torch.equal(rects2, rects) and torch.equal(eff2[vis], eff[vis])
    b = bin_tiles(rects, depth, 72, 40, 16)
    assert torch.equal(b2.offsets, b.offsets) and torch.equal(b2.splat, b.splat)


def test_triton_training_step_reads_back_only_the_binning():
    """A stage-1 step on ``rasterizer=triton`` (2DGS + ACT, the geometry losses) waits for the device only where the
    tile binning sizes its lists (tests/test_step_syncs.py's detector; the PyTorch rasteriser reads more there)."""
    from test_step_syncs import ALLOWED, HostReads, _run

    from arcsem.train import loop as loop_module

    run, losses, hook = _run("gs2d", "geometry", rasterizer="triton")
    for s in range(2):
        loop_module._step(run, losses, hook, s, record=False)
    reads = {}
    for impl in ("triton", "torch"):
        if impl == "torch":
            run, losses, hook = _run("gs2d", "geometry")
            for s in range(2):
                loop_module._step(run, losses, hook, s, record=False)
        mode = HostReads()
        with mode:
            loop_module._step(run, losses, hook, 2, record=False)
        reads[impl] = mode.sites
    binning = (*ALLOWED, "backbones/gaussians/_triton2d_bin.py")  # its pair count: the list's length
    stray = {k: n for k, n in reads["triton"].items() if not k[1].startswith(binning)}
    assert not stray, f"host reads in a triton training step (op, source line: count): {stray}"
    assert 0 < sum(reads["triton"].values()) < sum(reads["torch"].values()), reads


def test_triton_kernels_compile_for_a_gpu_here():
    """Triton compiles the kernels for sm_90 without a GPU (its interpreter, which the tests use, accepts constructs
    the compiler rejects), with no register spills: the rasteriser's five, the tile binning's one, the SH colours' two,
    the densification statistics' one and the losses' seven (tests/test_triton_losses.py)."""
    env = {k: v for k, v in os.environ.items() if k != "TRITON_INTERPRET"}
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "gpu" / "triton_compile.py"), "--arch", "90"],
                       capture_output=True, text=True, env=env, cwd=ROOT, timeout=600, check=False)
    assert r.returncode == 0, r.stdout + r.stderr
    lines = [ln for ln in r.stdout.splitlines() if "compiled for sm_90" in ln]
    assert len(lines) == 16 and all("0 bytes of spill" in ln for ln in lines), r.stdout


def test_triton_choice_says_where_it_cannot_run(monkeypatch):
    """``rasterizer=triton`` on the CPU (no interpreter) or for 3-D Gaussians: a ConfigError naming the key."""
    from arcsem.backbones.gs2d.backbone import GS2DBackbone
    from arcsem.backbones.gs3d.backbone import GS3DBackbone

    from arcsem.errors import ConfigError

    cfg2, cfg3 = GS2DBackbone.Config(rasterizer="triton"), GS3DBackbone.Config(rasterizer="triton")
    monkeypatch.setenv("TRITON_INTERPRET", "0")
    with pytest.raises(ConfigError, match=r"backbone.rasterizer=triton runs on CUDA tensors \(the device is cpu"):
        GS2DBackbone.check_config(cfg2, "cpu")
    with pytest.raises(ConfigError, match="2-D splats only"):
        GS3DBackbone.check_config(cfg3, "cuda")
    monkeypatch.setenv("TRITON_INTERPRET", "1")
    GS2DBackbone.check_config(cfg2, "cpu")  # the interpreter: allowed (the tests' path)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
def test_triton_on_cuda_matches_torch_on_cpu(model):
    """The compiled kernels on the GPU, float32, against the PyTorch path on the CPU in float64."""
    params, cams = _scene("gs2d", model, seed=3)
    ref, g_ref, cot = _values_and_grads(params, cams, "torch")
    p32 = [p.float().cuda() for p in params]
    out, g_out, _ = _values_and_grads(p32, cams.to(device="cuda", dtype=torch.float32), "triton",
                                      {k: v.float() for k, v in cot.items()})
    for k in OUTPUTS["gs2d"]:
        assert_rel(out[k].detach().double().cpu(), ref[k].detach(), 1e-4, f"{model} {k}")
    for name, a, b in zip(NAMES, g_out, g_ref):
        assert_rel(a.double().cpu(), b, 1e-3, f"{model} d/d{name}")


def test_auto_takes_the_triton_kernels_for_2dgs_on_cuda_only(monkeypatch):
    """``rasterizer=auto``: 2DGS on a CUDA device of compute capability 8.0 or newer resolves to ``triton`` where
    Triton imports, else the PyTorch path; 3DGS on CUDA and every backbone on the CPU keep their paths."""
    from trainer_util import tiny_scene

    from arcsem import tritonsupport
    from arcsem.plugins import BACKBONES

    scene = tiny_scene(n=2)
    gs2d, gs3d = (BACKBONES.build({"name": n, "random_init_points": 50}, scene=scene) for n in ("gs2d", "gs3d"))
    monkeypatch.setattr(tritonsupport, "_capability", lambda dev: (9, 0))  # an H100 / H200
    assert gs2d._impl("cuda") == "triton" and gs2d._impl("cuda:1") == "triton"
    assert gs3d._impl("cuda") == "torch"
    assert gs2d._impl("cpu") in ("cpp", "torch")
    monkeypatch.setattr(tritonsupport, "_capability", lambda dev: (7, 0))  # a V100: not a GPU Triton supports
    assert gs2d._impl("cuda") == "torch"
    monkeypatch.setattr(tritonsupport, "_capability", lambda dev: (8, 0))
    monkeypatch.setattr(tritonsupport, "_importable", lambda: False)
    assert gs2d._impl("cuda") == "torch"


@pytest.mark.parametrize("degree,ortho,act,dtype,tol", [
    (3, False, True, torch.float64, 1e-10), (3, True, True, torch.float64, 1e-10), (1, False, False, torch.float64, 1e-10),
    (0, False, True, torch.float64, 1e-10), (3, False, True, torch.float32, 2e-5)],
    ids=["deg3-act", "deg3-ortho", "deg1", "deg0", "deg3-f32"])
def test_triton_sh_colours_equal_torch(degree, ortho, act, dtype, tol):
    """The SH colours' kernels (``rasterizer=triton``) against :meth:`GaussianModel.colors`' PyTorch path (backbones/
    sh.py and ACT.apply): colours, and the gradients of the means, the coefficients and the ACT parameters; colours
    that clamp at 0 and ACT outputs that clamp at 0 and 1 among them."""
    from arcsem.backbones.gaussians.model import GaussianModel

    from arcsem.act import ACT
    from arcsem.cameras import Cameras, look_at

    g = torch.Generator().manual_seed(3)
    N, C = 70, 2
    r = lambda *shape: torch.randn(*shape, generator=g, dtype=dtype)
    model = GaussianModel({"means": r(N, 3), "quats": r(N, 4), "log_scales": r(N, 2), "opacity_logits": r(N),
                           "sh_dc": 0.8 * r(N, 1, 3), "sh_rest": 0.3 * r(N, 15, 3)}, sh_degree=3).to(dtype)
    eye = torch.tensor([[0.3, -0.2, -4.0], [-2.5, 0.1, -3.5]], dtype=dtype)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([[0.0, -1.0, 0.0]] * 2, dtype=dtype))
    K = torch.tensor([[40.0, 0, 8], [0, 40.0, 6], [0, 0, 1]], dtype=dtype).expand(C, 3, 3)
    cams = Cameras(w2c, K, 16, 12, "orthographic" if ortho else "pinhole", image_ids=torch.tensor([1, 0]))
    a = None
    if act:
        a = ACT(2).to(dtype)
        with torch.no_grad():
            a.weight.add_(0.3 * r(*a.weight.shape))
            a.bias.add_(0.2 * r(*a.bias.shape))
    cot = torch.randn(C, N, 3, generator=g, dtype=dtype)
    res = {}
    for impl in ("torch", "triton"):
        out = model.colors(cams, degree=degree, impl=impl, act=a)
        wrt = [model.means, model.sh_dc, model.sh_rest] + ([a.weight, a.bias] if act else [])
        grads = torch.autograd.grad((out * cot).sum(), wrt, allow_unused=True)
        res[impl] = (out.detach(), [torch.zeros_like(w) if gr is None else gr for w, gr in zip(wrt, grads)])
    (o0, g0), (o1, g1) = res["torch"], res["triton"]
    assert float((o0 == 0).float().mean()) > 0.01 or act, "some colours should clamp at 0"
    assert_rel(o1, o0, tol, "colours")
    for name, x, y in zip(("means", "sh_dc", "sh_rest", "act.weight", "act.bias"), g1, g0):
        assert_rel(x, y, tol, f"d/d{name}")


@pytest.mark.parametrize("ortho", [False, True], ids=["pinhole", "orthographic"])
def test_triton_densification_statistics_equal_torch(ortho):
    """One step's densification statistics added by the Triton kernel equal ``screen_grad_norms`` + ``accumulate``
    (densify.py): gradient sums, counts and the largest radii, over two cameras that see different splats."""
    from arcsem.backbones.gaussians._triton_densify import densify_stats_triton
    from arcsem.backbones.gaussians.densify import DensifyStats, screen_grad_norms

    from arcsem.cameras import Cameras, look_at

    g = torch.Generator().manual_seed(4)
    N, C = 300, 2
    means, grad = torch.randn(N, 3, generator=g), 1e-3 * torch.randn(N, 3, generator=g)
    eye = torch.tensor([[0.3, -0.2, -4.0], [-2.5, 0.1, -3.5]])
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([[0.0, -1.0, 0.0]] * 2))
    K = torch.tensor([[[40.0, 0, 8], [0, 40.0, 6], [0, 0, 1]], [[55.0, 0, 8], [0, 50.0, 6], [0, 0, 1]]])
    cams = Cameras(w2c, K, 16, 12, "orthographic" if ortho else "pinhole")
    visible = torch.rand(C, N, generator=g) > 0.3
    radii = torch.randint(0, 9, (C, N), generator=g)
    start = DensifyStats(torch.rand(N, generator=g), torch.randint(0, 4, (N,), generator=g).float(),
                         torch.randint(0, 6, (N,), generator=g).float())
    ref, out = (DensifyStats(*(t.clone() for t in (start.grad_sum, start.count, start.max_radii))) for _ in range(2))
    ref.accumulate(screen_grad_norms(grad, means, cams), visible, radii)
    densify_stats_triton(out, grad, means, cams, visible, radii)
    assert torch.equal(out.count, ref.count) and torch.equal(out.max_radii, ref.max_radii)
    assert not torch.equal(ref.grad_sum, start.grad_sum)
    assert_rel(out.grad_sum - start.grad_sum, ref.grad_sum - start.grad_sum, 1e-5, "gradient sums")
