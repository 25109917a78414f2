"""The fused C++ SSIM (losses/fused_ssim.py) against the PyTorch ssim_map: values and gradients in float64, the
``dssim`` loss on both paths, and the fallbacks."""
import pytest
import torch
from arcsem.losses.fused_ssim import EXTENSION, fused_ssim_map, usable

from arcsem.imageops import ssim_map

pytestmark = pytest.mark.skipif(not usable("auto", torch.zeros(1), torch.zeros(1)), reason="no C++ toolchain")


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
    x, y = _pair((1, 8, 8, 3), 6, torch.float32)
    assert usable("auto", x, y) and usable("cpp", x, y)
    assert not usable("torch", x, y)
    assert not usable("auto", x, y.requires_grad_())  # a target that needs its gradient: the PyTorch path
    assert not usable("auto", x.half(), y.detach().half())
    from arcsem import cext
    from arcsem.errors import ConfigError

    with pytest.raises(ConfigError, match="dssim.impl"):
        usable("fast", x, y.detach())
    assert cext.resolve_impl("auto", EXTENSION, "cuda") == "torch"
