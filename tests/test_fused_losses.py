"""The fused C++ losses (losses/fused.py) against their PyTorch references: the SSIM map and the 2DGS normal
consistency, values and gradients in float64, the losses on both paths, and the fallbacks."""
import pytest
import torch
from arcsem.losses.fused import EXTENSION, fused_ssim_map, usable

from arcsem.imageops import ssim_map

pytestmark = pytest.mark.skipif(not usable("auto", "impl", torch.zeros(1)), reason="no C++ toolchain")


def _pair(shape, seed, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(shape, generator=g, dtype=dtype)
    y = (0.6 * torch.rand(shape, generator=g, dtype=dtype) + 0.4 * x).clamp(0, 1)  # correlated, as a render and its view
    return x, y


@pytest.mark.parametrize("shape,size,sigma", [((2, 19, 23, 3), 11, 1.5), ((1, 6, 4, 1), 11, 1.5),
                                              ((1, 30, 17, 3), 7, 1.0)])
def test_fused_ssim_map_and_gradient_equal_torch(shape, size, sigma):
    """Images smaller than the window, one channel, another window: the map and d(sum(cot * map))/dx agree with the
    PyTorch function to round-off."""
    x, y = _pair(shape, 1)
    cot = torch.rand(shape, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    res = []
    for fn in (ssim_map, fused_ssim_map):
        xi = x.clone().requires_grad_()
        m = fn(xi, y, size, sigma)
        res.append((m.detach(), torch.autograd.grad((m * cot).sum(), xi)[0]))
    (m0, g0), (m1, g1) = res
    assert float(m0.std()) > 0.02, "the map should vary"
    assert torch.allclose(m1, m0, rtol=0, atol=1e-12)
    assert float((g1 - g0).abs().max() / g0.abs().max()) < 1e-10


def test_fused_ssim_gradcheck():
    x, y = _pair((1, 7, 9, 2), 3)
    assert torch.autograd.gradcheck(lambda a: fused_ssim_map(a, y, 5, 1.0), (x.requires_grad_(),), eps=1e-6, atol=1e-8)


@pytest.mark.parametrize("masked", [False, True])
def test_dssim_loss_fused_and_torch_agree(masked):
    """The ``dssim`` loss with ``impl: cpp`` and ``impl: torch`` on float32 renders: loss and gradient."""
    from arcsem.losses.photometric import DSSIM

    from arcsem.plugins import Batch

    x, y = _pair((2, 24, 32, 3), 4, torch.float32)
    masks = (torch.rand(2, 24, 32, 1, generator=torch.Generator().manual_seed(5)) > 0.3)
    batch = Batch(cameras=None, images=y, indices=torch.arange(2), masks=masks if masked else None)
    res = {}
    for impl in ("torch", "cpp"):
        xi = x.clone().requires_grad_()
        loss = DSSIM(DSSIM.Config(masked=masked, impl=impl))({"rgb": xi}, batch, 0)
        res[impl] = (loss.detach(), torch.autograd.grad(loss, xi)[0])
    assert abs(float(res["cpp"][0] - res["torch"][0])) < 1e-6
    assert float((res["cpp"][1] - res["torch"][1]).abs().max() / res["torch"][1].abs().max()) < 1e-4


def test_fused_path_is_taken_only_where_it_applies():
    from arcsem.losses.photometric import DSSIM

    from arcsem.plugins import Batch

    x, y = _pair((1, 8, 8, 3), 6, torch.float32)
    assert usable("auto", "k", x, y) and usable("cpp", "k", x, y)
    assert not usable("torch", "k", x, y)
    assert not usable("auto", "k", x.half(), y.half())
    from arcsem import cext
    from arcsem.errors import ConfigError

    with pytest.raises(ConfigError, match="dssim.impl"):
        usable("fast", "dssim.impl", x, y)
    assert cext.resolve_impl("auto", EXTENSION, "cuda") == "torch"
    # a target that needs its gradient: the PyTorch path, and the gradient reaches it
    yt = y.clone().requires_grad_()
    batch = Batch(cameras=None, images=yt, indices=torch.arange(1))
    DSSIM(DSSIM.Config(impl="cpp"))({"rgb": x.requires_grad_()}, batch, 0).backward()
    assert yt.grad is not None and float(yt.grad.abs().sum()) > 0


def _nc_inputs(ortho: bool, dtype=torch.float64):
    """A bumpy depth map seen by one pinhole or orthographic camera, rendered normals, an alpha with zeros."""
    from arcsem.cameras import Cameras, look_at

    g = torch.Generator().manual_seed(7)
    C, H, W = 2, 13, 17
    eye = torch.tensor([[0.3, -0.2, -4.0], [-0.5, 0.1, -3.5]], dtype=dtype)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([[0.0, -1.0, 0.0]] * 2, dtype=dtype))
    K = torch.tensor([[40.0, 0, W / 2], [0, 40.0, H / 2], [0, 0, 1]], dtype=dtype).expand(C, 3, 3)
    cams = Cameras(w2c, K, W, H, "orthographic" if ortho else "pinhole")
    depth = 3.5 + 0.2 * torch.rand(C, H, W, 1, generator=g, dtype=dtype)
    depth[0, 5, 5:8] = 3.5  # a flat patch
    normal = torch.randn(C, H, W, 3, generator=g, dtype=dtype) * 0.6
    alpha = torch.rand(C, H, W, 1, generator=g, dtype=dtype)
    alpha[1, :4] = 0
    return depth, normal, alpha, cams


@pytest.mark.parametrize("ortho", [False, True])
def test_fused_normal_consistency_equals_torch(ortho):
    """Loss and gradients of depth and rendered normal, float64, against the PyTorch loss (official form)."""
    from arcsem.losses.geometry import NormalConsistency

    from arcsem.plugins import Batch

    depth, normal, alpha, cams = _nc_inputs(ortho)
    res = {}
    for impl in ("torch", "cpp"):
        d, n = depth.clone().requires_grad_(), normal.clone().requires_grad_()
        batch = Batch(cameras=cams, images=torch.zeros(2, 13, 17, 3, dtype=torch.float64), indices=torch.arange(2))
        loss = NormalConsistency(NormalConsistency.Config(impl=impl))({"depth": d, "normal": n, "alpha": alpha}, batch, 0)
        res[impl] = (loss.detach(), *torch.autograd.grad(3.0 * loss, [d, n]))
    for a, b, what in zip(res["cpp"], res["torch"], ("loss", "d/ddepth", "d/dnormal")):
        assert float(b.abs().max()) > 0, what
        assert float((a - b).abs().max() / b.abs().max()) < 1e-10, what


def test_fused_normal_consistency_float32_and_choice():
    """float32 agrees with the PyTorch path to float32 round-off; official: false and impl: torch take PyTorch."""
    from arcsem.losses.geometry import NormalConsistency

    from arcsem.plugins import Batch

    depth, normal, alpha, cams = _nc_inputs(False, torch.float32)
    batch = Batch(cameras=cams, images=torch.zeros(2, 13, 17, 3), indices=torch.arange(2))
    out = {"depth": depth.requires_grad_(), "normal": normal, "alpha": alpha}
    a = NormalConsistency(NormalConsistency.Config(impl="cpp"))(out, batch, 0)
    b = NormalConsistency(NormalConsistency.Config(impl="torch"))(out, batch, 0)
    assert abs(float(a.detach() - b.detach())) < 1e-5
    assert a.grad_fn is not None and "NormalConsistency" in type(a.grad_fn).__name__
    for cfg in (NormalConsistency.Config(impl="torch"), NormalConsistency.Config(official=False)):
        assert "NormalConsistency" not in type(NormalConsistency(cfg)(out, batch, 0).grad_fn).__name__


def test_unavailable_loss_kernels_warn_once_with_their_keys(monkeypatch):
    """Without a toolchain the losses take the PyTorch path; the one warning names the losses' own keys."""
    import warnings

    import torch.utils.cpp_extension as cpp_ext

    from arcsem import cext

    def broken(*a, **k):
        raise OSError("no compiler here")

    x, y = _pair((1, 8, 8, 3), 6, torch.float32)
    monkeypatch.setattr(cpp_ext, "load", broken)
    cext.load.cache_clear()
    try:
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            assert not usable("auto", "dssim.impl", x, y) and not usable("auto", "dssim.impl", x, y)
        msgs = [str(w.message) for w in rec if issubclass(w.category, RuntimeWarning)]
        assert len(msgs) == 1 and "fused C++ losses" in msgs[0], msgs
        assert "dssim.impl=torch, normal_consistency.impl=torch" in msgs[0] and "rasterizer" not in msgs[0], msgs
    finally:
        cext.load.cache_clear()
