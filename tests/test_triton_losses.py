"""The losses' Triton kernels (for CUDA) against their PyTorch references, values and gradients, and where ``auto``
takes them. Without a GPU the kernels run on CPU tensors through Triton's interpreter (``TRITON_INTERPRET=1``, set
here before the kernels are first imported); on a GPU machine ``pytest -m cuda`` runs the compiled ones too."""
from __future__ import annotations

import os

import pytest
import torch

if not torch.cuda.is_available():
    os.environ.setdefault("TRITON_INTERPRET", "1")

pytest.importorskip("triton")

from test_fused_losses import _nc_inputs, _pair

from arcsem.imageops import ssim_map
from arcsem.plugins import Batch

DEVICE = "cuda" if torch.cuda.is_available() else "cpu"


@pytest.mark.parametrize("shape,size,sigma,dtype,tol", [
    ((2, 19, 23, 3), 11, 1.5, torch.float64, 1e-10),
    ((1, 6, 4, 1), 11, 1.5, torch.float64, 1e-10),  # smaller than the window, one channel
    ((1, 30, 17, 3), 7, 1.0, torch.float64, 1e-10),  # another window
    ((1, 12, 101, 3), 11, 1.5, torch.float32, 2e-5),  # rows longer than a program's block (101 x 3 > 256)
], ids=["f64", "small", "window7", "f32-wide"])
def test_triton_ssim_map_and_gradient_equal_torch(shape, size, sigma, dtype, tol):
    _compare_ssim(shape, size, sigma, dtype, tol)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_triton_ssim_on_cuda_equals_torch_on_cpu():
    """The compiled kernels (``pytest -m cuda``): the demo's image size in float32, and float64."""
    _compare_ssim((1, 192, 288, 3), 11, 1.5, torch.float32, 2e-5)
    _compare_ssim((2, 19, 23, 3), 11, 1.5, torch.float64, 1e-10)


def _compare_ssim(shape, size, sigma, dtype, tol):
    from arcsem.losses.triton_ssim import triton_ssim_map

    x, y = _pair(shape, 1, dtype)
    cot = torch.rand(shape, generator=torch.Generator().manual_seed(2), dtype=dtype)
    res = []
    for fn, dev in ((ssim_map, "cpu"), (triton_ssim_map, DEVICE)):
        xi = x.clone().to(dev).requires_grad_()
        m = fn(xi, y.to(dev), size, sigma)
        res.append((m.detach().cpu(), torch.autograd.grad((m * cot.to(dev)).sum(), xi)[0].cpu()))
    (m0, g0), (m1, g1) = res
    assert float(m0.std()) > 0.02, "the map should vary"
    assert float((m1 - m0).abs().max()) < tol
    assert float((g1 - g0).abs().max() / g0.abs().max()) < tol


def test_auto_takes_the_losses_triton_kernels_where_the_rasteriser_does(monkeypatch):
    """``dssim.impl`` and ``normal_consistency.impl`` ``auto``: the Triton kernels on a CUDA device Triton supports
    (capability faked here), the C++ or PyTorch path on the CPU, PyTorch on older GPUs, for half precision and for a
    D-SSIM target that needs its gradient; ``impl=triton`` on a device it cannot run on is a config error naming the
    key."""
    import arcsem.losses.triton_normals
    import arcsem.losses.triton_ssim  # noqa: F401 - imported (interpreted) before TRITON_INTERPRET=0 below
    from arcsem.losses.fused import kernel_path

    from arcsem import tritonsupport
    from arcsem.errors import ConfigError

    class Cuda:  # what kernel_path reads of a tensor
        device, dtype, requires_grad = torch.device("cuda"), torch.float32, False

    x = Cuda()
    monkeypatch.setattr(tritonsupport, "_capability", lambda dev: (9, 0))
    assert kernel_path("auto", "dssim.impl", x, x) == "triton" and kernel_path("torch", "dssim.impl", x, x) == "torch"
    half = Cuda()
    half.dtype = torch.float16
    assert kernel_path("auto", "dssim.impl", half, half) == "torch"
    monkeypatch.setattr(tritonsupport, "_capability", lambda dev: (7, 5))
    assert kernel_path("auto", "normal_consistency.impl", x, x) == "torch"
    cpu = torch.zeros(1, 4, 4, 3)
    assert kernel_path("auto", "dssim.impl", cpu, cpu) in ("cpp", "torch")

    from arcsem.losses.geometry import NormalConsistency
    from arcsem.losses.photometric import DSSIM

    target = cpu.clone().requires_grad_()  # a target with a gradient: the PyTorch SSIM, even when triton is asked for
    DSSIM(DSSIM.Config(impl="triton"))({"rgb": cpu}, Batch(cameras=None, images=target, indices=None), 0).backward()
    assert target.grad is not None
    monkeypatch.setenv("TRITON_INTERPRET", "0")
    batch = Batch(cameras=None, images=cpu, indices=torch.arange(1))
    with pytest.raises(ConfigError, match="dssim.impl=triton runs on CUDA tensors"):
        DSSIM(DSSIM.Config(impl="triton"))({"rgb": cpu}, batch, 0)
    depth, normal, alpha, cams = _nc_inputs(False, torch.float32)
    with pytest.raises(ConfigError, match="normal_consistency.impl=triton runs on CUDA tensors"):
        NormalConsistency(NormalConsistency.Config(impl="triton"))(
            {"depth": depth, "normal": normal, "alpha": alpha}, Batch(cameras=cams, images=None, indices=None), 0)


@pytest.mark.parametrize("masked", [False, True])
def test_dssim_loss_on_triton_equals_torch(masked):
    from arcsem.losses.photometric import DSSIM

    x, y = _pair((2, 24, 32, 3), 4, torch.float32)
    masks = torch.rand(2, 24, 32, 1, generator=torch.Generator().manual_seed(5)) > 0.3
    res = {}
    for impl, dev in (("torch", "cpu"), ("triton", DEVICE)):
        batch = Batch(cameras=None, images=y.to(dev), indices=torch.arange(2),
                      masks=masks.to(dev) if masked else None)
        xi = x.clone().to(dev).requires_grad_()
        loss = DSSIM(DSSIM.Config(masked=masked, impl=impl))({"rgb": xi}, batch, 0)
        res[impl] = (loss.detach().cpu(), torch.autograd.grad(loss, xi)[0].cpu())
    assert abs(float(res["triton"][0] - res["torch"][0])) < 1e-6
    assert float((res["triton"][1] - res["torch"][1]).abs().max() / res["torch"][1].abs().max()) < 1e-4


@pytest.mark.parametrize("ortho,dtype,tol", [(False, torch.float64, 1e-10), (True, torch.float64, 1e-10),
                                             (False, torch.float32, 2e-5)], ids=["pinhole-f64", "ortho-f64", "f32"])
def test_triton_normal_consistency_equals_torch(ortho, dtype, tol):
    """The official normal consistency (a bumpy depth map with a flat patch, an alpha with zeros, two views): the
    loss and its gradients in the depth and the rendered normals."""
    _compare_normals(ortho, dtype, tol, DEVICE)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_triton_normal_consistency_on_cuda_equals_torch_on_cpu():
    _compare_normals(False, torch.float32, 2e-5, "cuda")
    _compare_normals(True, torch.float64, 1e-10, "cuda")


def _compare_normals(ortho, dtype, tol, device):
    from arcsem.losses.geometry import NormalConsistency

    depth, normal, alpha, cams = _nc_inputs(ortho, dtype)
    res = []
    for impl, dev in (("torch", "cpu"), ("triton", device)):
        d, n = depth.clone().to(dev).requires_grad_(), normal.clone().to(dev).requires_grad_()
        loss = NormalConsistency(NormalConsistency.Config(impl=impl))(
            {"depth": d, "normal": n, "alpha": alpha.to(dev)},
            Batch(cameras=cams.to(device=dev), images=None, indices=None), 0)
        res.append([t.detach().cpu() for t in (loss, *torch.autograd.grad(1.7 * loss, (d, n)))])
    (l0, gd0, gn0), (l1, gd1, gn1) = res
    assert 0.5 < float(l0) < 1.5 and float(gd0.abs().max()) > 0
    assert abs(float(l1 - l0)) < tol
    assert float((gd1 - gd0).abs().max() / gd0.abs().max()) < tol
    assert float((gn1 - gn0).abs().max() / gn0.abs().max()) < tol
