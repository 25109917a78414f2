"""Plenoxels fused C++ ray marching: values and gradients against the PyTorch reference, gradcheck, reproducibility."""
from __future__ import annotations

import pytest
import torch
from arcsem.backbones.plenoxels.grid import build_index
from arcsem.backbones.plenoxels.render import GridData, render_grid
from test_plenoxels import BOX, make, small_scene, with_ball


def _cpp_or_skip():
    from arcsem.backbones.plenoxels.fused import load_extension

    if load_extension() is None:
        pytest.skip("C++ extension unavailable")


def test_fused_kernel_matches_torch_reference_values_and_gradients():
    from arcsem.act import ACT

    _cpp_or_skip()
    gen = torch.Generator().manual_seed(3)
    occ = torch.rand(6, 5, 7, generator=gen) > 0.3
    idx, m = build_index(occ), int(occ.sum())
    dens = (torch.rand(m, generator=gen, dtype=torch.float64) * 30 - 5).requires_grad_()  # some negative (ReLU)
    sh = (0.3 * torch.randn(m, 9, 3, generator=gen, dtype=torch.float64)).requires_grad_()
    o = torch.randn(60, 3, generator=gen, dtype=torch.float64) * 0.3 + torch.tensor([-3.0, 0, 0], dtype=torch.float64)
    d = torch.randn(60, 3, generator=gen, dtype=torch.float64) * 0.3 + torch.tensor([1.0, 0, 0], dtype=torch.float64)
    act = ACT(4, mode="rgb", init_noise=0.3).double()
    ids = torch.randint(-1, 4, (60,), generator=gen)
    res = {}
    for impl in ("torch", "cpp"):
        out = render_grid(GridData(idx, dens, sh, BOX.double()), o, d, act=act, image_ids=ids, impl=impl,
                          background=torch.tensor([0.2, 0.3, 0.4]), stop_thresh=1e-3)
        loss = (out["rgb"] * torch.tensor([0.3, -1.0, 2.0], dtype=torch.float64)).sum() + out["alpha"].sum() \
            + 0.1 * out["depth"].sum()
        res[impl] = (out, torch.autograd.grad(loss, (dens, sh, act.weight, act.bias)))
    assert (res["torch"][0]["alpha"] > 0.999).any() and (res["torch"][0]["alpha"] < 0.5).any()
    for k in ("rgb", "alpha", "depth"):
        torch.testing.assert_close(res["cpp"][0][k], res["torch"][0][k], atol=1e-12, rtol=0)
    for gc, gt in zip(res["cpp"][1], res["torch"][1]):
        assert gt.abs().sum() > 0
        torch.testing.assert_close(gc.to_dense() if gc.is_sparse else gc, gt, atol=1e-10, rtol=1e-10)


def test_fused_kernel_gradcheck():
    _cpp_or_skip()
    gen = torch.Generator().manual_seed(4)
    occ = torch.rand(3, 3, 3, generator=gen) > 0.3
    idx, m = build_index(occ), int(occ.sum())
    dens0 = (0.5 + torch.rand(m, generator=gen, dtype=torch.float64)).requires_grad_()
    sh0 = (0.2 * torch.randn(m, 9, 3, generator=gen, dtype=torch.float64)).requires_grad_()
    o = torch.tensor([[-3.0, 0.1, 0.2], [0.2, -3.0, -0.1]], dtype=torch.float64)
    d = torch.tensor([[1.0, 0.05, -0.1], [0.1, 1.0, 0.2]], dtype=torch.float64)

    def f(dens, sh):
        out = render_grid(GridData(idx, dens, sh, BOX.double()), o, d, impl="cpp", sparse_grad=False)
        return torch.cat([out["rgb"], out["alpha"], out["depth"]], 1)

    assert torch.autograd.gradcheck(f, (dens0, sh0), eps=1e-6, atol=1e-6, fast_mode=True)


def test_backbone_renderers_agree():
    _cpp_or_skip()
    scene = small_scene()
    a, b = make(scene, rasterizer="torch"), make(scene, rasterizer="cpp")
    with_ball(a, sigma=5.0)
    b.load_state_dict(a.state_dict())
    with torch.no_grad():
        ra, rb = a.render(scene.train.cameras[:2]), b.render(scene.train.cameras[:2])
    for k in ("rgb", "alpha", "depth"):
        torch.testing.assert_close(rb[k], ra[k], atol=1e-5, rtol=0)


def test_fused_gradients_are_reproducible():
    _cpp_or_skip()
    scene = small_scene(w=40, h=30)
    bb = make(scene, rasterizer="cpp")
    with_ball(bb, sigma=5.0)
    o, d = scene.train.cameras.rays()
    grads = []
    for _ in range(2):
        bb.render_rays(o.reshape(-1, 3), d.reshape(-1, 3))["rgb"].sum().backward()
        grads.append((bb.density.grad.to_dense(), bb.sh.grad.to_dense()))
        bb.zero_grad(set_to_none=True)
    assert all(torch.equal(a, b) for a, b in zip(*grads))  # bitwise: exact resume needs it
