"""Plenoxels fused C++ ray marching: values and gradients against the PyTorch reference, gradcheck, reproducibility."""
from __future__ import annotations

import pytest
import torch
from arcsem.backbones.plenoxels.grid import build_index, occupied_coords, voxel_size
from arcsem.backbones.plenoxels.render import GridData, render_grid
from test_plenoxels import BOX, make, small_scene, with_ball

from arcsem.plugins import LOSSES
from arcsem.train.optim import apply_schedules


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
            + 0.1 * out["depth"].sum() + 3.0 * out["distortion"].sum()
        res[impl] = (out, torch.autograd.grad(loss, (dens, sh, act.weight, act.bias)))
    assert (res["torch"][0]["alpha"] > 0.999).any() and (res["torch"][0]["alpha"] < 0.5).any()
    assert (res["torch"][0]["distortion"] > 1e-3).any()  # rays with spread-out weights
    for k in ("rgb", "alpha", "depth", "distortion"):
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
        return torch.cat([out["rgb"], out["alpha"], out["depth"], out["distortion"]], 1)

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


def _sparse_grid(gen, shape=(40, 36, 44), dtype=torch.float64):
    """A grid mostly stored and empty (density < 0), with three positive blobs and an unstored slab."""
    occ = torch.ones(shape, dtype=torch.bool)
    occ[:, 10:14, :] = False  # a slab with nothing stored
    idx, m = build_index(occ), int(occ.sum())
    axes = [torch.linspace(-1, 1, s, dtype=dtype) for s in shape]
    p = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1)[occ]
    dens = torch.full((m,), -2.0, dtype=dtype)
    for c, r in (((0.3, 0.2, -0.1), 0.25), ((-0.5, -0.4, 0.5), 0.15), ((0.6, -0.6, -0.6), 0.1)):
        near = (p - torch.tensor(c, dtype=dtype)).norm(dim=-1) < r
        dens[near] = 3 + 20 * torch.rand(int(near.sum()), generator=gen, dtype=dtype)
    return idx, dens


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_skipping_marcher_matches_reference_on_a_sparse_grid(degree):
    """Float64 values and gradients (density, SH, ACT) where most of the box is skipped: rays from every side,
    axis-parallel ones included, through dead blocks, an unstored slab and three blobs."""
    from arcsem.act import ACT

    _cpp_or_skip()
    gen = torch.Generator().manual_seed(5)
    idx, dens0 = _sparse_grid(gen)
    k = (degree + 1) ** 2
    dens = dens0.clone().requires_grad_()
    sh = (0.3 * torch.randn(dens.shape[0], k, 3, generator=gen, dtype=torch.float64)).requires_grad_()
    n = 300
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen, dtype=torch.float64), dim=-1)
    d[:6] = torch.tensor([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [-1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]],
                         dtype=torch.float64)
    blobs = torch.tensor([[0.3, 0.2, -0.1], [-0.5, -0.4, 0.5], [0.6, -0.6, -0.6]], dtype=torch.float64)
    aim = blobs[torch.randint(0, 3, (n,), generator=gen)] + 0.2 * torch.randn(n, 3, generator=gen, dtype=torch.float64)
    aim[n // 2 :] = 2 * torch.rand(n - n // 2, 3, generator=gen, dtype=torch.float64) - 1  # anywhere
    aim[:6] = blobs[0]
    o = aim - 3 * d
    act = ACT(3, mode="rgb", init_noise=0.2).double()
    ids = torch.randint(-1, 3, (n,), generator=gen)
    res = {}
    for impl in ("torch", "cpp"):
        out = render_grid(GridData(idx, dens, sh, BOX.double()), o, d, sh_degree=degree, act=act, image_ids=ids,
                          impl=impl)
        loss = (out["rgb"] * torch.tensor([0.5, -1.0, 2.0], dtype=torch.float64)).sum() + out["alpha"].sum() \
            + 0.1 * out["depth"].sum() + 3.0 * out["distortion"].sum()
        grads = torch.autograd.grad(loss, (dens, sh, act.weight, act.bias))
        res[impl] = (out, [g.to_dense() if g.is_sparse else g for g in grads])
    hit = res["torch"][0]["alpha"][:, 0] > 1e-3
    assert 0.2 < hit.float().mean() < 0.9  # rays both through blobs and through nothing
    for key in ("rgb", "alpha", "depth", "distortion"):
        torch.testing.assert_close(res["cpp"][0][key], res["torch"][0][key], atol=1e-12, rtol=0)
    for gc, gt in zip(res["cpp"][1], res["torch"][1]):
        assert gt.abs().sum() > 0
        torch.testing.assert_close(gc, gt, atol=1e-10, rtol=1e-10)


def test_live_masks_and_block_distances():
    """Cells with a positive stored corner; the point and volume paths agree; distances are Chebyshev."""
    from arcsem.backbones.plenoxels.fused import live_masks
    from arcsem.backbones.plenoxels.grid import cell_occupancy, occupied_coords

    _cpp_or_skip()
    gen = torch.Generator().manual_seed(6)
    idx, dens = _sparse_grid(gen, shape=(30, 22, 26))
    cell, dist = live_masks(idx, occupied_coords(idx), dens, shift=2)  # dense storage: the volume path
    positive = torch.zeros(idx.shape, dtype=torch.bool)
    positive[idx >= 0] = dens[idx[idx >= 0].long()] > 0
    want = cell_occupancy(build_index(positive))
    want[-1], want[:, -1], want[:, :, -1] = False, False, False  # the last plane is no cell
    assert torch.equal(cell.bool(), want) and want.any()
    sparse_idx = build_index(positive)  # only the positive points stored: the point path
    cell2, dist2 = live_masks(sparse_idx, occupied_coords(sparse_idx), dens[idx[positive].long()], shift=2)
    assert torch.equal(cell2, cell) and torch.equal(dist2, dist)
    blocks = torch.nn.functional.max_pool3d(want.float()[None, None], 4, 4, ceil_mode=True)[0, 0] > 0
    live = blocks.nonzero()
    every = torch.stack(torch.meshgrid(*[torch.arange(s) for s in blocks.shape], indexing="ij"), -1).reshape(-1, 3)
    cheb = (every[:, None] - live[None]).abs().amax(-1).amin(1).clamp_max(16).reshape(blocks.shape)
    assert torch.equal(dist.long(), cheb) and (cheb > 1).any()


def test_fused_max_weights_match_reference():
    from arcsem.backbones.plenoxels.fused import max_weights
    from arcsem.backbones.plenoxels.grid import occupied_coords
    from arcsem.backbones.plenoxels.upsample import max_weights as reference_max

    _cpp_or_skip()
    gen = torch.Generator().manual_seed(7)
    idx, dens = _sparse_grid(gen, shape=(24, 20, 22))
    sh = torch.zeros(dens.shape[0], 1, 3, dtype=torch.float64)
    d = torch.nn.functional.normalize(torch.randn(400, 3, generator=gen, dtype=torch.float64), dim=-1)
    o = -3 * d + 0.6 * torch.randn(400, 3, generator=gen, dtype=torch.float64)
    step = 0.5 * 2 / 23
    ref = render_grid(GridData(idx, dens, sh, BOX.double()), o, d, sh_degree=0, return_samples=True)
    want = reference_max(dens.shape[0], [ref["samples"]]).double()
    got = max_weights(dens, idx, occupied_coords(idx), BOX.double(), o, d, step=step, scale=1.0, stop=1e-4)
    assert want.max() > 0.3
    torch.testing.assert_close(got, want, atol=1e-6, rtol=0)  # the reference reduces in float32


def test_distortion_is_the_pairwise_spread_of_the_weights():
    """``distortion(alpha, moments)`` = sum over sample pairs of ``w_i w_j (m_i - m_j)^2`` (``m = t / scale``),
    whatever the moments' origin; brute force over random rays of 1-40 samples."""
    from arcsem.backbones.plenoxels.render import distortion

    gen = torch.Generator().manual_seed(8)
    scale, rows = 0.7, []
    for n in (1, 2, 5, 40):
        w = torch.rand(n, generator=gen, dtype=torch.float64) / n
        t = 50 + torch.rand(n, generator=gen, dtype=torch.float64).sort().values  # far from the origin
        pairs = sum(w[i] * w[j] * ((t[i] - t[j]) / scale) ** 2 for i in range(n) for j in range(i + 1, n))
        u = t - 49.5  # an entry point in front of the samples
        rows.append((w.sum(), torch.stack([(w * u).sum(), (w * u * u).sum()]), torch.as_tensor(pairs).double()))
    alpha, mom, truth = (torch.stack(c) for c in zip(*rows))
    torch.testing.assert_close(distortion(alpha, mom, scale)[:, 0], truth, atol=1e-13, rtol=1e-10)
    assert truth[0] == 0 and (truth[1:] > 0).all()


def test_distortion_loss_thins_a_fuzzy_surface():
    """The ``distortion`` loss on Plenoxels' rays (fused marcher, sparse RMSProp): a ball whose density fades
    over several voxels, fitted to its own images with and without the term. With it the rays' weights
    concentrate (mean distortion falls) while the images stay; without it nothing moves."""
    scene = small_scene(n=4, w=24, h=18)
    cams = scene.train.cameras
    o, d = (t.reshape(-1, 3) for t in cams.rays())
    results = {}
    for weight in (0.0, 1.0):
        torch.manual_seed(0)
        bb = make(scene, reso=[[20, 20, 20]], lr_sigma_delay_steps=0)
        g = bb.grid()
        pts = occupied_coords(bb.index).float() * voxel_size(bb.bounds, bb.reso) + bb.bounds[0]
        with torch.no_grad():
            bb.density.copy_((8.0 * (0.45 - pts.norm(dim=-1)) / 0.25).clamp(0, 8.0))  # fades over ~4 voxels
            target = bb.render_rays(o, d)["rgb"]
            before = bb.render_rays(o, d)["distortion"].mean()
        assert g.density.shape[0] > 0 and "distortion" in bb.provides
        loss_fn = LOSSES.build({"name": "distortion", "weight": weight, "start_step": 0})
        opts = bb.make_optimizers("geometry", bb.param_groups("geometry"))
        gen = torch.Generator().manual_seed(0)
        for step in range(60):
            apply_schedules(opts, bb.learning_rates("geometry"), step, 60)
            sel = torch.randint(0, o.shape[0], (400,), generator=gen)
            out = bb.render_rays(o[sel], d[sel])
            loss = ((out["rgb"] - target[sel]) ** 2).mean() + weight * loss_fn(out, None, step)
            for opt in opts.values():
                opt.zero_grad()
            loss.backward()
            for opt in opts.values():
                opt.step()
        with torch.no_grad():
            out = bb.render_rays(o, d)
        psnr = float(-10 * torch.log10(((out["rgb"] - target) ** 2).mean().clamp_min(1e-12)))
        results[weight] = (float(out["distortion"].mean() / before), psnr)
    assert results[1.0][0] < 0.7 * results[0.0][0], results  # the term thins the surface (measured: 0.005 of before)
    assert results[1.0][1] > 25, results  # ... and the images stay (measured: 32.7 dB)
